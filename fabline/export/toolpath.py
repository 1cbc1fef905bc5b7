"""Toolpaths for one sheet: kerf-compensated contours in cutting order, with lead-ins, tabs and common cuts.

Order: marks, then text, then inner contours (slots, holes), then outer contours, so no part comes
loose before its features are cut. Within each operation the travel is minimised by a nearest-neighbour
tour improved by 2-opt, and every closed contour starts at the vertex nearest its neighbours in the tour.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.spatial import cKDTree

from fabline.errors import FablineError
from fabline.export.contours import (FLATTEN_TOLERANCE, offset, remove_intervals, reverse, rotate_start,
                                     segment_lengths, signed_area, stack_contours, with_bulges)
from fabline.machine.profile import OPERATIONS, MachineProfile
from fabline.nest.layout import CommonCut, Placement, Sheet, place
from fabline.unroll.parts import Part, flatten_contour

MIN_TABS = 2              # a part held by one tab swings on it and can still tip up into the head
LEAD_IN_FRACTIONS = (1.0, 0.75, 0.5, 0.35, 0.25)   # a lead-in with no room is tried shorter, then at other vertices
NN_CANDIDATES = 16         # nearest points looked at per greedy step before widening the search
TWO_OPT_NEIGHBOURS = 16    # nearest path ends looked at per path end in 2-opt (about half are usable)
TWO_OPT_PASSES = 30


@dataclass
class Toolpath:
    """One continuous tool-on path in sheet coordinates: vertices [x, y, bulge], closed or open."""

    operation: str
    part: str
    contour: np.ndarray
    closed: bool
    lead_in: np.ndarray | None = None    # (2,) point where cutting starts before the contour, or None
    no_room: bool = False                # a lead-in was wanted, but none fits: the cut pierces on its contour

    @property
    def entry(self) -> np.ndarray:
        """Where the tool goes on."""
        return self.lead_in if self.lead_in is not None else self.contour[0, :2]

    @property
    def exit(self) -> np.ndarray:
        """Where the tool goes off."""
        return self.contour[-1, :2]


@dataclass
class ToolpathOptions:
    """Choices that shape the toolpaths (lengths in mm): kerf; lead-in length and the pierce point's clearance from
    every part on the sheet; tabs per outer contour (None: by part size, tabs_below and tab_every) and their width.

    One options object serves one job: it remembers each part's offset contours by part id.
    """

    kerf: float = 0.0
    lead_in: float = 0.0
    tabs: int | None = 0
    tab_width: float = 1.0
    pierce_clearance: float = 0.0
    tabs_below: float = 0.0
    tab_every: float = 250.0
    optimise: bool = True
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def for_profile(cls, profile: MachineProfile, optimise: bool = True, **given: float | int | None) -> "ToolpathOptions":
        """The options a machine profile's kerf and [cutting] rule give, with every value in `given` that is not
        None (a command-line option, a job's [export] key) instead; an explicit `tabs` count replaces the rule."""
        cutting = profile.cutting
        values = {"kerf": profile.kerf, "lead_in": cutting.lead_in, "tabs": None, "tab_width": cutting.tab_width,
                  "pierce_clearance": cutting.pierce_clearance, "tabs_below": cutting.tabs_below,
                  "tab_every": cutting.tab_every}
        unknown = set(given) - set(values)
        if unknown:
            raise TypeError(f"unknown toolpath options {sorted(unknown)}")
        values.update((key, value) for key, value in given.items() if value is not None)
        return cls(optimise=optimise, **values)

    def tab_count(self, part: Part, perimeter: float) -> int:
        """Tabs on this part's outer contour: the explicit count, else MIN_TABS or one per `tab_every` of perimeter
        for a part whose bounding box's longer side is under `tabs_below`, else none."""
        if self.tabs is not None:
            return self.tabs
        size = float(np.max(np.ptp(part.outline[:, :2], axis=0)))
        if size >= self.tabs_below:
            return 0
        return max(MIN_TABS, math.ceil(perimeter / self.tab_every))


def sheet_toolpaths(sheet: Sheet, parts: dict[str, Part], options: ToolpathOptions, source: str = "nesting") -> list[Toolpath]:
    """All toolpaths of a sheet, grouped by operation in cutting order, each group ordered for short travel."""
    check_placements(sheet, parts, source)
    groups: dict[str, list[Toolpath]] = {op: [] for op in OPERATIONS}
    placed_ids = set()
    for placement in sheet.placements:
        part = parts[placement.part]
        placed_ids.add(part.id)
        for operation, path in _part_paths(part, placement, options):
            groups[operation].append(path)
    cuts = list(sheet.common_cuts)
    for cut in cuts:
        missing = [p for p in cut.parts if p not in placed_ids]
        if missing:
            raise FablineError(f"{source}: sheet {sheet.id}: common cut refers to part {missing[0]!r}, "
                               "which is not placed on this sheet")
    if cuts:
        groups["cut-outer"] = _apply_common_cuts(groups["cut-outer"], cuts, options.kerf)
    ordered: list[Toolpath] = []
    position = np.zeros(2)
    for operation in OPERATIONS:
        paths = groups[operation]
        if options.optimise:
            paths = order_paths(paths, position)
        ordered.extend(paths)
        if paths:
            position = paths[-1].exit
    if options.lead_in > 0:
        ordered = lead_ins(ordered, sheet, parts, options)
    if options.tabs != 0:
        ordered = [piece for path in ordered for piece in _with_tabs(path, parts, options)]
    return ordered


def check_placements(sheet: Sheet, parts: dict[str, Part], source: str = "nesting") -> None:
    """Every placement of the sheet must name a part of the parts file."""
    for index, placement in enumerate(sheet.placements):
        if placement.part not in parts:
            raise FablineError(f"{source}: sheet {sheet.id}: placements[{index}] refers to part "
                               f"{placement.part!r}, which is not in the parts file")


def _part_paths(part: Part, placement: Placement, options: ToolpathOptions):
    """(operation, toolpath) for every contour of a placed part; cut contours offset by half the kerf."""
    key = ("part", part.id, options.kerf)
    if key not in options._cache:
        options._cache[key] = _part_contours(part, options)
    rows, pieces = options._cache[key]
    placed = place(rows, placement)
    for operation, closed, start, end in pieces:
        yield operation, Toolpath(operation, part.id, placed[start:end], closed)


def _part_contours(part: Part, options: ToolpathOptions) -> tuple[np.ndarray, list[tuple[str, bool, int, int]]]:
    """Every toolpath contour of a part in its own frame, stacked into one array so a placement moves them at once,
    with (operation, closed, first row, end row) for each: marks and text as they are, cuts offset by half the kerf."""
    half = options.kerf / 2.0
    operations = ["engrave-mark"] * len(part.marks) + ["engrave-text"] * len(part.text)
    contours = [*part.marks, *part.text]
    for contour, operation, distance in ([(c, "cut-inner", -half) for c in part.inner_contours()]
                                         + [(part.outline, "cut-outer", half)]):
        moved = _cached_offset(contour, distance, options._cache)
        if moved is None:
            raise FablineError(f"part {part.id}: a contour vanishes when offset by half the kerf ({half} mm)")
        operations.append(operation)
        contours.append(moved)
    stacked, ends, closed = stack_contours(contours)
    ends = ends.tolist()
    pieces = [(operation, operation.startswith("cut") or shut, start, end)
              for operation, shut, start, end in zip(operations, closed.tolist(), [0] + ends[:-1], ends)]
    return stacked, pieces


def _cached_offset(contour: np.ndarray, distance: float, cache: dict) -> np.ndarray | None:
    """Offset a contour, reusing the result for congruent-by-translation contours (washers, screw holes)."""
    contour = with_bulges(contour)
    origin = contour[0, :2].copy()
    local = contour.copy()
    local[:, :2] -= origin
    key = (np.round(local, 9).tobytes(), len(local), distance)
    if key not in cache:
        cache[key] = offset(local, distance)
    result = cache[key]
    if result is None:
        return None
    moved = result.copy()
    moved[:, :2] += origin
    return moved


def _apply_common_cuts(paths: list[Toolpath], cuts: list[CommonCut], kerf: float) -> list[Toolpath]:
    """Outer contours without the stretches along a common cut, plus each common cut once as its own path."""
    tolerance = kerf / 2.0 + 0.01
    out = []
    for path in paths:
        removed = []
        for cut in cuts:
            if path.part in cut.parts:
                removed.extend(_overlaps(path.contour, np.array(cut.start), np.array(cut.end), tolerance))
        if removed:
            out.extend(Toolpath(path.operation, path.part, piece, False) for piece in remove_intervals(path.contour, removed))
        else:
            out.append(path)
    for cut in cuts:
        line = np.array([[*cut.start, 0.0], [*cut.end, 0.0]])
        out.append(Toolpath("cut-outer", "+".join(cut.parts), line, False))
    return out


def _overlaps(contour: np.ndarray, a: np.ndarray, b: np.ndarray, tolerance: float) -> list[tuple[float, float]]:
    """Arc-length intervals of the contour's straight segments that run along segment a-b within `tolerance`."""
    axis = b - a
    span = np.hypot(*axis)
    if span == 0:
        return []
    axis = axis / span
    normal = np.array([-axis[1], axis[0]])
    lengths = segment_lengths(contour)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    intervals = []
    for i in np.flatnonzero(contour[:-1, 2] == 0):
        p0, p1 = contour[i, :2], contour[i + 1, :2]
        if abs(np.dot(p0 - a, normal)) > tolerance or abs(np.dot(p1 - a, normal)) > tolerance or lengths[i] == 0:
            continue
        t0, t1 = np.dot(p0 - a, axis), np.dot(p1 - a, axis)
        lo, hi = max(min(t0, t1), 0.0), min(max(t0, t1), span)
        if hi - lo <= 1e-6:
            continue
        # back to the segment's own arc length, whichever way it runs along the cut
        s_lo, s_hi = sorted(((lo - t0) / (t1 - t0) * lengths[i], (hi - t0) / (t1 - t0) * lengths[i]))
        intervals.append((cumulative[i] + s_lo, cumulative[i] + s_hi))
    return intervals


def _with_tabs(path: Toolpath, parts: dict[str, Part], options: ToolpathOptions) -> list[Toolpath]:
    """A closed outer contour split into open pieces that leave its tabs uncut, `tab_width` mm of toolpath each.

    The last tab ends where the cut began (after its lead-in), so the cut runs out into it as laser CAM's
    micro-joints do, and the others are spread evenly along the perimeter: the beam goes off over each and the next
    piece starts on the contour. The first piece keeps the lead-in.
    """
    if not path.closed or path.operation != "cut-outer":
        return [path]
    perimeter = float(np.sum(segment_lengths(path.contour)))
    count = options.tab_count(parts[path.part], perimeter)
    if count <= 0 or perimeter <= count * options.tab_width * 2:
        return [path]
    ends = perimeter - np.arange(count) * perimeter / count
    removed = [(end - options.tab_width, end) for end in ends.tolist()]
    pieces = [Toolpath(path.operation, path.part, piece, False) for piece in remove_intervals(path.contour, removed)]
    pieces[0].lead_in, pieces[0].no_room = path.lead_in, path.no_room
    return pieces


def lead_ins(paths: list[Toolpath], sheet: Sheet, parts: dict[str, Part], options: ToolpathOptions) -> list[Toolpath]:
    """The paths with a lead-in on every closed cut: from a pierce point on the scrap side (right of a
    counter-clockwise outer cut, left of a counter-clockwise inner one) at least
    `pierce_clearance` from every part on the sheet (and inside the sheet by as much), reached by a straight move
    that crosses no part. The lead-in starts at the path's first vertex, `lead_in` mm long or, where that does not
    fit, shorter (LEAD_IN_FRACTIONS); failing that at the nearest vertex where one fits (the path restarted there);
    failing that the path has none and is marked `no_room`."""
    wanted = [k for k, path in enumerate(paths) if path.closed and path.operation.startswith("cut")]
    if not wanted:
        return paths
    material = _material(sheet, parts, options._cache)
    tree = shapely.STRtree(material)
    inner = shapely.box(options.pierce_clearance, options.pierce_clearance, sheet.width - options.pierce_clearance,
                        sheet.height - options.pierce_clearance)
    result = list(paths)
    todo = wanted
    flip = dict(zip(wanted, (_counter_clockwise([paths[k].contour for k in wanted])
                             == np.array([paths[k].operation == "cut-inner" for k in wanted])).tolist()))
    fractions = np.array(LEAD_IN_FRACTIONS)
    for first_only in (True, False):
        if first_only:                      # every path's first vertex, gathered at once
            owner, vertex = np.array(todo), np.zeros(len(todo), dtype=int)
            rows = [np.array([paths[k].contour[i] for k in todo]) for i in (0, 1, -2)]
        else:                               # every other vertex of the paths left, nearest the first vertex first
            owner, vertex, rows = [], [], [[], [], []]
            for k in todo:
                contour = paths[k].contour
                order = np.argsort(np.hypot(*(contour[:-1, :2] - contour[0, :2]).T))[1:]
                owner.append(np.full(len(order), k))
                vertex.append(order)
                for bucket, index in zip(rows, (order, order + 1, (order - 1) % (len(contour) - 1))):
                    bucket.append(contour[index])
            owner, vertex = np.concatenate(owner), np.concatenate(vertex)
            rows = [np.vstack(bucket) for bucket in rows]
        directions = _scrap_directions(*rows, np.array([flip[k] for k in owner.tolist()]))
        # each vertex's lead-in at every fraction, longest first: candidates in order of preference per path
        starts = np.repeat(rows[0][:, :2], len(fractions), axis=0)
        points = starts + np.repeat(directions, len(fractions), axis=0) * np.tile(fractions, len(owner))[:, None] \
            * options.lead_in
        owner, vertex = np.repeat(owner, len(fractions)), np.repeat(vertex, len(fractions))
        fits = ~np.isnan(points[:, 0]) & shapely.contains_xy(inner, points[:, 0], points[:, 1])
        near = tree.query(shapely.points(points[fits]), predicate="dwithin", distance=options.pierce_clearance)[0]
        fits[np.flatnonzero(fits)[near]] = False
        candidates = np.flatnonzero(fits)
        lines = shapely.linestrings(np.stack([points[candidates], starts[candidates]], axis=1))
        fits[candidates[tree.query(lines, predicate="crosses")[0]]] = False
        chosen: dict[int, int] = {}
        for index in np.flatnonzero(fits).tolist():
            chosen.setdefault(int(owner[index]), index)
        for k, index in chosen.items():
            path, v = paths[k], int(vertex[index])
            contour = rotate_start(path.contour, v) if v else path.contour
            result[k] = Toolpath(path.operation, path.part, contour, True, points[index].copy())
        todo = [k for k in todo if k not in chosen]
        if not todo:
            break
    for k in todo:
        path = paths[k]
        result[k] = Toolpath(path.operation, path.part, path.contour, True, None, no_room=True)
    return result


def _material(sheet: Sheet, parts: dict[str, Part], cache: dict) -> list[shapely.Polygon]:
    """Every placed part of the sheet as a shapely polygon with its holes and closed slots (the nested geometry,
    not offset by the kerf): what a pierce must keep clear of."""
    polygons = []
    for placement in sheet.placements:
        part = parts[placement.part]
        key = ("material", *((c.shape, c.tobytes()) for c in [part.outline, *part.holes]),
               *((slot.edge, slot.outline.shape, slot.outline.tobytes()) for slot in part.slots))   # by shape
        if key not in cache:
            cache[key] = (_cached_flat(part.outline, cache), [_cached_flat(c, cache) for c in part.inner_contours()])
        shell, holes = cache[key]
        polygons.append(shapely.Polygon(place(shell, placement), [place(h, placement) for h in holes]))
    return polygons


def _cached_flat(contour: np.ndarray, cache: dict) -> np.ndarray:
    """A contour flattened within FLATTEN_TOLERANCE, reusing the result for congruent-by-translation contours."""
    contour = with_bulges(contour)
    origin = contour[0, :2].copy()
    local = contour - [*origin, 0.0]
    key = ("flat", np.round(local, 9).tobytes(), len(local))
    if key not in cache:
        cache[key] = flatten_contour(local, FLATTEN_TOLERANCE)
    return cache[key] + origin


def _scrap_directions(at: np.ndarray, after: np.ndarray, before: np.ndarray, flip: np.ndarray) -> np.ndarray:
    """Unit vectors at vertices `at` ([x, y, bulge] rows; `after` the next vertex, `before` the one before with the
    bulge of the segment from it) pointing to the right of the path, or its left where `flip`: the scrap side,
    along the bisector of the tangents that arrive and leave (arcs through their bulges); NaN where the path turns
    back on itself."""
    leaving = _rotate_all(after[:, :2] - at[:, :2], -2.0 * np.arctan(at[:, 2]))
    arriving = _rotate_all(at[:, :2] - before[:, :2], 2.0 * np.arctan(before[:, 2]))
    tangent = _unit(leaving) + _unit(arriving)
    length = np.hypot(*tangent.T)
    tangent = np.where(length[:, None] > 1e-9, tangent / np.maximum(length, 1e-12)[:, None], np.nan)
    right = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    return np.where(flip[:, None], -right, right)


def _counter_clockwise(contours: list[np.ndarray]) -> np.ndarray:
    """Whether each closed contour runs counter-clockwise: by the polygon of its vertices, all at once, and by its
    arcs too (signed_area) where that polygon is flat."""
    stacked = np.vstack(contours)
    ends = np.cumsum([len(c) for c in contours])
    cross = stacked[:-1, 0] * stacked[1:, 1] - stacked[1:, 0] * stacked[:-1, 1]
    cross = np.append(cross, 0.0)
    cross[ends - 1] = 0.0                                       # no segment from one contour's end to the next
    area = np.add.reduceat(cross, np.concatenate([[0], ends[:-1]]))
    flat = np.flatnonzero(np.abs(area) <= 1e-6)
    area[flat] = [signed_area(contours[i]) for i in flat.tolist()]
    return area > 0


def _rotate_all(vectors: np.ndarray, angles: np.ndarray) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    return np.column_stack([c * vectors[:, 0] - s * vectors[:, 1], s * vectors[:, 0] + c * vectors[:, 1]])


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.hypot(*vectors.T), 1e-12)[:, None]


def order_paths(paths: list[Toolpath], start: np.ndarray) -> list[Toolpath]:
    """Paths reordered (open ones possibly reversed, closed ones restarted) for short travel from `start`."""
    if len(paths) > 1:
        paths = _two_opt(_nearest_neighbour(paths, start), start)
    return _restart(_restart(list(paths), start), start)


def _restart(tour: list[Toolpath], start: np.ndarray) -> list[Toolpath]:
    """Every closed path started at the vertex that minimises travel in from the path before and on to the next.

    All closed paths are restarted at once against their neighbours' current ends (run it twice to settle).
    """
    closed = [k for k, path in enumerate(tour) if path.closed]
    if not closed:
        return tour
    entries = np.array([p.entry for p in tour])
    exits = np.array([p.exit for p in tour])
    previous = np.vstack([start, exits[:-1]])[closed]
    following = np.vstack([entries[1:], [np.nan, np.nan]])[closed]
    counts = np.array([len(tour[k].contour) - 1 for k in closed])
    owner = np.repeat(np.arange(len(closed)), counts)
    vertices = np.vstack([tour[k].contour[:-1, :2] for k in closed])
    cost = _distance(vertices, previous[owner]) + np.nan_to_num(_distance(vertices, following[owner]))
    firsts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    best = np.lexsort((cost, owner))[firsts] - firsts          # cheapest vertex of each path, counted from its first
    for k, at in zip(closed, best.tolist()):
        if at:
            path = tour[k]
            tour[k] = Toolpath(path.operation, path.part, rotate_start(path.contour, at), True, path.lead_in)
    return tour


def _nearest_neighbour(paths: list[Toolpath], start: np.ndarray) -> list[Toolpath]:
    """Greedy tour: always go to the nearest free entry point (any vertex of a closed path, either end of an open one).

    The candidate points sit in a KD-tree; once most of them are used up the tree is rebuilt on the free ones.
    """
    points, owner, role = [], [], []
    for i, path in enumerate(paths):
        if path.closed:
            points.append(path.contour[:-1, :2])
            owner.extend([i] * (len(path.contour) - 1))
            role.extend(range(len(path.contour) - 1))
        else:
            points.append(path.contour[[0, -1], :2])
            owner.extend([i, i])
            role.extend([0, -1])
    points_arr = np.vstack(points)
    free = [True] * len(paths)
    free_points = len(points_arr)
    active = list(range(len(points_arr)))          # tree index -> point index
    tree = cKDTree(points_arr)
    position, chosen = np.asarray(start, dtype=float), []
    for _ in range(len(paths)):
        k, best = NN_CANDIDATES, -1
        while best < 0:
            _, found = tree.query(position, k=min(k, len(active)))
            for f in np.atleast_1d(found).tolist():
                if free[owner[active[f]]]:
                    best = active[f]
                    break
            else:
                if 2 * free_points < len(active):
                    active, k = [p for p in active if free[owner[p]]], NN_CANDIDATES
                    tree = cKDTree(points_arr[active])
                else:
                    k *= 4
        index = owner[best]
        free[index] = False
        free_points -= len(paths[index].contour) - 1 if paths[index].closed else 2
        path = paths[index]
        chosen.append((path, role[best]))
        position = path.contour[role[best], :2] if path.closed else path.contour[-1 - role[best], :2]
    tour = []
    for path, at in chosen:
        if path.closed:
            path = Toolpath(path.operation, path.part, rotate_start(path.contour, at), True)
        elif at == -1:
            path = Toolpath(path.operation, path.part, reverse(path.contour), False)
        tour.append(path)
    return tour


def _two_opt(tour: list[Toolpath], start: np.ndarray) -> list[Toolpath]:
    """2-opt on the tour's travel moves with neighbour lists: reversing a run of paths also reverses its open paths.

    Each pass looks at the reversals whose new travel moves join near neighbours, applies the best
    non-overlapping improving ones at once, and repeats until no reversal shortens the travel. Reversals only
    swap which end of a path is its entry, so the neighbours of every path end are found once (KD-tree) and
    each pass keeps those that are currently an exit (or an entry), as the new moves need.
    """
    n = len(tour)
    ends = np.empty((2 * n, 2))                             # row 2q: path q's entry in the tour given, 2q + 1: its exit
    ends[0::2] = [p.entry for p in tour]
    ends[1::2] = [p.exit for p in tour]
    closed = np.array([p.closed for p in tour])
    k = min(TWO_OPT_NEIGHBOURS, 2 * n)
    tree = cKDTree(ends)
    gap, near = (a.reshape(2 * n, k) for a in tree.query(ends, k=k))
    gap_start, near_start = (np.atleast_1d(a) for a in tree.query(start, k=k))
    order = np.arange(n)                                    # path at each tour position
    flipped = np.zeros(n, dtype=bool)                       # by path: run backwards from the tour given
    rows = np.arange(n)
    for _ in range(TWO_OPT_PASSES):
        position = np.empty(n, dtype=int)
        position[order] = rows
        entry_end = 2 * order + flipped[order]              # row of `ends` each position enters at
        exit_end = 2 * order + 1 - flipped[order]
        entry, exit_ = ends[entry_end], ends[exit_end]
        before = np.vstack([start, exit_[:-1]])             # where the tool comes from into position i
        move_in = np.append(_distance(before, entry), 0.0)  # travel into each position (and past the end: none)
        # reversal [i..j] with a short new move before[i] -> exit[j]: ends near before[i] that are an exit now
        found = np.vstack([near_start, near[exit_end[:-1]]])
        path = found // 2
        usable = np.nonzero(closed[path] | ((found % 2 == 1) != flipped[path]))
        i1, j1 = usable[0], position[path[usable]]
        short1 = np.vstack([gap_start, gap[exit_end[:-1]]])[usable]
        # reversal [i..j] with a short new move entry[i] -> entry[j + 1]: ends near entry[i] that are an entry now
        found = near[entry_end]
        path = found // 2
        usable = np.nonzero(closed[path] | ((found % 2 == 0) != flipped[path]))
        i2, j2 = usable[0], position[path[usable]] - 1
        short2 = gap[entry_end][usable]
        keep1, keep2 = j1 >= i1, j2 >= i2
        i1, j1, short1, i2, j2, short2 = i1[keep1], j1[keep1], short1[keep1], i2[keep2], j2[keep2], short2[keep2]
        after1 = j1 + 1 < n
        other1 = np.where(after1, _distance(entry[i1], entry[np.minimum(j1 + 1, n - 1)]), 0.0)
        other2 = _distance(before[i2], exit_[j2])          # j2 + 1 < n: it is a position
        i, j = np.concatenate([i1, i2]), np.concatenate([j1, j2])
        gain = move_in[i] + move_in[j + 1] - np.concatenate([short1 + other1, short2 + other2])
        improving = np.flatnonzero(gain > 1e-6)
        if len(improving) == 0:
            break
        busy = np.zeros(n, dtype=bool)
        for c in improving[np.argsort(-gain[improving], kind="stable")].tolist():
            lo, hi = int(i[c]), int(j[c])
            if busy[max(lo - 1, 0):hi + 2].any():
                continue
            busy[lo:hi + 1] = True
            run = order[lo:hi + 1]
            flipped[run] = ~flipped[run]
            order[lo:hi + 1] = run[::-1].copy()
    result = []
    for index, flip in zip(order.tolist(), flipped[order].tolist()):
        path = tour[index]
        if flip and not path.closed:
            path = Toolpath(path.operation, path.part, reverse(path.contour), False)
        result.append(path)
    return result


def _distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])


def travel_length(paths: list[Toolpath], start: np.ndarray | None = None) -> float:
    """Tool-off distance to run the paths in order from `start` (origin by default) and back."""
    position = np.zeros(2) if start is None else np.asarray(start, dtype=float)
    total = 0.0
    for path in paths:
        total += float(np.hypot(*(path.entry - position)))
        position = path.exit
    return total + float(np.hypot(*position))
