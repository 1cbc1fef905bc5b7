"""The bill of materials of a nested job: sheets (size, thickness, material, mass, scrap share, cost where the
materials file gives a price) and the hardware the parts call for (bolts, nuts, seam screws, cable clamps).

Masses are sheet area x thickness x the material's density; the parts' share is their net area (outline less
holes and inner cuts) over the sheet's. Hardware is counted from what parts.json says of each part: a washer pair
(`meta.node`) is one crossing node with one carriage bolt and nut; a singularity joint's plates share a bolt per
bolt hole; strips meet at seams (`meta.joins`), screwed through the holes of the seam's overlap; a clamp has a
square bolt hole and a cable hole at each arm's end; an edge member's node is one bolt through its top and bottom
bars (the node's carriage bolt where it has washers: one bolt per axis) and a lamella end's end-fix holes take a
bolt and a square tube cleat (the thesis's edge detail).

`items` is the same bill as rows of one table, also written as bom.csv beside the report (`BOM_COLUMNS`): the sheets,
the cut parts by kind, every fastener by size and length (`fabline.jobs.fasteners`), and each cable run with its
cut length, its mass from the cable declared in hardware.toml.
"""

from __future__ import annotations

import csv
import io
import os
from collections import Counter
from typing import Any

import numpy as np
import shapely

from fabline.fileio import atomic_output
from fabline.jobs.fasteners import (bolt_row, edge_fasteners, end_fix_count, end_fix_fasteners, fastener_rows,
                                    hole_across)
from fabline.mechanics.hardware import Catalogue, load_catalogue
from fabline.mechanics.materials import Material
from fabline.nest.layout import Nesting
from fabline.unroll.parts import Part, PartSet, flatten_contour


BOM_NAME = "bom.csv"
BOM_COLUMNS = ("item", "kind", "size", "length_mm", "count", "unit_mass_kg", "total_mass_kg", "per")


def net_area(part: Part) -> float:
    """The part's area in mm2: its outline less its holes and inner cuts."""
    outline = shapely.Polygon(flatten_contour(part.outline)[:, :2])
    cuts = [shapely.Polygon(flatten_contour(c)[:, :2]) for c in part.inner_contours()]
    return float(outline.area - sum(c.area for c in cuts))


def hardware(parts: list[Part], screw_hole_mm: float | None) -> list[dict[str, Any]]:
    """The fasteners the parts call for: rows of item, count, and what one is per. Each bolt axis counts once: at a
    lamella end on the edge members the node's carriage bolt is the edge bolt, longer, through both bars."""
    washer_nodes = {p.meta.get("node") for p in parts if p.kind == "washer"}
    joint_bolts = {p.meta.get("node"): len(p.holes) for p in parts if p.kind == "joint"}
    seams = sum(1 for p in parts for join in ((p.meta.get("joins") or {}).get("start"),)
                if join and join.get("kind") == "seam")
    strips = [p for p in parts if p.kind in ("strip", "curved-strip")]
    screw_holes = sum(1 for p in strips for h in p.holes if _screw(h, screw_hole_mm))
    end_fixes = end_fix_count(parts)
    clamps = [p for p in parts if p.kind == "clamp"]
    cable_holes = sum(len(p.holes) - 1 for p in clamps)
    # one bolt per edge node, also where two edge members meet at a corner node (through all four bars)
    edge_nodes = {node["id"] for p in parts if p.meta.get("member") == "edge" for node in p.nodes}
    carriage = washer_nodes - edge_nodes
    bolts = len(carriage) + sum(joint_bolts.values())
    rows = [{"item": "carriage bolt with nut", "count": bolts,
             "per": f"1 per crossing node ({len(carriage)} nodes with star washers"
                    + (" and no edge bolt)" if edge_nodes else ")")
                    + (f", {sum(joint_bolts.values())} in {len(joint_bolts)} singularity joints" if joint_bolts else "")},
            {"item": "seam screw with nut", "count": screw_holes // 2,
             "per": f"{screw_holes // 2 / seams:g} per seam ({seams} seams)" if seams else "no seams"},
            {"item": "cable clamp", "count": len(clamps),
             "per": f"{cable_holes / len(clamps):g} cable holes each: the two diagonal cables pass through it"
             if clamps else "no clamps"}]
    if edge_nodes:
        shared = len(edge_nodes & washer_nodes)
        rows.append({"item": "edge bolt with nut and spacer tube", "count": len(edge_nodes),
                     "per": "1 per edge member bar hole, through the top bars, a spacer tube and the bottom bars"
                            + (f"; at {shared} nodes with star washers it is the node's carriage bolt, longer"
                               if shared else "")})
    if end_fixes:
        rows.append({"item": "end-fix bolt with nut and square tube cleat", "count": end_fixes,
                     "per": "1 per lamella end: through the end-fix holes of its strips and the tube between them, "
                            "which the edge bars clamp"})
    return rows


def _screw(hole: np.ndarray, screw_hole_mm: float | None) -> bool:
    """Whether a strip's hole is a seam screw's (its diameter within 0.05 mm; every hole when the size is unknown)."""
    return screw_hole_mm is None or abs(float(np.ptp(np.asarray(hole)[:, 0])) - screw_hole_mm) < 0.05


def edge_members(parts: list[Part], thickness: float, kg_per_mm3: float) -> dict[str, Any] | None:
    """The edge members' bars (cut with the sheets): how many, their length along the bar and their mass."""
    bars = [p for p in parts if p.meta.get("member") == "edge"]
    if not bars:
        return None
    return {"bars": len(bars), "length_m": round(sum(p.meta["length_mm"] for p in bars) / 1000.0, 3),
            "mass_kg": round(sum(net_area(p) for p in bars) * thickness * kg_per_mm3, 2)}


def sheet_rows(nesting: Nesting, partset: PartSet, material: Material) -> list[dict[str, Any]]:
    """Per sheet of `nesting` (the parts of `partset`, at its profile's thickness t): size, mass, parts' mass, scrap."""
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
    return sheets


def bill_of_materials(nesting: Nesting, partset: PartSet, material: Material, plate_nesting: Nesting | None = None,
                      plate_material: Material | None = None) -> dict[str, Any]:
    """Sheets with mass and scrap share, totals (cost where the material has a price), the hardware counts and the
    bill's rows (`items`); the plate parts (supports) on their own sheets (`plate_nesting`, of `plate_material`)."""
    thickness = float(partset.profile.get("t", 0.0))
    kg_per_mm3 = material.density * 1e-9
    sheets = sheet_rows(nesting, partset, material)
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
    catalogue = load_catalogue()
    h = float(partset.profile.get("h", 0.0))
    plates = partset.plates
    fins = {p.meta["node"]: float(plates.profile["t"]) for p in plates.parts if p.meta.get("plate") == "fin"} if plates else {}
    items = (sheet_items(sheets) + part_items(partset.parts, thickness, kg_per_mm3)
             + fastener_rows(partset.parts, h, thickness, screw_hole, catalogue, fins)
             + edge_fasteners(partset.parts, h, thickness, catalogue, fins)
             + end_fix_fasteners(partset.parts, h, thickness, catalogue)
             + cable_items(partset.cables, catalogue) + coupler_items(partset.couplers, thickness, catalogue))
    plate_entry = None
    if plates and plate_nesting is not None and plate_material is not None:
        plate_sheets = sheet_rows(plate_nesting, plates, plate_material)
        plate_t = float(plates.profile["t"])
        supports = support_items(plates.parts, plate_t, plate_material.density * 1e-9, catalogue)
        items += sheet_items(plate_sheets) + supports
        plate_entry = {"material": plate_material.name, "thickness_mm": plate_t, "sheets": plate_sheets,
                       "parts": len(plates.parts), "supports": len(fins),
                       "mass_kg": round(sum(s["mass_kg"] for s in plate_sheets), 1),
                       "parts_mass_kg": round(sum(s["parts_mass_kg"] for s in plate_sheets), 1)}
    return {"material": material.name, "density_kg_m3": material.density, "thickness_mm": thickness,
            "price_per_kg": material.price_per_kg, "sheets": sheets, "totals": totals,
            "hardware": rows, "edge_members": edges, "items": items,
            "cables": cable_totals(partset.cables, catalogue) if partset.cables else None, "plates": plate_entry}


def coupler_items(couplers: list[dict], t: float, catalogue: Catalogue) -> list[dict[str, Any]]:
    """The shear blocks (sawn hardwood, by size; mass from the declared density) and their bolts: through strip,
    block, strip with a washer under head and nut."""
    rows = []
    sizes = Counter(tuple(c["block_mm"]) for c in couplers)
    wood = catalogue.coupler
    for (length, height, width), count in sorted(sizes.items()):
        unit = length * height * width * wood["density"] * 1e-9
        rows.append({"item": f"shear block {length:g} x {height:g} x {width:g}", "kind": "coupler",
                     "size": f"{length:g}x{height:g}x{width:g}", "length_mm": length, "count": count,
                     "unit_mass_kg": round(unit, 4), "total_mass_kg": round(unit * count, 3),
                     "per": f"{wood['description']}, sawn: between a pair's strips next to a support"})
    bolts = Counter((c["bolt_hole_mm"], c["block_mm"][2]) for c in couplers for _ in range(c["bolts"]))
    rows.extend(bolt_row("hex bolt with 2 washers and nut", catalogue.bolt("hex", hole, 2.0 * t + width, washers=2),
                         count, "shear block: 2 through strip, block, strip")
                for (hole, width), count in sorted(bolts.items()))
    return rows


def support_items(plates: list[Part], thickness: float, kg_per_mm3: float, catalogue: Catalogue) -> list[dict[str, Any]]:
    """The support brackets' plates (fins and base plates, each its own size) and their anchor bolts."""
    rows = []
    for kind in ("fin", "base"):
        members = [p for p in plates if p.meta.get("plate") == kind]
        if not members:
            continue
        mass = sum(net_area(p) for p in members) * thickness * kg_per_mm3
        rows.append({"item": f"support {kind} plate", "kind": "cut part", "size": f"t {thickness:g}",
                     "length_mm": None, "count": len(members), "unit_mass_kg": round(mass / len(members), 4),
                     "total_mass_kg": round(mass, 2),
                     "per": "support node: cut from the plate sheets" + (", welded on its base plate" if kind == "fin" else "")})
    bases = [p for p in plates if p.meta.get("plate") == "base"]
    if bases:
        size = catalogue.size_for_hole(min(hole_across(h) for p in bases for h in p.holes))
        rows.append({"item": f"anchor bolt {size.name}", "kind": "fastener", "size": size.name, "length_mm": None,
                     "count": sum(len(p.holes) for p in bases), "unit_mass_kg": None, "total_mass_kg": None,
                     "per": "base plate hole into the footing (length and kind by the footing)"})
    return rows


def sheet_items(sheets: list[dict]) -> list[dict[str, Any]]:
    """One row per sheet size, thickness and material: how many and their mass."""
    groups = Counter((s["width_mm"], s["height_mm"], s["thickness_mm"], s["material"]) for s in sheets)
    rows = []
    for (width, height, thickness, name), count in groups.items():
        unit = next(s["mass_kg"] for s in sheets if (s["width_mm"], s["height_mm"], s["thickness_mm"],
                                                     s["material"]) == (width, height, thickness, name))
        rows.append({"item": f"sheet {name}", "kind": "sheet", "size": f"{width:g}x{height:g}x{thickness:g}",
                     "length_mm": None, "count": count, "unit_mass_kg": unit, "total_mass_kg": round(unit * count, 2),
                     "per": "nested sheet"})
    return rows


def part_items(parts: list[Part], thickness: float, kg_per_mm3: float) -> list[dict[str, Any]]:
    """One row per kind of cut part (edge bars apart from strips): how many, their mass (net area x t x density; the
    unit mass is their mean) and, for strips and bars, their total length."""
    groups: dict[str, list[Part]] = {}
    for part in parts:
        groups.setdefault("edge bar" if part.meta.get("member") == "edge" else part.kind, []).append(part)
    rows = []
    for kind, members in groups.items():
        mass = sum(net_area(p) for p in members) * thickness * kg_per_mm3
        length = sum(float(p.meta.get("length_mm", 0.0)) for p in members)
        rows.append({"item": kind, "kind": "cut part", "size": f"t {thickness:g}", "length_mm": None,
                     "count": len(members), "unit_mass_kg": round(mass / len(members), 5),
                     "total_mass_kg": round(mass, 2),
                     "per": "cut from the sheets" + (f", {length / 1000.0:.1f} m in all" if length else "")})
    return rows


def cable_items(cables: list[dict], catalogue: Catalogue) -> list[dict[str, Any]]:
    """One row per cable run (cut length, mass from the declared cable) and the end stops, two per run."""
    cable = catalogue.cable
    rows = [{"item": f"cable {run['id']}", "kind": "cable", "size": f"{cable.diameter:g} mm",
             "length_mm": run["cut_length_mm"], "count": 1,
             "unit_mass_kg": round(run["cut_length_mm"] / 1000.0 * cable.kg_per_m, 3),
             "total_mass_kg": round(run["cut_length_mm"] / 1000.0 * cable.kg_per_m, 3),
             "per": f"{len(run['clamps'])} clamps {run['nodes'][0]} to {run['nodes'][-1]}, geometric "
                    f"{run['geometric_length_mm']:.1f} mm"} for run in cables]
    if cables:
        rows.append({"item": f"cable {cable.end_fitting}", "kind": "cable fitting", "size": f"{cable.diameter:g} mm",
                     "length_mm": None, "count": 2 * len(cables), "unit_mass_kg": None, "total_mass_kg": None,
                     "per": "cable end, behind the end clamp's outer hole"})
    return rows


def cable_totals(cables: list[dict], catalogue: Catalogue) -> dict[str, Any]:
    """The cables in one line of figures: runs, total geometric and cut length (m), mass (kg), the cable."""
    cut = sum(r["cut_length_mm"] for r in cables) / 1000.0
    return {"runs": len(cables), "geometric_length_m": round(sum(r["geometric_length_mm"] for r in cables) / 1000.0, 3),
            "cut_length_m": round(cut, 3), "mass_kg": round(cut * catalogue.cable.kg_per_m, 2),
            "cable": catalogue.cable.description, "kg_per_m": round(catalogue.cable.kg_per_m, 4)}


def bom_csv(items: list[dict[str, Any]]) -> str:
    """The bill of materials as CSV text: a header row (`BOM_COLUMNS`), then one row per item; empty cells where a
    figure does not apply."""
    out = io.StringIO()
    writer = csv.DictWriter(out, BOM_COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: ("" if row.get(k) is None else row.get(k)) for k in BOM_COLUMNS} for row in items)
    return out.getvalue()


def write_bom_csv(items: list[dict[str, Any]], path: str | os.PathLike) -> None:
    """Write `bom_csv` to `path` atomically (temp file, then rename)."""
    with atomic_output(path) as handle:
        handle.write(bom_csv(items))
