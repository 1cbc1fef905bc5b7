"""SVG drawings of parts for a look before cutting: cuts in black, engraved marks in blue, text in red.

One file per part, 1 SVG unit = 1 mm, y pointing up as in the part frame; arcs are flattened finely.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import atomic_output
from fabline.naming import file_stem
from fabline.unroll.parts import Part, PartSet, flatten_contour

LAYER_STYLE = {
    "cut": {"stroke": "#000000", "stroke-width": "0.6", "fill": "none"},
    "marks": {"stroke": "#1f5fbf", "stroke-width": "0.4", "fill": "none"},
    "text": {"stroke": "#c0392b", "stroke-width": "0.3", "fill": "none", "stroke-linecap": "round"},
}
MARGIN_MM = 5.0


def part_svg(part: Part) -> str:
    """The part drawn as an SVG document (text)."""
    cuts = [flatten_contour(part.outline, 0.02)] + [flatten_contour(h, 0.02) for h in part.holes]
    everything = np.vstack(cuts + [m[:, :2] for m in part.marks] + [t[:, :2] for t in part.text])
    low, high = everything.min(axis=0) - MARGIN_MM, everything.max(axis=0) + MARGIN_MM
    width, height = high - low
    svg = ET.Element("svg", {
        "xmlns": "http://www.w3.org/2000/svg", "width": f"{width:.2f}mm", "height": f"{height:.2f}mm",
        "viewBox": f"{low[0]:.3f} {-high[1]:.3f} {width:.3f} {height:.3f}",
    })
    ET.SubElement(svg, "title").text = f"{part.id} ({part.kind}) {part.label}"
    for layer, polylines, closed in (("cut", cuts, True), ("marks", part.marks, False), ("text", part.text, False)):
        group = ET.SubElement(svg, "g", {"id": layer, "transform": "scale(1,-1)", **LAYER_STYLE[layer]})
        for line in polylines:
            coords = " ".join(f"{x:.3f},{y:.3f}" for x, y in np.asarray(line)[:, :2])
            ET.SubElement(group, "polygon" if closed else "polyline", {"points": coords})
    return ET.tostring(svg, encoding="unicode")


def write_previews(partset: PartSet, directory: str | os.PathLike,
                   kinds: tuple[str, ...] = ("strip", "curved-strip", "joint")) -> list[Path]:
    """Write one `<part id>.svg` per part of the given kinds into `directory` (the id as `fabline.naming` makes it
    a file name, so it stays in `directory`); returns the paths written. Two ids that differ only in case are
    refused before anything is written: on a case-blind disk one file would replace the other."""
    directory = Path(directory)
    chosen = [part for part in partset.parts if part.kind in kinds]
    seen: dict[str, str] = {}
    for part in chosen:
        other = seen.setdefault(file_stem(part.id).casefold(), part.id)
        if other != part.id:
            raise FablineError(f"parts {other!r} and {part.id!r}: their previews would be one file on a disk that "
                               "ignores case; give the lamellas ids that differ in more than case")
    written = []
    for part in chosen:
        path = directory / f"{file_stem(part.id)}.svg"
        with atomic_output(path) as handle:
            handle.write(part_svg(part))
        written.append(path)
    return written
