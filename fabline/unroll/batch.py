"""Straight strip segments built all at once: the same parts as `pieces.segment_part`, with the numpy work batched.

Asymptotic gridshells are made of straight strips, and a large model has tens of thousands of segments:
building each one with a few dozen small numpy calls costs more than the geometry itself. Here every slot,
notch, mark, node id, label and screw hole of all straight segments is computed in a handful of array
operations; only the Part objects and the label placement are assembled per segment. The result equals
`segment_part` (a test compares them), which stays the reference and handles curved strips.
"""

from __future__ import annotations

import numpy as np

from fabline.unroll.options import TEXT_GAP, UnrollOptions
from fabline.unroll.parts import Part, Slot
from fabline.unroll.pieces import (ARROW_LENGTH, SEAM_HOLE_COLUMNS, SEAM_HOLE_ROWS, is_seam, label_spot,
                                   segment_label, segment_meta)
from fabline.unroll.flat import QUARTER_ARC_BULGE
from fabline.unroll.seams import Segment
from fabline.unroll.stations import FAMILY_EDGE
from fabline.unroll.strokes import TextBlock, gather, layout_block, split_rows

_QUARTERS = np.column_stack([np.cos(np.arange(5) * np.pi / 2.0), np.sin(np.arange(5) * np.pi / 2.0)])


def straight_flags(segments: list[Segment], options: UnrollOptions) -> np.ndarray:
    """Per segment, True when it is certainly cut straight: the largest in-plane curvature k over it (samples one
    beyond each end included) keeps it within k L^2 / 8 < tolerance of its chord, as `FlatCentreline.build` checks.

    One `maximum.reduceat` over all strips' |k_n| (each followed by a 0 sentinel) with interleaved [lo, hi) bounds.
    """
    if not segments:
        return np.zeros(0, dtype=bool)
    curvature, bounds, base, seen = [], [], 0, {}
    for segment in segments:
        strip = segment.strip
        if id(strip) not in seen:
            seen[id(strip)] = base
            curvature.extend([np.abs(strip.geometry.k_n), np.zeros(1)])
            base += len(strip.geometry.k_n) + 1
        lo, hi = np.searchsorted(strip.curve.s_at_samples, (segment.start, segment.end)).tolist()
        bounds += [seen[id(strip)] + max(lo - 1, 0), seen[id(strip)] + min(hi + 1, len(strip.geometry.k_n))]
    k_max = np.maximum.reduceat(np.concatenate(curvature), bounds)[::2]
    length = np.array([s.end - s.start for s in segments])
    return k_max * length ** 2 / 8.0 < options.straight_tolerance


def straight_parts(segments: list[Segment], options: UnrollOptions) -> list[Part]:
    """The parts of straight segments, in order; segments of one strip must follow each other in order along it."""
    if not segments:
        return []
    h, half_slot, height = options.profile.h, options.slot / 2.0, options.engrave_height
    a = np.array([s.start for s in segments])
    b = np.array([s.end for s in segments])
    sign = np.array([-1.0 if FAMILY_EDGE[s.strip.family] == "top" else 1.0 for s in segments])  # free edge side
    slots = _gather(segments, "slot_x")
    nodes = _gather(segments, "node_x")
    slot_seg, slot_x = slots["segment"], slots["x"]
    slot_top = np.array([e == "top" for e in slots["edges"]], dtype=bool)
    node_seg, node_x = nodes["segment"], nodes["x"]
    slot_range = _ranges(slot_seg, len(segments))
    node_range = _ranges(node_seg, len(segments))

    outlines = _outlines(a, b, slot_seg, slot_x, slot_top, h, half_slot, options.slot_depth)
    slot_contours = _slot_contours(slot_x - a[slot_seg], slot_top, h, half_slot, options.slot_depth)

    # node marks: from the free edge to short of the slot ends (full height where the strip has no slot there)
    edge_y = sign * h / 2.0
    slot_end_y = sign * (h / 2.0 - options.free_height)
    s_node = sign[node_seg]
    far = np.where(nodes["slotted"], slot_end_y[node_seg] + s_node * TEXT_GAP, -edge_y[node_seg] + s_node * TEXT_GAP)
    marks = np.empty((len(node_x), 2, 2))
    marks[:, :, 0] = (node_x - a[node_seg])[:, None]
    marks[:, 0, 1] = edge_y[node_seg] - s_node * TEXT_GAP
    marks[:, 1, 1] = far

    # node ids beside their marks, on the side away from a seam overlap or the strip end
    unique: dict[str, int] = {}
    which = np.array([unique.setdefault(n, len(unique)) for n in nodes["ids"]], dtype=int)
    id_block = layout_block(list(unique))
    widths = id_block.widths[which]
    widest = np.zeros(len(segments))
    np.maximum.at(widest, node_seg, widths)
    reach = widest * height + 2.0 * TEXT_GAP
    r_node = reach[node_seg]
    tip = node_x + r_node
    start_seam = np.array([is_seam(s.start_join) for s in segments])
    end_seam = np.array([is_seam(s.end_join) for s in segments])
    seg_a, seg_b = a[node_seg], b[node_seg]
    in_seam = ((start_seam[node_seg] & (seg_a < tip) & (tip < seg_a + options.overlap))
               | (end_seam[node_seg] & (seg_b - options.overlap < tip) & (tip < seg_b)))
    right = (tip <= seg_b - TEXT_GAP) & ~in_seam
    dx = np.where(right, TEXT_GAP, -TEXT_GAP - widths * height)
    baseline = edge_y - sign * TEXT_GAP - np.where(sign > 0, height, 0.0)
    blocked_lo = np.where(right, node_x - TEXT_GAP, node_x - r_node)
    blocked_hi = np.where(right, node_x + r_node, node_x + TEXT_GAP)
    ids = gather(id_block, which)  # each id is laid out once and engraved on up to four strips
    id_points = ids.points * height
    id_points[:, 0] += (node_x - a[node_seg] + dx)[ids.owner]
    id_points[:, 1] += baseline[node_seg][ids.owner]
    node_strokes = split_rows(id_points, ids.starts)
    node_stroke_count = np.bincount(ids.stroke_owner, minlength=len(which))

    # labels: placed per segment (a short loop over each segment's few spans), drawn together
    labels = [segment_label(s) for s in segments]
    label_block = layout_block(labels)
    spots = []
    for k, segment in enumerate(segments):
        lo, hi = node_range[k], node_range[k + 1]
        blocked = [(a[k], a[k] + options.overlap) if start_seam[k] else (a[k], a[k]),
                   (b[k] - options.overlap, b[k]) if end_seam[k] else (b[k], b[k])]
        blocked += zip(blocked_lo[lo:hi].tolist(), blocked_hi[lo:hi].tolist())
        spots.append(label_spot(float(label_block.widths[k]), a[k], b[k], blocked, height))
    label_strokes = _labels(spots, label_block, a, edge_y, slot_end_y)

    holes, hole_count = _seam_holes(segments, a, start_seam, end_seam, options)

    # the per-part assembly below only slices Python lists with Python ints, the cheapest way to build objects
    node_ids = nodes["ids"]
    stroke_at = np.concatenate([[0], np.cumsum(node_stroke_count)]).tolist()
    hole_at = np.concatenate([[0], np.cumsum(hole_count)]).tolist()
    slot_list = [Slot(n, c, e) for n, c, e in zip(slots["nodes"], slot_contours, slots["edges"])]
    mark_list = list(marks)
    node_s = np.round(node_x - a[node_seg], 4).tolist()
    node_rows = [{"id": n, "s": s} for n, s in zip(node_ids, node_s)]
    slot_bounds, node_bounds = slot_range.tolist(), node_range.tolist()
    parts = []
    for k, segment in enumerate(segments):
        s0, s1, n0, n1 = slot_bounds[k], slot_bounds[k + 1], node_bounds[k], node_bounds[k + 1]
        text = node_strokes[stroke_at[n0]:stroke_at[n1]] + label_strokes.get(k, [])
        parts.append(Part(
            segment.id, "strip", outlines[k], lamella=segment.strip.lamella, holes=holes[hole_at[k]:hole_at[k + 1]],
            slots=slot_list[s0:s1], marks=mark_list[n0:n1], text=text, nodes=node_rows[n0:n1],
            label=labels[k], grain=True, meta=segment_meta(segment, None)))
    return parts


def _gather(segments: list[Segment], field: str) -> dict:
    """Slots ("slot_x") or nodes ("node_x") of every segment, concatenated in segment order, with their segment index.

    A feature belongs to the segment whose [start, end) holds it; features in a gap between segments (at a
    singularity joint) belong to none.
    """
    xs, seg, ids, edges, slotted = [], [], [], [], []
    k = 0
    while k < len(segments):
        strip = segments[k].strip
        last = k
        while last + 1 < len(segments) and segments[last + 1].strip is strip:
            last += 1
        values = getattr(strip, field)
        with_slot = set(strip.slot_nodes)
        bounds = np.searchsorted(values, [(s.start, s.end) for s in segments[k:last + 1]])
        for offset, (lo, hi) in enumerate(bounds.tolist()):
            xs.append(values[lo:hi])
            seg.append(np.full(hi - lo, k + offset))
            if field == "slot_x":
                ids.extend(strip.slot_nodes[lo:hi])
                edges.extend(strip.slot_edges[lo:hi])
            else:
                chosen = strip.node_ids[lo:hi]
                ids.extend(chosen)
                slotted.extend(n in with_slot for n in chosen)
        k = last + 1
    out = {"x": np.concatenate(xs), "segment": np.concatenate(seg).astype(int)}
    if field == "slot_x":
        out.update(nodes=ids, edges=edges)
    else:
        out.update(ids=ids, slotted=np.array(slotted, dtype=bool))
    return out


def _ranges(owner: np.ndarray, count: int) -> np.ndarray:
    """Start index of each segment's rows in an array sorted by segment, plus the end: (count + 1,)."""
    return np.searchsorted(owner, np.arange(count + 1))


def _outlines(a, b, slot_seg, slot_x, slot_top, h, half, depth) -> list[np.ndarray]:
    """Every segment's notched rectangle, as `flat._straight_outline` builds it, from one sorted vertex table."""
    y = h / 2.0
    count = len(a)
    length = b - a
    # fixed vertices: (0,-y) | bottom notches | (L,-y) (L,y) | top notches | (0,y) (0,-y)
    fixed_x = np.column_stack([np.zeros(count), length, length, np.zeros(count), np.zeros(count)])
    fixed_y = np.tile([-y, -y, y, y, -y], (count, 1))
    fixed_section = np.tile([0, 2, 3, 5, 6], (count, 1))
    rel = slot_x - a[slot_seg]
    notch_sign = np.where(slot_top, 1.0, -1.0)
    nx = rel[:, None] + notch_sign[:, None] * half * np.array([1.0, 1.0, -1.0, -1.0])
    ny = notch_sign[:, None] * np.array([y, y - depth + half, y - depth + half, y])
    nb = np.tile([0.0, -1.0, 0.0, 0.0], (len(rel), 1))
    order_key = np.where(slot_top, -rel, rel)  # bottom edge runs towards +x, the top edge back towards -x
    rows_seg = np.concatenate([np.repeat(np.arange(count), 5), np.repeat(slot_seg, 4)])
    section = np.concatenate([fixed_section.ravel(), np.repeat(np.where(slot_top, 4, 1), 4)])
    along = np.concatenate([np.zeros(5 * count), np.repeat(order_key, 4)])
    within = np.concatenate([np.zeros(5 * count), np.tile(np.arange(4), len(rel))])
    order = np.lexsort((within, along, section, rows_seg))
    table = np.column_stack([np.concatenate([fixed_x.ravel(), nx.ravel()]),
                             np.concatenate([fixed_y.ravel(), ny.ravel()]),
                             np.concatenate([np.zeros(5 * count), nb.ravel()])])[order]
    starts = np.searchsorted(rows_seg[order], np.arange(count))
    return split_rows(table, starts)


def _slot_contours(x: np.ndarray, top: np.ndarray, h: float, half: float, depth: float) -> np.ndarray:
    """(N, 5, 3) closed slot outlines as `pieces.slot_contours` draws them, in the segments' frames."""
    sign = np.where(top, 1.0, -1.0)[:, None]
    contours = np.empty((len(x), 5, 3))
    contours[:, :4, 0] = x[:, None] - sign * half * np.array([1.0, 1.0, -1.0, -1.0])
    y_edge, y_end = sign * h / 2.0, sign * (h / 2.0 - depth + half)
    contours[:, :4, 1] = np.hstack([y_edge, y_end, y_end, y_edge])
    contours[:, 4, :2] = contours[:, 0, :2]
    contours[:, :, 2] = [0.0, 1.0, 0.0, 0.0, 0.0]
    return contours


def _labels(spots: list, block: TextBlock, a: np.ndarray, edge_y: np.ndarray,
            slot_end_y: np.ndarray) -> dict[int, list[np.ndarray]]:
    """Per segment with a label spot: the label's strokes, then its arrow's shaft and head (as `pieces._label`)."""
    placed = np.array([k for k, spot in enumerate(spots) if spot is not None], dtype=int)
    if not placed.size:
        return {}
    count = len(spots)
    anchor, size = np.zeros(count), np.zeros(count)
    anchor[placed] = [spots[k][0] for k in placed]
    size[placed] = [spots[k][1] for k in placed]
    anchor -= a
    mid_y = (slot_end_y + edge_y) / 2.0
    start = anchor - (block.widths + 1.0 + ARROW_LENGTH) * size / 2.0
    points = block.points * size[block.owner][:, None]
    points[:, 0] += start[block.owner]
    points[:, 1] += (mid_y - size / 2.0)[block.owner]
    every = split_rows(points, block.starts)
    first = np.searchsorted(block.stroke_owner, np.arange(count + 1)).tolist()
    shaft_x = start + (block.widths + 1.0) * size
    length, head = ARROW_LENGTH * size, np.minimum(0.8 * size, ARROW_LENGTH * size / 3.0)
    tip = shaft_x + length
    shafts = np.stack([np.column_stack([shaft_x, mid_y]), np.column_stack([tip, mid_y])], axis=1)
    heads = np.stack([np.column_stack([tip - head, mid_y + head / 2.0]), np.column_stack([tip, mid_y]),
                      np.column_stack([tip - head, mid_y - head / 2.0])], axis=1)
    return {k: every[first[k]:first[k + 1]] + [shafts[k], heads[k]] for k in placed.tolist()}


def _seam_holes(segments: list[Segment], a: np.ndarray, start_seam: np.ndarray, end_seam: np.ndarray,
                options: UnrollOptions) -> tuple[list[np.ndarray], list[int]]:
    """The six screw-hole circles at each seam end of every segment (as `pieces` orders them); holes per segment."""
    seam_x, owner = [], []
    for k, segment in enumerate(segments):
        for join, flag in ((segment.start_join, start_seam[k]), (segment.end_join, end_seam[k])):
            if flag:
                seam_x.append(join.x)
                owner.append(k)
    if not seam_x:
        return [], [0] * len(segments)
    owner = np.array(owner)
    columns = np.array(seam_x)[:, None] + SEAM_HOLE_COLUMNS[None, :] * options.overlap   # (seams, 3)
    rows = SEAM_HOLE_ROWS * options.profile.h
    # per segment: every column of its seams for the first row, then again for the second row (as pieces does)
    seam = np.repeat(np.arange(len(seam_x)), len(rows) * 3)
    row = np.tile(np.repeat(np.arange(len(rows)), 3), len(seam_x))
    column = np.tile(np.arange(3), len(rows) * len(seam_x))
    order = np.lexsort((column, seam, row, owner[seam]))
    seam, row, column = seam[order], row[order], column[order]
    centres = np.column_stack([columns[seam, column] - a[owner[seam]], rows[row]])
    rings = np.empty((len(centres), 5, 3))
    rings[:, :, :2] = centres[:, None, :] + options.screw_hole / 2.0 * _QUARTERS[None, :, :]
    rings[:, :, 2] = [QUARTER_ARC_BULGE] * 4 + [0.0]
    return list(rings), (np.bincount(owner, minlength=len(segments)) * len(rows) * 3).tolist()
