"""One SVG per nested sheet at 1:1, for the shop's own laser and CAM software: every part's cut and engrave
paths in their layer colours, its id, and the sheet, margin and remnants for reference.

Drawn in sheet millimetres with the y axis flipped so the picture shows the sheet as seen from above
with its origin at the lower-left corner, as in nesting.json.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from fabline.fileio import atomic_output
from fabline.naming import file_stem
from fabline.nest.layout import Nesting, Sheet, place
from fabline.shop.layers import LAYERS
from fabline.unroll.parts import Part, PartSet, flatten_contour

STROKE = "0.5"       # mm: thin enough for LightBurn to read the paths as lines, thick enough to see


def _path_data(contours: list[np.ndarray], height: float, closed: bool = True) -> str:
    """SVG path data of contours in sheet mm, y flipped (closed ones without their repeated last vertex)."""
    if closed:
        return " ".join("M " + " L ".join(f"{x:.2f},{height - y:.2f}" for x, y in c[:-1, :2]) + " Z" for c in contours)
    return " ".join("M " + " L ".join(f"{x:.2f},{height - y:.2f}" for x, y in c[:, :2]) for c in contours)


def sheet_svg(sheet: Sheet, parts: dict[str, Part], margin: float, remnants: list[dict]) -> ET.Element:
    """The SVG element tree of one sheet at 1:1 (width and height in mm, user units mm): each part a group with
    its id, cut and engrave paths in their layer colours (`fabline.shop.layers`), the sheet, margin, remnants
    and part labels in the tool-layer colour LightBurn does not output."""
    colour = {name: layer.rgb for name, layer in LAYERS.items()}
    note = {"fill": "none", "stroke": colour["SHEET"], "stroke-width": STROKE}
    root = ET.Element("svg", xmlns="http://www.w3.org/2000/svg", width=f"{sheet.width:g}mm",
                      height=f"{sheet.height:g}mm", viewBox=f"0 0 {sheet.width:g} {sheet.height:g}")
    ET.SubElement(root, "title").text = f"sheet {sheet.id} ({sheet.stock}) {sheet.width:g} x {sheet.height:g} mm"
    ET.SubElement(root, "rect", x="0", y="0", width=f"{sheet.width:g}", height=f"{sheet.height:g}", id="sheet", **note)
    ET.SubElement(root, "rect", x=f"{margin:g}", y=f"{margin:g}", width=f"{sheet.width - 2 * margin:g}",
                  height=f"{sheet.height - 2 * margin:g}", id="margin", **note, **{"stroke-dasharray": "10 6"})
    for remnant in remnants:
        ET.SubElement(root, "rect", x=f"{remnant['x']:g}", y=f"{sheet.height - remnant['y'] - remnant['height']:g}",
                      width=f"{remnant['width']:g}", height=f"{remnant['height']:g}", **note,
                      **{"stroke-dasharray": "30 10"})
    for placement in sheet.placements:
        part = parts[placement.part]
        group = ET.SubElement(root, "g", id=part.id, **{"class": f"part {part.kind}"})
        ET.SubElement(group, "title").text = part.id
        layers = [("CUT-OUTER", [part.outline], True), ("CUT-INNER", part.inner_contours(), True),
                  ("ENGRAVE-MARK", part.marks, False), ("ENGRAVE-TEXT", part.text, False)]
        for layer, contours, closed in layers:
            if len(contours):
                placed = [place(flatten_contour(c) if closed else np.asarray(c, dtype=float), placement) for c in contours]
                ET.SubElement(group, "path", d=_path_data(placed, sheet.height, closed), fill="none",
                              stroke=colour[layer], **{"stroke-width": STROKE, "class": layer})
        outline = place(flatten_contour(part.outline), placement)
        low, high = outline.min(axis=0)[:2], outline.max(axis=0)[:2]
        size = float(np.clip(0.35 * min(high - low), 4.0, 60.0))
        label = ET.SubElement(group, "text", x=f"{(low[0] + high[0]) / 2:.1f}",
                              y=f"{sheet.height - (low[1] + high[1]) / 2:.1f}", fill=colour["SHEET"], **{
                                  "font-size": f"{size:.1f}", "font-family": "sans-serif",
                                  "text-anchor": "middle", "dominant-baseline": "middle"})
        label.text = part.label or part.id
    for cut in sheet.common_cuts:
        ET.SubElement(root, "line", x1=f"{cut.start[0]:.2f}", y1=f"{sheet.height - cut.start[1]:.2f}",
                      x2=f"{cut.end[0]:.2f}", y2=f"{sheet.height - cut.end[1]:.2f}", stroke=colour["CUT-OUTER"],
                      **{"stroke-width": STROKE, "class": "CUT-OUTER"})
    return root


def write_sheet_svgs(nesting: Nesting, partset: PartSet, folder: str | os.PathLike) -> list[Path]:
    """Write `<sheet id>.svg` for every sheet into `folder`; return the paths written."""
    parts = {p.id: p for p in partset.parts}
    folder = Path(folder)
    written = []
    for sheet in nesting.sheets:
        remnants = [r for r in nesting.remnants if r.get("sheet") == sheet.id]
        tree = ET.ElementTree(sheet_svg(sheet, parts, nesting.margin, remnants))
        ET.indent(tree)
        path = folder / f"{file_stem(sheet.id)}.svg"
        with atomic_output(path, "wb") as handle:
            tree.write(handle, encoding="utf-8", xml_declaration=True)
        written.append(path)
    return written
