"""The operation layers of every drawing fabline writes (DXF and sheet SVG), in LightBurn's palette colours.

LightBurn gives each colour a layer of its own (its palette: 00 black, 01 blue, 02 red, 03 green, ... and the
tool layers T1 and T2, which are never sent to the laser); a file's colours decide the layer each shape lands
on. The cut and engrave layers use palette colours (ACI colours in the DXF whose RGB is the palette's), the
sheet outline and annotations the tool layer T1's colour (docs/export.md, Colours and layers).
"""

from __future__ import annotations

from typing import NamedTuple


class Layer(NamedTuple):
    """One operation layer: its AutoCAD colour index, the same colour as RGB hex (for SVG), the LightBurn palette
    layer that colour lands on when LightBurn imports the file, and whether it is meant to be output."""

    aci: int
    rgb: str
    lightburn: str
    output: bool = True


LAYERS = {      # the colours are LightBurn's palette colours (docs/export.md, Colours and layers)
    "CUT-OUTER": Layer(1, "#FF0000", "02 red"),
    "CUT-INNER": Layer(5, "#0000FF", "01 blue"),
    "ENGRAVE-MARK": Layer(3, "#00E000", "03 green"),
    "ENGRAVE-TEXT": Layer(6, "#FF00FF", "07 magenta"),
    "SHEET": Layer(30, "#F36926", "T1 tool layer", output=False),
}
