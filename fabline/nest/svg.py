"""One SVG picture per nested sheet: sheet, margin, every part outline with its holes, labelled, and remnants.

Drawn in sheet millimetres with the y axis flipped so the picture shows the sheet as seen from above
with its origin at the lower-left corner, as in nesting.json.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from fabline.fileio import atomic_output
from fabline.nest.layout import Nesting, Sheet, place, sheet_file_stem
from fabline.unroll.parts import Part, PartSet, flatten_contour

PART_FILL = {"strip": "#9ecae1", "curved-strip": "#a1d99b", "washer": "#fdae6b", "clamp": "#bcbddc", "joint": "#fc9272"}


def _path_data(contours: list[np.ndarray], height: float) -> str:
    """SVG path data of closed contours in sheet mm, y flipped."""
    return " ".join("M " + " L ".join(f"{x:.2f},{height - y:.2f}" for x, y in c[:-1]) + " Z" for c in contours)


def sheet_svg(sheet: Sheet, parts: dict[str, Part], margin: float, remnants: list[dict]) -> ET.Element:
    """The SVG element tree of one sheet."""
    root = ET.Element("svg", xmlns="http://www.w3.org/2000/svg", width=f"{sheet.width / 10:g}mm",
                      height=f"{sheet.height / 10:g}mm", viewBox=f"0 0 {sheet.width:g} {sheet.height:g}")
    ET.SubElement(root, "title").text = f"sheet {sheet.id} ({sheet.stock}) {sheet.width:g} x {sheet.height:g} mm"
    ET.SubElement(root, "rect", x="0", y="0", width=f"{sheet.width:g}", height=f"{sheet.height:g}",
                  fill="#f4f4f4", stroke="#333", **{"stroke-width": "2"})
    ET.SubElement(root, "rect", x=f"{margin:g}", y=f"{margin:g}", width=f"{sheet.width - 2 * margin:g}",
                  height=f"{sheet.height - 2 * margin:g}", fill="none", stroke="#999",
                  **{"stroke-width": "1", "stroke-dasharray": "10 6"})
    for remnant in remnants:
        ET.SubElement(root, "rect", x=f"{remnant['x']:g}", y=f"{sheet.height - remnant['y'] - remnant['height']:g}",
                      width=f"{remnant['width']:g}", height=f"{remnant['height']:g}", fill="none",
                      stroke="#2ca25f", **{"stroke-width": "3", "stroke-dasharray": "30 10"})
    for placement in sheet.placements:
        part = parts[placement.part]
        contours = [place(flatten_contour(c), placement) for c in [part.outline, *part.holes]]
        group = ET.SubElement(root, "g")
        ET.SubElement(group, "title").text = part.id
        ET.SubElement(group, "path", d=_path_data(contours, sheet.height), fill=PART_FILL.get(part.kind, "#ccc"),
                      stroke="#000", **{"stroke-width": "0.5", "fill-rule": "evenodd"})
        low, high = contours[0].min(axis=0), contours[0].max(axis=0)
        size = float(np.clip(0.35 * min(high - low), 4.0, 60.0))
        label = ET.SubElement(group, "text", x=f"{(low[0] + high[0]) / 2:.1f}",
                              y=f"{sheet.height - (low[1] + high[1]) / 2:.1f}", **{
                                  "font-size": f"{size:.1f}", "font-family": "sans-serif",
                                  "text-anchor": "middle", "dominant-baseline": "middle"})
        label.text = part.label or part.id
    for cut in sheet.common_cuts:
        ET.SubElement(root, "line", x1=f"{cut.start[0]:.2f}", y1=f"{sheet.height - cut.start[1]:.2f}",
                      x2=f"{cut.end[0]:.2f}", y2=f"{sheet.height - cut.end[1]:.2f}", stroke="#e6550d",
                      **{"stroke-width": "1.5"})
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
        path = folder / f"{sheet_file_stem(sheet.id)}.svg"
        with atomic_output(path, "wb") as handle:
            tree.write(handle, encoding="utf-8", xml_declaration=True)
        written.append(path)
    return written
