"""Independent check of a nesting: every part placed once, inside its sheet's usable area, never too close to another.

It shares nothing with the placement code but the file formats: it rebuilds each placed outline from
parts.json with its own transform (shapely affinity), finely flattened arcs, and finds neighbours with
an STR-tree, so a bug in the nester cannot hide itself here.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Polygon

from fabline.errors import FablineError
from fabline.nest.layout import Nesting, Placement
from fabline.unroll.parts import Part, PartSet, flatten_contour

# Arcs are flattened far finer than the nester's own geometry, and distances may fall short by this much (mm).
ARC_TOLERANCE = 0.01
DISTANCE_TOLERANCE = 0.02
QUERY_CHUNK = 256  # placements whose neighbours are looked up at once: the pairs found stay few even when all stack
MAX_SHEET_PROBLEMS = 100  # a sheet's pairs are checked until this many problems are found


def check_fit(nesting: Nesting, partset: PartSet, source: str) -> None:
    """Refuse (FablineError naming the sheet) a sheet whose placed parts' material covers more area than the sheet
    has: they cannot fit however they are placed, and checking them pair by pair would take time and memory as their
    square. Material, not outline: a part nested in another's hole covers no area of its own."""
    areas = {p.id: outline_area(p.outline) - sum(outline_area(h) for h in p.holes) for p in partset.parts}
    for sheet in nesting.sheets:
        placed = sum(areas.get(placement.part, 0.0) for placement in sheet.placements)
        if placed > sheet.width * sheet.height:
            raise FablineError(f"{source}: sheet {sheet.id}: its {len(sheet.placements)} placements cover {placed:.4g} mm², "
                               f"the sheet ({sheet.width:g} x {sheet.height:g} mm) only {sheet.width * sheet.height:.4g} "
                               "mm²: they cannot all fit on it (a part placed over and over?)")


def outline_area(contour: np.ndarray) -> float:
    """The area a closed contour with bulges encloses, exactly: the polygon of its vertices and each arc's segment."""
    contour = np.asarray(contour, dtype=float)
    p0, p1 = contour[:-1, :2], contour[1:, :2]
    area = 0.5 * float(np.sum(p0[:, 0] * p1[:, 1] - p1[:, 0] * p0[:, 1]))
    if contour.shape[1] > 2:
        bulge = contour[:-1, 2]
        angle = 4.0 * np.arctan(np.abs(bulge[bulge != 0]))
        chord = np.linalg.norm((p1 - p0)[bulge != 0], axis=1)
        radius = chord / (2.0 * np.sin(angle / 2.0))
        area += float(np.sum(np.sign(bulge[bulge != 0]) * radius**2 / 2.0 * (angle - np.sin(angle))))
    return abs(area)


def _part_polygon(part: Part, outline: np.ndarray, with_holes: bool) -> Polygon:
    """The part's flattened `outline` (and holes when other parts may lie in them), where the part file puts it."""
    holes = [flatten_contour(h, ARC_TOLERANCE) for h in part.holes] if with_holes else []
    return shapely.make_valid(Polygon(outline, holes))


def _placed_polygon(polygon: Polygon, placement: Placement) -> Polygon:
    """A part's polygon rotated about its origin, then translated to the placement."""
    rotated = affinity.rotate(polygon, placement.rotation, origin=(0.0, 0.0), use_radians=False)
    return affinity.translate(rotated, placement.x, placement.y)


def validate_nesting(nesting: Nesting, partset: PartSet) -> list[str]:
    """All problems found, one line each naming the sheet and part; an empty list means the nesting is sound."""
    parts = {p.id: p for p in partset.parts}
    problems = [f"{name} is {value:g} mm: must not be negative" for name, value in
                (("kerf", nesting.kerf), ("gap", nesting.gap), ("margin", nesting.margin)) if value < 0]
    outlines = {p.id: flatten_contour(p.outline, ARC_TOLERANCE) for p in partset.parts}
    problems += [problem for part in partset.parts if (problem := _outline_problem(part, outlines[part.id]))]
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
        problems += _check_sheet(sheet, parts, outlines, nesting.margin, clearance, nesting.kerf, with_holes)
    return problems


def _sheets_named(sheets: list[str]) -> str:
    """'sheet S1', 'sheets S1 and S2', 'sheet S1 twice'... for a part's placements."""
    counts = Counter(sheets)
    named = [f"{s}" + (f" {counts[s]} times" if counts[s] > 1 else "") for s in counts]
    return ("sheet " if len(named) == 1 else "sheets ") + ", ".join(named)


def _outline_problem(part: Part, outline: np.ndarray) -> str:
    """Why a part's (flattened) outline cannot be cut (empty or crossing itself, like a bow-tie), or ""."""
    polygon = Polygon(outline)
    reason = shapely.is_valid_reason(polygon)
    if reason.startswith("Self-intersection"):
        return f"part {part.id}: outline crosses itself ({reason})"
    if polygon.area <= 1e-9:
        return f"part {part.id}: outline encloses no area"
    return ""


def _check_sheet(sheet, parts: dict[str, Part], outlines: dict[str, np.ndarray], margin: float, clearance: float, kerf: float,
                 with_holes: bool) -> list[str]:
    """Problems on one sheet: grain, outside the usable area (the sheet less its margin), and pairs closer
    than the clearance (the kerf alone for pairs that share a common cut)."""
    problems = []
    placed: list[tuple[str, Polygon]] = []
    polygons: dict[str, Polygon] = {}
    for placement in sheet.placements:
        part = parts.get(placement.part)
        if part is None:
            continue  # named by `validate_nesting`: placed but not in the parts file
        if part.grain and round(placement.rotation % 360.0, 6) not in (0.0, 180.0):
            problems.append(f"sheet {sheet.id}: part {part.id} is grain-bound but rotated {placement.rotation:g} deg")
        if part.id not in polygons:
            polygons[part.id] = _part_polygon(part, outlines[part.id], with_holes)
        polygon = _placed_polygon(polygons[part.id], placement)
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
    for a, b in _near_pairs(tree, geometries, max(clearance, kerf) - DISTANCE_TOLERANCE):
        if len(problems) >= MAX_SHEET_PROBLEMS:
            problems.append(f"sheet {sheet.id}: stopped after {MAX_SHEET_PROBLEMS} problems (fix these first)")
            break
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


def _near_pairs(tree: shapely.STRtree, geometries: list[Polygon], reach: float):
    """Pairs (a, b), a < b, of placed polygons within `reach` (touching if it is not positive), found QUERY_CHUNK
    placements at a time so that parts stacked on each other do not ask for all their pairs at once."""
    for start in range(0, len(geometries), QUERY_CHUNK):
        chunk = geometries[start:start + QUERY_CHUNK]
        if reach <= 0:
            left, right = tree.query(chunk, predicate="intersects")
        else:
            left, right = tree.query(chunk, predicate="dwithin", distance=reach)
        left = left + start
        keep = left < right
        yield from zip(left[keep].tolist(), right[keep].tolist())
