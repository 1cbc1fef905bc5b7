"""Cutting a strip into pieces a sheet can hold: seams between two joints, and ends at singularity joints.

A strip longer than the usable sheet length is split at seams. A seam lies between two neighbouring
nodes, clear of their marks and slots; the two segments overlap there by `overlap` and are screwed
together through six holes (domain.md 1). Seams go as far along as a sheet allows (greedy, anywhere in
an interval, so a segment fills its row on the sheet), and the second strip of a pair
avoids the node intervals its partner's seams use, so the two seams of a pair are staggered. In the
separate-joint mode a strip also ends `setback` before each singularity node and starts again after it.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from fabline.errors import FablineError
from fabline.unroll.options import TEXT_GAP, UnrollOptions
from fabline.unroll.stations import Strip
from fabline.unroll.strokes import text_width


SEAM_HOLE_COLUMNS = np.array([-1.0, 0.0, 1.0]) / 3.0  # of the overlap, about the seam
SEAM_HOLE_ROWS = np.array([-0.25, 0.25])              # of the height, about the centreline


@dataclass
class Join:
    """What a segment end meets: a seam (overlap centred at `x`), a singularity joint at node `node`, or nothing."""

    kind: str
    x: float
    node: str = ""
    interval: tuple[str, str] = ("", "")
    overlap: float = 0.0  # a seam's overlap length (options.overlap, or shorter where that does not fit)


@dataclass
class Segment:
    """One piece of a strip to cut: arc-length range [start, end] along the strip, and what each end joins."""

    strip: Strip
    start: float
    end: float
    index: int = 1
    count: int = 1
    start_join: Join | None = None
    end_join: Join | None = None

    @cached_property
    def id(self) -> str:
        """Part id: the strip's id, with ".k" when the strip has several segments (read after splitting)."""
        return self.strip.id if self.count == 1 else f"{self.strip.id}.{self.index}"


def strip_extent(strip: Strip, options: UnrollOptions) -> tuple[float, float]:
    """Arc-length range of the whole strip: its outermost node, slot or edge crossing plus the end length at both ends."""
    xs = np.concatenate([strip.node_x, strip.slot_x, strip.edge_x])
    return float(xs.min() - options.end), float(xs.max() + options.end)


def split_strip(strip: Strip, options: UnrollOptions, setback: float,
                avoid: set[tuple[str, str]] = frozenset()) -> list[Segment]:
    """The strip's segments in order along it; seams in `avoid` (node intervals) are used only if nothing else fits."""
    start, end = strip_extent(strip, options)
    runs: list[tuple[float, float, Join | None, Join | None]] = []
    run_start, start_join = start, None
    # in order along the strip (node_x increases: stations checks it); most strips have no joints, so no loop
    joints = ([(nid, x) for nid, x in zip(strip.node_ids, strip.node_x.tolist()) if nid in strip.joint_nodes]
              if strip.joint_nodes else [])
    for nid, x in joints:
        joint = Join("joint", x, nid)
        if x - setback > run_start + options.end:
            runs.append((run_start, x - setback, start_join, joint))
        run_start, start_join = x + setback, joint
    if end > run_start + options.end:
        runs.append((run_start, end, start_join, None))
    segments: list[Segment] = []
    for a, b, join_a, join_b in runs:
        segments.extend(_split_run(strip, options, a, b, join_a, join_b, avoid))
    for k, segment in enumerate(segments, start=1):
        segment.index, segment.count = k, len(segments)
    return segments


def _split_run(strip: Strip, options: UnrollOptions, start: float, end: float, join_start: Join | None,
               join_end: Join | None, avoid: set[tuple[str, str]]) -> list[Segment]:
    """Greedy seams: each segment as long as the usable sheet length allows, each seam in a free node interval.

    First with every seam in the middle of its interval with the full overlap; only a run where that leaves a sheet
    length without a seam is split again with the seams shifted and shortened as far as allowed (SEAM_SHIFTS,
    down to `min_overlap`)."""
    for extended in (False, True):
        segments = _greedy(strip, options, start, end, join_start, join_end, avoid,
                           seam_candidates(strip, options, start, end, extended))
        if segments is not None:
            return segments
    usable = options.usable_length
    current = _greedy(strip, options, start, end, join_start, join_end, avoid,
                      seam_candidates(strip, options, start, end, True), stuck_at=True)
    raise FablineError(f"lamella {strip.lamella}, strip {strip.id}: no seam fits between x = {current:.0f} and "
                       f"{current + usable:.0f} mm (usable sheet length {usable:g} mm): "
                       + seam_failure(strip, options, current, current + usable, start, end))


def _greedy(strip: Strip, options: UnrollOptions, start: float, end: float, join_start: Join | None,
            join_end: Join | None, avoid: set[tuple[str, str]], candidates: tuple, stuck_at: bool = False):
    """The segments of a run with seams from `candidates` (centres, half overlaps, intervals; in order along the
    strip), or None where a sheet length holds no seam (with `stuck_at`: the x where that happens)."""
    at, halves, intervals = candidates
    usable = options.usable_length
    # a seam fits when its overlap starts past the previous seam's centre and ends within a sheet length; with
    # equal overlaps and no shifts the candidates' overlap ends are sorted, and those that fit are a range found
    # by bisection; of them the last one free of the partner's seams
    low, high = at - halves, at + halves
    in_order = bool(np.all(np.diff(low) >= 0) and np.all(np.diff(high) >= 0))
    overlap_start, overlap_end = low.tolist(), high.tolist()
    free = [k for k, interval in enumerate(intervals) if interval not in avoid]
    segments, current, join, centre = [], start, join_start, start + options.overlap / 2.0
    while end - current > usable:
        if in_order:
            first, stop = bisect_right(overlap_start, centre), bisect_right(overlap_end, current + usable)
            last_free = bisect_left(free, stop) - 1
            chosen = free[last_free] if last_free >= 0 and free[last_free] >= first else stop - 1
            found = chosen >= first
        else:
            fitting = np.flatnonzero((low > centre) & (high <= current + usable)).tolist()
            free_fitting = [k for k in fitting if intervals[k] not in avoid]
            found = bool(fitting)
            chosen = (free_fitting or fitting or [-1])[-1]
        if not found:
            return current if stuck_at else None
        seam = Join("seam", float(at[chosen]), interval=intervals[chosen], overlap=2.0 * float(halves[chosen]))
        segments.append(Segment(strip, current, seam.x + halves[chosen], start_join=join, end_join=seam))
        current, join, centre = seam.x - halves[chosen], seam, seam.x
    segments.append(Segment(strip, current, end, start_join=join, end_join=join_end))
    return segments


SEAM_SHIFTS = np.linspace(-0.45, 0.45, 37)  # where in its interval a seam may go, as a share of the interval
OVERLAP_STEPS = 5  # overlaps tried from `overlap` down to `min_overlap`


def seam_candidates(strip: Strip, options: UnrollOptions, start: float, end: float,
                    extended: bool = False) -> tuple[np.ndarray, np.ndarray, list[tuple[str, str]]]:
    """Every place inside (start, end) where a seam fits: its centre, half its overlap, and its node interval's node
    pair, in order along the strip (arrays rather than Join objects: a strip has many candidates, few seams). A seam
    may lie anywhere in its interval clear of the node marks, ids and slots (SEAM_SHIFTS), so that a segment can
    run nearly a whole sheet length and fill its row; with the full overlap, and `extended` also with the overlap
    shortened down to `min_overlap` where no full one fits in the interval (the longest that does)."""
    x, ids = strip.node_x, strip.node_ids  # in order along the strip (stations checks it)
    length, middle = np.diff(x), (x[1:] + x[:-1]) / 2.0
    overlaps = np.linspace(options.overlap, options.shortest_overlap, OVERLAP_STEPS) if extended else [options.overlap]
    rows = np.arange(len(length))
    done = np.zeros(len(length), dtype=bool)
    found: list[tuple[float, float, int]] = []
    for overlap in dict.fromkeys(float(o) for o in overlaps):
        todo = rows[~done]
        if not todo.size:
            break
        for shift in SEAM_SHIFTS:
            centre = middle[todo] + shift * length[todo]
            fits = _seam_problem_codes(strip, options, centre, start, end, todo, overlap, clear=not extended) == 0
            found.extend((c, overlap / 2.0, k) for c, k in zip(centre[fits].tolist(), todo[fits].tolist()))
            done[todo[fits]] = True
    found.sort()
    return (np.array([c for c, _, _ in found]), np.array([h for _, h, _ in found]),
            [(ids[k], ids[k + 1]) for _, _, k in found])


SEAM_PROBLEMS = {
    1: "the overlap would run past the strip's end",
    2: "the overlap would cover a node mark (the overlap plus {gap:g} mm each side must lie between two nodes)",
    3: "a node id would have no room beside its mark, outside the overlap",
    4: "an overlap end would cut within {web:g} mm (the web) of a slot",
    5: "a screw hole would come within {web:g} mm of a slot",
    6: "the overlap would reach over a slot",
}


def _seam_problem_codes(strip: Strip, options: UnrollOptions, centre: np.ndarray, start: float,
                        end: float, rows: np.ndarray | None = None, overlap: float | None = None,
                        clear: bool = False) -> np.ndarray:
    """Per node interval k (of `rows`, default all; seam centre `centre[k]` between nodes k and k + 1), 0 if a seam
    fits there, else the first SEAM_PROBLEMS code it breaks. The overlap may contain slots (both segments are cut
    from the same strip stations, so their slots line up and the crossing strip goes through both layers), not
    node marks; with `clear` it must lie clear of every slot by the web (a joint's layers stay whole)."""
    x, ids = strip.node_x, strip.node_ids
    rows = np.arange(len(x) - 1) if rows is None else rows
    overlap = options.overlap if overlap is None else overlap
    half, reach = overlap / 2.0, node_text_reach(options, ids)
    left, right = centre - x[rows], x[rows + 1] - centre
    # node k's distance to node k - 1 (the first node's: twice its distance to the strip's start)
    before = np.diff(np.concatenate([[x[0] - 2.0 * (x[0] - start)], x]))[rows]
    # node k's id goes right of its mark unless it would reach into the overlap; then left, clear of node k-1's id
    codes = np.zeros(len(centre), dtype=int)
    checks = [(1, (centre - half <= start) | (centre + half >= end)),
              (2, np.minimum(left, right) < half + TEXT_GAP),
              (3, (left < half + reach) & (before < 2.0 * reach))]
    if len(strip.slot_x):
        cut_clear = options.slot / 2.0 + options.web
        hole_clear = options.screw_hole / 2.0 + cut_clear
        ends = np.minimum(_nearest_distance(centre - half, strip.slot_x), _nearest_distance(centre + half, strip.slot_x))
        holes = np.min([_nearest_distance(centre + column * overlap, strip.slot_x)
                        for column in SEAM_HOLE_COLUMNS], axis=0)
        checks += [(4, ends < cut_clear), (5, holes < hole_clear)]
        if clear:
            inside = np.searchsorted(strip.slot_x, centre + half + cut_clear) - np.searchsorted(strip.slot_x,
                                                                                               centre - half - cut_clear)
            checks.append((6, inside > 0))
    for code, broken in reversed(checks):
        codes[broken] = code
    return codes


def seam_failure(strip: Strip, options: UnrollOptions, lo: float, hi: float, start: float, end: float) -> str:
    """Why no seam fits with its overlap within (lo, hi): the limit each node interval there breaks, the widest first."""
    x, ids = strip.node_x, strip.node_ids
    half = options.shortest_overlap / 2.0
    inside = np.flatnonzero((x[1:] > lo + half) & (x[:-1] < hi - half))
    if not inside.size:
        return f"no node interval lies there (nodes {ids[0]}..{ids[-1]})"
    length = x[inside + 1] - x[inside]
    middle = (x[inside + 1] + x[inside]) / 2.0
    codes = _seam_problem_codes(strip, options, middle, start, end, inside, options.shortest_overlap)
    codes = np.where((middle - half <= lo) | (middle + half > hi), 1, codes)
    widest = inside[np.argsort(-length, kind="stable")][:3]
    described = []
    for k in widest:
        code = int(codes[np.flatnonzero(inside == k)[0]])
        reason = SEAM_PROBLEMS[code].format(gap=TEXT_GAP, web=options.web) if code else "its overlap would leave the sheet"
        described.append(f"{ids[k]}..{ids[k + 1]} ({x[k + 1] - x[k]:.1f} mm): {reason}")
    return (f"every interval there breaks a limit of an overlap of {options.overlap:g} mm shortened down to "
            f"{options.shortest_overlap:g} mm (min overlap) with six {options.screw_hole:g} mm screw holes, shifted "
            f"up to {SEAM_SHIFTS[-1]:g} of an interval from its middle; widest, at the shortest overlap: " + "; ".join(described)
            + " (lower the min overlap, screw hole or text height, or use a longer sheet)")


def _nearest_distance(points: np.ndarray, sorted_values: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of the (non-empty, increasing) values: only its two neighbours count."""
    after = np.minimum(np.searchsorted(sorted_values, points), len(sorted_values) - 1)
    before = np.maximum(after - 1, 0)
    return np.minimum(np.abs(points - sorted_values[before]), np.abs(points - sorted_values[after]))


def node_text_reach(options: UnrollOptions, node_ids: list[str]) -> float:
    """How far a node's engraved id reaches from its mark along the strip (mm): the longest id plus a gap."""
    widest = max(map(text_width, node_ids), default=0.0)
    return widest * options.engrave_height + 2.0 * TEXT_GAP

