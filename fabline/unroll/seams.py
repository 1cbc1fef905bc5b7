"""Cutting a strip into pieces a sheet can hold: seams midway between two joints, and ends at singularity joints.

A strip longer than the usable sheet length is split at seams. A seam lies midway between two
neighbouring nodes; the two segments overlap there by `overlap` and are screwed together through six
holes (domain.md 1). Seams go as far along as a sheet allows (greedy), and the second strip of a pair
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


@dataclass
class Join:
    """What a segment end meets: a seam (overlap centred at `x`), a singularity joint at node `node`, or nothing."""

    kind: str
    x: float
    node: str = ""
    interval: tuple[str, str] = ("", "")


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
    """Arc-length range of the whole strip: its outermost node or slot plus the end length at both ends."""
    xs = np.concatenate([strip.node_x, strip.slot_x])
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
    """Greedy seams: each segment as long as the usable sheet length allows, each seam in a free node interval."""
    usable, half = options.usable_length, options.overlap / 2.0
    at, intervals = seam_candidates(strip, options, start, end)
    # the candidates that fit are those with current + half < at - half and at + half <= current + usable: a
    # range of the sorted candidates, found by bisection; of them the last one free of the partner's seams
    overlap_start, overlap_end = (at - half).tolist(), (at + half).tolist()
    free = [k for k, interval in enumerate(intervals) if interval not in avoid]
    segments, current, join = [], start, join_start
    while end - current > usable:
        first, stop = bisect_right(overlap_start, current + half), bisect_right(overlap_end, current + usable)
        last_free = bisect_left(free, stop) - 1
        chosen = free[last_free] if last_free >= 0 and free[last_free] >= first else stop - 1
        if chosen < first:
            raise FablineError(
                f"lamella {strip.lamella}, strip {strip.id}: no seam fits between x = {current:.0f} and "
                f"{current + usable:.0f} mm: no node interval there leaves {options.overlap:g} mm of overlap clear "
                f"of slots and marks (usable sheet length {usable:g} mm)")
        seam = Join("seam", float(at[chosen]), interval=intervals[chosen])
        segments.append(Segment(strip, current, seam.x + half, start_join=join, end_join=seam))
        current, join = seam.x - half, seam
    segments.append(Segment(strip, current, end, start_join=join, end_join=join_end))
    return segments


def seam_candidates(strip: Strip, options: UnrollOptions, start: float,
                    end: float) -> tuple[np.ndarray, list[tuple[str, str]]]:
    """Midpoints of node intervals inside (start, end) whose overlap keeps a web clear of every slot and node mark,
    and those intervals' node pairs (arrays rather than Join objects: a strip has many candidates, few seams)."""
    x, ids = strip.node_x, strip.node_ids  # in order along the strip (stations checks it)
    middle = (x[1:] + x[:-1]) / 2.0
    half = options.overlap / 2.0
    keep_out_slot = half + options.slot / 2.0 + options.web
    keep_out_mark = half + node_text_reach(options, ids)
    clear = np.minimum(middle - x[:-1], x[1:] - middle) >= keep_out_mark  # the interval's own nodes are nearest
    if len(strip.slot_x):
        clear &= _nearest_distance(middle, strip.slot_x) >= keep_out_slot
    clear &= (middle - half > start) & (middle + half < end)
    chosen = np.flatnonzero(clear).tolist()
    return middle[chosen], [(ids[k], ids[k + 1]) for k in chosen]


def _nearest_distance(points: np.ndarray, sorted_values: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of the (non-empty, increasing) values: only its two neighbours count."""
    after = np.minimum(np.searchsorted(sorted_values, points), len(sorted_values) - 1)
    before = np.maximum(after - 1, 0)
    return np.minimum(np.abs(points - sorted_values[before]), np.abs(points - sorted_values[after]))


def node_text_reach(options: UnrollOptions, node_ids: list[str]) -> float:
    """How far a node's engraved id reaches from its mark along the strip (mm): the longest id plus a gap."""
    widest = max(map(text_width, node_ids), default=0.0)
    return widest * options.engrave_height + 2.0 * TEXT_GAP

