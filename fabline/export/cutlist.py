"""The cut list: one CSV row per placed part (id, kind, lamella, sheet, position, seam partners, label), so a shop
can find, sort and assemble what came off the machine, or re-nest in its own CAM software."""

from __future__ import annotations

import csv
import io

from fabline.nest.layout import Nesting
from fabline.unroll.parts import Part

CUTLIST_NAME = "cutlist.csv"
CUTLIST_COLUMNS = ("part", "kind", "lamella", "sheet", "x_mm", "y_mm", "rotation_deg", "seam_partners", "label")


def seam_partners(part: Part) -> list[str]:
    """The parts a strip overlaps and is screwed to at its seams (parts.json `meta.joins`), start end first."""
    joins = part.meta.get("joins") or {}
    return [join["part"] for join in (joins.get("start"), joins.get("end"))
            if join and join.get("kind") == "seam" and join.get("part")]


def cutlist_rows(nesting: Nesting, parts: dict[str, Part]) -> list[dict]:
    """One row per placement in sheet and placement order; positions are the part frame's origin on the sheet,
    in mm to 0.1, and its rotation in degrees (as in nesting.json)."""
    rows = []
    for sheet in nesting.sheets:
        for placement in sheet.placements:
            part = parts[placement.part]
            rows.append({"part": part.id, "kind": part.kind, "lamella": part.lamella or "", "sheet": sheet.id,
                         "x_mm": f"{placement.x:.1f}", "y_mm": f"{placement.y:.1f}",
                         "rotation_deg": f"{placement.rotation:g}", "seam_partners": " ".join(seam_partners(part)),
                         "label": part.label})
    return rows


def cutlist_csv(nesting: Nesting, parts: dict[str, Part]) -> str:
    """The cut list as CSV text (a header row, then `cutlist_rows`)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, CUTLIST_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(cutlist_rows(nesting, parts))
    return out.getvalue()
