"""The bill of materials of a nested job: sheets (size, thickness, material, mass, scrap share, cost where the
materials file gives a price) and the hardware the parts call for (bolts, nuts, seam screws, cable clamps).

Masses are sheet area x thickness x the material's density; the parts' share is their net area (outline less
holes and inner cuts) over the sheet's. Hardware is counted from what parts.json says of each part: a washer pair
(`meta.node`) is one crossing node with one carriage bolt and nut; a singularity joint's plates share a bolt per
bolt hole; strips meet at seams (`meta.joins`), screwed through the holes of the seam's overlap; a clamp has a
square bolt hole and a cable hole at each arm's end; an edge member's node is one bolt through its top and bottom
bars and a spacer tube between them (the thesis's edge detail).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import shapely

from fabline.mechanics.materials import Material
from fabline.nest.layout import Nesting
from fabline.unroll.parts import Part, PartSet, flatten_contour


def net_area(part: Part) -> float:
    """The part's area in mm2: its outline less its holes and inner cuts."""
    outline = shapely.Polygon(flatten_contour(part.outline)[:, :2])
    cuts = [shapely.Polygon(flatten_contour(c)[:, :2]) for c in part.inner_contours()]
    return float(outline.area - sum(c.area for c in cuts))


def hardware(parts: list[Part], screw_hole_mm: float | None) -> list[dict[str, Any]]:
    """The fasteners the parts call for: rows of item, count, and what one is per."""
    washer_nodes = {p.meta.get("node") for p in parts if p.kind == "washer"}
    joint_bolts = {p.meta.get("node"): len(p.holes) for p in parts if p.kind == "joint"}
    seams = sum(1 for p in parts for join in ((p.meta.get("joins") or {}).get("start"),)
                if join and join.get("kind") == "seam")
    screw_holes = sum(1 for p in parts if p.kind in ("strip", "curved-strip") for h in p.holes
                      if screw_hole_mm is None or abs(float(np.ptp(np.asarray(h)[:, 0])) - screw_hole_mm) < 0.05)
    clamps = [p for p in parts if p.kind == "clamp"]
    cable_holes = sum(len(p.holes) - 1 for p in clamps)
    bolts = len(washer_nodes) + sum(joint_bolts.values())
    rows = [{"item": "carriage bolt with nut", "count": bolts,
             "per": f"1 per crossing node ({len(washer_nodes)} nodes with star washers)"
                    + (f", {sum(joint_bolts.values())} in {len(joint_bolts)} singularity joints" if joint_bolts else "")},
            {"item": "seam screw with nut", "count": screw_holes // 2,
             "per": f"{screw_holes // 2 / seams:g} per seam ({seams} seams)" if seams else "no seams"},
            {"item": "cable clamp", "count": len(clamps),
             "per": f"{cable_holes / len(clamps):g} cable holes each: the two diagonal cables pass through it"
             if clamps else "no clamps"}]
    # one bolt per edge node, also where two edge members meet at a corner node (through all four bars)
    edge_nodes = {node["id"] for p in parts if p.meta.get("member") == "edge" for node in p.nodes}
    if edge_nodes:
        rows.append({"item": "edge bolt with nut and spacer tube", "count": len(edge_nodes),
                     "per": "1 per lamella end on the edge members: through the top bars, a spacer tube and the "
                            "bottom bars"})
    return rows


def edge_members(parts: list[Part], thickness: float, kg_per_mm3: float) -> dict[str, Any] | None:
    """The edge members' bars (cut with the sheets): how many, their length along the bar and their mass."""
    bars = [p for p in parts if p.meta.get("member") == "edge"]
    if not bars:
        return None
    return {"bars": len(bars), "length_m": round(sum(p.meta["length_mm"] for p in bars) / 1000.0, 3),
            "mass_kg": round(sum(net_area(p) for p in bars) * thickness * kg_per_mm3, 2)}


def bill_of_materials(nesting: Nesting, partset: PartSet, material: Material) -> dict[str, Any]:
    """Sheets with mass and scrap share, totals (cost where the material has a price), and the hardware counts."""
    thickness = float(partset.profile.get("t", 0.0))
    kg_per_mm3 = material.density * 1e-9
    parts = {p.id: p for p in partset.parts}
    areas: dict[str, float] = {}
    sheets = []
    for sheet in nesting.sheets:
        used = sum(areas.setdefault(p.part, net_area(parts[p.part])) for p in sheet.placements)
        area = sheet.width * sheet.height
        sheets.append({"id": sheet.id, "width_mm": sheet.width, "height_mm": sheet.height, "thickness_mm": thickness,
                       "material": material.name, "mass_kg": round(area * thickness * kg_per_mm3, 2),
                       "parts_mass_kg": round(used * thickness * kg_per_mm3, 2),
                       "scrap_share": round(1.0 - used / area, 4)})
    mass = sum(s["mass_kg"] for s in sheets)
    parts_mass = sum(s["parts_mass_kg"] for s in sheets)
    totals = {"sheets": len(sheets), "mass_kg": round(mass, 1), "parts_mass_kg": round(parts_mass, 1),
              "scrap_share": round(1.0 - parts_mass / mass, 4) if mass else 0.0,
              "cost": None if material.price_per_kg is None else round(mass * material.price_per_kg, 2),
              "currency": material.currency}
    screw_hole = (partset.report.get("options") or {}).get("screw_hole_mm")
    rows = hardware(partset.parts, screw_hole)
    edges = edge_members(partset.parts, thickness, kg_per_mm3)
    if edges:
        rows.append({"item": "edge member bars (cut with the sheets)", "count": edges["bars"],
                     "per": f"{edges['length_m']:.1f} m of bar, {edges['mass_kg']:.1f} kg"})
    return {"material": material.name, "density_kg_m3": material.density, "thickness_mm": thickness,
            "price_per_kg": material.price_per_kg, "sheets": sheets, "totals": totals,
            "hardware": rows, "edge_members": edges}
