"""Independent check of a nesting: every part placed once, inside its sheet's usable area, never too close to another.

It shares nothing with the placement code but the file formats: it rebuilds each placed outline from
parts.json with its own transform (shapely affinity), finely flattened arcs, and finds neighbours with
an STR-tree, so a bug in the nester cannot hide itself here.
"""

from __future__ import annotations

from collections import Counter

import shapely
from shapely import affinity
from shapely.geometry import Polygon

from fabline.nest.layout import Nesting, Placement
from fabline.unroll.parts import Part, PartSet, flatten_contour

# Arcs are flattened far finer than the nester's own geometry, and distances may fall short by this much (mm).
ARC_TOLERANCE = 0.01
DISTANCE_TOLERANCE = 0.02


def _placed_polygon(part: Part, placement: Placement, with_holes: bool) -> Polygon:
    """The part's outline (and holes when other parts may lie in them) rotated about its origin, then translated."""
    outline = flatten_contour(part.outline, ARC_TOLERANCE)
    holes = [flatten_contour(h, ARC_TOLERANCE) for h in part.holes] if with_holes else []
    polygon = shapely.make_valid(Polygon(outline, holes))
    rotated = affinity.rotate(polygon, placement.rotation, origin=(0.0, 0.0), use_radians=False)
    return affinity.translate(rotated, placement.x, placement.y)


def validate_nesting(nesting: Nesting, partset: PartSet) -> list[str]:
    """All problems found, one line each naming the sheet and part; an empty list means the nesting is sound."""
    parts = {p.id: p for p in partset.parts}
    problems = [f"{name} is {value:g} mm: must not be negative" for name, value in
                (("kerf", nesting.kerf), ("gap", nesting.gap), ("margin", nesting.margin)) if value < 0]
    problems += [problem for part in partset.parts if (problem := _outline_problem(part))]
    where: dict[str, list[str]] = {}
    for sheet in nesting.sheets:
        for placement in sheet.placements:
            where.setdefault(placement.part, []).append(sheet.id)
    for pid in parts:
        if pid not in where:
            problems.append(f"part {pid}: not placed on any sheet")
        elif len(where[pid]) > 1:
            problems.append(f"part {pid}: placed {len(where[pid])} times (on {_sheets_named(where[pid])})")
    for pid, sheets in where.items():
        if pid not in parts:
            problems.append(f"part {pid}: placed (on {_sheets_named(sheets)}) but not in the parts file")
    with_holes = bool(nesting.summary.get("settings", {}).get("fill_holes", False))
    clearance = nesting.gap + nesting.kerf
    for sheet in nesting.sheets:
        problems += _check_sheet(sheet, parts, nesting.margin, clearance, nesting.kerf, with_holes)
    return problems


def _sheets_named(sheets: list[str]) -> str:
    """'sheet S1', 'sheets S1 and S2', 'sheet S1 twice'... for a part's placements."""
    counts = Counter(sheets)
    named = [f"{s}" + (f" {counts[s]} times" if counts[s] > 1 else "") for s in counts]
    return ("sheet " if len(named) == 1 else "sheets ") + ", ".join(named)


def _outline_problem(part: Part) -> str:
    """Why a part's outline cannot be cut (empty or crossing itself, like a bow-tie), or ""."""
    polygon = Polygon(flatten_contour(part.outline, ARC_TOLERANCE))
    reason = shapely.is_valid_reason(polygon)
    if reason.startswith("Self-intersection"):
        return f"part {part.id}: outline crosses itself ({reason})"
    if polygon.area <= 1e-9:
        return f"part {part.id}: outline encloses no area"
    return ""


def _check_sheet(sheet, parts: dict[str, Part], margin: float, clearance: float, kerf: float,
                 with_holes: bool) -> list[str]:
    """Problems on one sheet: grain, outside the usable area (the sheet less its margin), and pairs closer
    than the clearance (the kerf alone for pairs that share a common cut)."""
    problems = []
    placed: list[tuple[str, Polygon]] = []
    for placement in sheet.placements:
        part = parts.get(placement.part)
        if part is None:
            continue  # named by `validate_nesting`: placed but not in the parts file
        if part.grain and round(placement.rotation % 360.0, 6) not in (0.0, 180.0):
            problems.append(f"sheet {sheet.id}: part {part.id} is grain-bound but rotated {placement.rotation:g} deg")
        polygon = _placed_polygon(part, placement, with_holes)
        minx, miny, maxx, maxy = polygon.bounds
        overshoot = max(margin - minx, margin - miny, maxx - (sheet.width - margin), maxy - (sheet.height - margin))
        if overshoot > DISTANCE_TOLERANCE:
            problems.append(f"sheet {sheet.id}: part {part.id} lies outside the usable area "
                            f"(margin {margin:g} mm) by {overshoot:.2f} mm")
        placed.append((part.id, polygon))
    on_sheet = {pid for pid, _ in placed}
    for cut in sheet.common_cuts:
        missing = [pid for pid in cut.parts if pid not in on_sheet]
        if missing:
            problems.append(f"sheet {sheet.id}: common cut names part {missing[0]}, which is not on this sheet")
    if not placed:
        return problems
    shared = {frozenset(cut.parts) for cut in sheet.common_cuts}
    geometries = [g for _, g in placed]
    tree = shapely.STRtree(geometries)
    reach = max(clearance, kerf) - DISTANCE_TOLERANCE
    if reach <= 0:
        left, right = tree.query(geometries, predicate="intersects")
    else:
        left, right = tree.query(geometries, predicate="dwithin", distance=reach)
    for a, b in zip(left.tolist(), right.tolist()):
        if a >= b:
            continue
        (id_a, geom_a), (id_b, geom_b) = placed[a], placed[b]
        distance = geom_a.distance(geom_b)
        needed = kerf if frozenset((id_a, id_b)) in shared else clearance
        overlap = geom_a.intersection(geom_b).area
        if overlap > 1e-6:
            problems.append(f"sheet {sheet.id}: parts {id_a} and {id_b} overlap by {overlap:.4g} mm²")
        elif distance < needed - DISTANCE_TOLERANCE:
            problems.append(f"sheet {sheet.id}: parts {id_a} and {id_b} are {distance:.3f} mm apart, "
                            f"need {needed:g} mm (gap + kerf)")
    return problems
