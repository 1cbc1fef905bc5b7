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
from fabline.unroll.parts import Part, Polylines, Slot
from fabline.unroll.pieces import (ARROW_LENGTH, LABEL_TIE_MM, MIN_LABEL_HEIGHT, SEAM_HOLE_COLUMNS, SEAM_HOLE_ROWS,
                                   is_seam, segment_label, segment_meta)
from fabline.unroll.flat import circles, stays_straight
from fabline.unroll.seams import Segment
from fabline.unroll.stations import FAMILY_EDGE
from fabline.unroll.strokes import Characters, TextBlock, characters, gather, join_blocks, split_rows

ROWS_PER_BLOCK = 4096  # segments per block of the full straightness test (rows of up to a few hundred stations)


def straight_flags(segments: list[Segment], options: UnrollOptions) -> np.ndarray:
    """Per segment, True when `FlatCentreline.build` cuts it straight (`flat.stays_straight` on its stations).

    First the quick bound k L^2 / 8 < tolerance with the largest |k_n| over the segment (samples one beyond each
    end included), from one `maximum.reduceat` over all strips' |k_n| (each followed by a 0 sentinel) with
    interleaved [lo, hi) bounds; the segments it leaves in doubt get the full test, a block of rows at a time.
    """
    if not segments:
        return np.zeros(0, dtype=bool)
    curvature, bounds, base = [], [], 0
    for strip, group in _by_strip(segments):
        k_n = strip.geometry.k_n
        lo, hi = np.searchsorted(strip.curve.s_at_samples, [(s.start, s.end) for s in group]).T
        bounds.append(np.column_stack([base + np.maximum(lo - 1, 0), base + np.minimum(hi + 1, len(k_n))]).ravel())
        curvature += [np.abs(k_n), np.zeros(1)]
        base += len(k_n) + 1
    k_max = np.maximum.reduceat(np.concatenate(curvature), np.concatenate(bounds))[::2]
    length = np.array([s.end - s.start for s in segments])
    straight = k_max * length ** 2 / 8.0 < options.straight_tolerance
    doubtful = np.flatnonzero(~straight)
    if len(doubtful):
        stations = _stations([segments[k] for k in doubtful])
        for start in range(0, len(doubtful), ROWS_PER_BLOCK):
            x, kappa = _station_rows(stations, slice(start, start + ROWS_PER_BLOCK))
            straight[doubtful[start:start + ROWS_PER_BLOCK]] = stays_straight(x, kappa, options.straight_tolerance)
    return straight


def _stations(segments: list[Segment]) -> tuple[np.ndarray, ...]:
    """What `_station_rows` reads, one pass over the strips: all strips' samples and k_n there (concatenated), and per
    segment its first sample strictly inside (a row of those), how many lie inside, its ends and k_n at its ends."""
    xs, ks, first, inside, a, b, ka, kb, base = [], [], [], [], [], [], [], [], 0
    for strip, group in _by_strip(segments):
        samples, k_n = strip.curve.s_at_samples, strip.geometry.k_n
        starts, ends = np.array([(s.start, s.end) for s in group]).T
        lo, hi = np.searchsorted(samples, starts, side="right"), np.searchsorted(samples, ends, side="left")
        xs.append(samples)
        ks.append(k_n)
        first.append(base + lo)
        inside.append(hi - lo)
        a.append(starts)
        b.append(ends)
        ka.append(np.interp(starts, samples, k_n))
        kb.append(np.interp(ends, samples, k_n))
        base += len(samples)
    return tuple(np.concatenate(column) for column in (xs, ks, first, inside, a, b, ka, kb))


def _station_rows(stations: tuple[np.ndarray, ...], rows: slice) -> tuple[np.ndarray, np.ndarray]:
    """The stations of segments `rows` of a `_stations` table (their ends and the samples strictly inside, as
    `segment_part` takes them) and k_n at them, one row per segment, padded by repeating the end."""
    xs, ks, *columns = stations
    first, inside, a, b, ka, kb = (column[rows] for column in columns)
    column = np.arange(inside.max() + 2)[None, :]
    sample = np.minimum(first[:, None] + column - 1, len(xs) - 1)
    interior = (column >= 1) & (column <= inside[:, None])
    x = np.where(interior, xs[sample], b[:, None])
    kappa = np.where(interior, ks[sample], kb[:, None])
    x[:, 0], kappa[:, 0] = a, ka
    return x, kappa


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
    id_chars = characters(list(unique))
    widths = id_chars.widths[which]
    widest = np.zeros(len(segments))
    np.maximum.at(widest, node_seg, widths)
    reach = widest * height + 2.0 * TEXT_GAP
    r_node = reach[node_seg]
    tip = node_x + r_node
    start_seam = np.array([is_seam(s.start_join) for s in segments])
    end_seam = np.array([is_seam(s.end_join) for s in segments])
    seg_a, seg_b = a[node_seg], b[node_seg]
    start_overlap = np.array([s.start_join.overlap if flag else 0.0 for s, flag in zip(segments, start_seam)])
    end_overlap = np.array([s.end_join.overlap if flag else 0.0 for s, flag in zip(segments, end_seam)])
    in_seam = ((start_seam[node_seg] & (seg_a < tip) & (tip < seg_a + start_overlap[node_seg]))
               | (end_seam[node_seg] & (seg_b - end_overlap[node_seg] < tip) & (tip < seg_b)))
    right = (tip <= seg_b - TEXT_GAP) & ~in_seam
    dx = np.where(right, TEXT_GAP, -TEXT_GAP - widths * height)
    baseline = edge_y - sign * TEXT_GAP - np.where(sign > 0, height, 0.0)
    blocked_lo = np.where(right, node_x - TEXT_GAP, node_x - r_node)
    blocked_hi = np.where(right, node_x + r_node, node_x + TEXT_GAP)
    id_shift = np.column_stack([node_x - a[node_seg] + dx, baseline[node_seg]])

    # labels: the widest stretch between seam overlaps and node ids, for all segments at once
    labels = [segment_label(s) for s in segments]
    label_chars = characters(labels)
    starting, ending = np.flatnonzero(start_seam), np.flatnonzero(end_seam)
    span_seg = np.concatenate([starting, ending, node_seg])
    span_lo = np.concatenate([a[starting], b[ending] - end_overlap[ending], blocked_lo])
    span_hi = np.concatenate([a[starting] + start_overlap[starting], b[ending], blocked_hi])
    anchor, size = label_spots(label_chars.widths, a, b, span_seg, span_lo, span_hi, height)
    text, text_starts, text_stroke_at, text_point_at = _engraving(
        id_chars, which, id_shift, node_seg, height, label_chars, anchor, size, a, edge_y, slot_end_y)

    holes, hole_count = _seam_holes(segments, a, start_seam, end_seam, options)

    # the per-part assembly below only slices Python lists with Python ints, the cheapest way to build objects
    node_ids = nodes["ids"]
    hole_at = np.concatenate([[0], np.cumsum(hole_count)]).tolist()
    slot_list = list(map(Slot, slots["nodes"], list(slot_contours), slots["edges"]))
    mark_points = marks.reshape(-1, 2)
    mark_starts = 2 * (np.arange(len(node_x)) - node_range[node_seg])   # two vertices a mark, from its part's first
    node_s = np.round(node_x - a[node_seg], 4).tolist()
    node_rows = [{"id": n, "s": s} for n, s in zip(node_ids, node_s)]
    slot_bounds, node_bounds = slot_range.tolist(), node_range.tolist()
    parts = []
    for k, segment in enumerate(segments):
        s0, s1, n0, n1 = slot_bounds[k], slot_bounds[k + 1], node_bounds[k], node_bounds[k + 1]
        t0, t1 = text_stroke_at[k], text_stroke_at[k + 1]
        parts.append(Part(  # fields by position (id, kind, outline, lamella, holes, slots, marks, text, nodes, label,
            # grain, meta): keywords double the cost of making a dataclass
            segment.id, "strip", outlines[k], segment.strip.lamella, holes[hole_at[k]:hole_at[k + 1]],
            slot_list[s0:s1], Polylines(mark_points[2 * n0:2 * n1], mark_starts[n0:n1]),
            Polylines(text[text_point_at[k]:text_point_at[k + 1]], text_starts[t0:t1]), node_rows[n0:n1],
            labels[k], True, segment_meta(segment, None)))
        fixes = segment.strip.fix_x
        if len(fixes):  # end-fix holes on the centreline (y = 0), x from the segment's start
            fixes = fixes[(fixes > segment.start) & (fixes < segment.end)]
            parts[-1].holes = parts[-1].holes + circles(np.column_stack([fixes - segment.start, 0.0 * fixes]),
                                                        options.bolt_square / 2.0)
            if len(fixes):
                parts[-1].meta["end_fixes"] = len(fixes)
    return parts


def _gather(segments: list[Segment], field: str) -> dict:
    """Slots ("slot_x") or nodes ("node_x") of every segment, concatenated in segment order, with their segment index.

    A feature belongs to the segment whose [start, end) holds it; features in a gap between segments (at a
    singularity joint) belong to none. One searchsorted per strip, then index arrays over all strips' features.
    """
    values, names, flags, lows, highs, offset = [], [], [], [], [], 0
    for strip, group in _by_strip(segments):
        strip_values = getattr(strip, field)
        bounds = np.searchsorted(strip_values, [(s.start, s.end) for s in group]) + offset
        lows.append(bounds[:, 0])
        highs.append(bounds[:, 1])
        values.append(strip_values)
        if field == "slot_x":
            names += strip.slot_nodes
            flags += strip.slot_edges
        else:
            with_slot = set(strip.slot_nodes)
            names += strip.node_ids
            flags += [n in with_slot for n in strip.node_ids]
        offset += len(strip_values)
    low, high = np.concatenate(lows), np.concatenate(highs)
    counts = high - low
    index = np.repeat(low - (np.cumsum(counts) - counts), counts) + np.arange(counts.sum())
    out = {"x": np.concatenate(values)[index], "segment": np.repeat(np.arange(len(segments)), counts)}
    chosen = index.tolist()
    if field == "slot_x":
        out.update(nodes=[names[i] for i in chosen], edges=[flags[i] for i in chosen])
    else:
        out.update(ids=[names[i] for i in chosen], slotted=np.array(flags, dtype=bool)[index])
    return out


def _by_strip(segments: list[Segment]) -> list[tuple]:
    """The segments in runs of one strip each (a strip's segments follow each other): (strip, its segments)."""
    runs, k = [], 0
    while k < len(segments):
        last = k
        while last + 1 < len(segments) and segments[last + 1].strip is segments[k].strip:
            last += 1
        runs.append((segments[k].strip, segments[k:last + 1]))
        k = last + 1
    return runs


def _ranges(owner: np.ndarray, count: int) -> np.ndarray:
    """Start index of each segment's rows in an array sorted by segment, plus the end: (count + 1,)."""
    return np.searchsorted(owner, np.arange(count + 1))


def _outlines(a, b, slot_seg, slot_x, slot_top, h, half, depth) -> list[np.ndarray]:
    """Every segment's notched rectangle, as `flat._straight_outline` builds it, in one vertex table.

    Per segment the rows run (0,-y) | bottom notches by increasing x | (L,-y) (L,y) | top notches by decreasing x |
    (0,y) (0,-y); slots come sorted by segment and x, so each vertex's row follows from counts alone.
    """
    y = h / 2.0
    count = len(a)
    bottom = ~slot_top
    bottoms = np.bincount(slot_seg[bottom], minlength=count)
    tops = np.bincount(slot_seg[slot_top], minlength=count)
    slots_before = np.cumsum(bottoms + tops) - bottoms - tops
    base = 5 * np.arange(count) + 4 * slots_before              # first row of each segment
    table = np.zeros((5 * count + 4 * len(slot_x), 3))
    fixed = base[:, None] + np.column_stack([np.zeros(count, int), 1 + 4 * bottoms, 2 + 4 * bottoms,
                                             3 + 4 * (bottoms + tops), 4 + 4 * (bottoms + tops)])
    length = b - a
    table[fixed, 0] = np.column_stack([np.zeros(count), length, length, np.zeros(count), np.zeros(count)])
    table[fixed, 1] = [-y, -y, y, y, -y]
    # a slot's place along its edge: its rank among its segment's slots of that edge (the top edge runs backwards)
    bottom_rank = np.cumsum(bottom) - 1 - (np.cumsum(bottoms) - bottoms)[slot_seg]
    top_rank = np.cumsum(slot_top) - 1 - (np.cumsum(tops) - tops)[slot_seg]
    first = base[slot_seg] + np.where(slot_top, 3 + 4 * bottoms[slot_seg] + 4 * (tops[slot_seg] - 1 - top_rank),
                                      1 + 4 * bottom_rank)
    rows = first[:, None] + np.arange(4)
    sign = np.where(slot_top, 1.0, -1.0)[:, None]
    table[rows, 0] = (slot_x - a[slot_seg])[:, None] + sign * half * np.array([1.0, 1.0, -1.0, -1.0])
    table[rows, 1] = sign * np.array([y, y - depth + half, y - depth + half, y])
    table[rows, 2] = [0.0, -1.0, 0.0, 0.0]
    return split_rows(table, base)


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


def label_spots(widths: np.ndarray, a: np.ndarray, b: np.ndarray, span_seg: np.ndarray, span_lo: np.ndarray,
                span_hi: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """`pieces.label_spot` for every segment at once: per segment the label's centre station (NaN where no label
    fits) and cap height, from the segments' ranges [a, b] and the blocked spans (segment, lo, hi) in any order.

    The free stretches lie between the spans sorted along each segment; each one starts at the farthest end of
    the spans before it (a running maximum within the segment, taken over integer ranks so it stays exact).
    """
    count = len(a)
    lo, hi = np.maximum(a[span_seg], span_lo), np.minimum(b[span_seg], span_hi)
    keep = (span_hi > a[span_seg]) & (span_lo < b[span_seg])
    seg, lo, hi = span_seg[keep], lo[keep], hi[keep]
    order = np.lexsort((hi, lo, seg))
    seg, lo, hi = seg[order], lo[order], hi[order]
    by_end = np.lexsort((hi, seg))                       # ranks of the span ends, increasing segment by segment
    rank = np.empty(len(seg), dtype=int)
    rank[by_end] = np.arange(len(seg))
    reached = np.maximum.accumulate(rank) if len(seg) else rank
    first_of_segment = np.r_[True, seg[1:] != seg[:-1]] if len(seg) else np.zeros(0, dtype=bool)
    before = np.where(first_of_segment, -np.inf, hi[by_end][np.r_[0, reached[:-1]]] if len(seg) else hi)
    cursor = np.maximum(a[seg] + TEXT_GAP, before)
    last = np.full(count, -np.inf)
    np.maximum.at(last, seg, hi)
    closing = np.maximum(a + TEXT_GAP, last)
    # free stretches: before each span that starts past the cursor, then from the last cursor to the end
    gap = lo > cursor
    ends = b - TEXT_GAP > closing
    free_seg = np.concatenate([seg[gap], np.flatnonzero(ends)])
    free_lo = np.concatenate([cursor[gap], closing[ends]])
    free_hi = np.concatenate([lo[gap], (b - TEXT_GAP)[ends]])
    free_order = np.concatenate([np.flatnonzero(gap), np.full(int(ends.sum()), len(seg))])
    order = np.lexsort((free_order, free_seg))
    free_seg, free_lo, free_hi = free_seg[order], free_lo[order], free_hi[order]
    width = free_hi - free_lo
    widest = np.full(count, -np.inf)
    np.maximum.at(widest, free_seg, width)
    candidate = np.flatnonzero(width >= widest[free_seg] - LABEL_TIE_MM)
    owner, first = np.unique(free_seg[candidate], return_index=True)   # the first of equally wide stretches
    chosen = candidate[first]
    room = free_hi[chosen] - free_lo[chosen] - 2.0 * TEXT_GAP
    fitted = np.where(room > 0, np.minimum(height, room / (widths[owner] + ARROW_LENGTH + 1.0)), 0.0)
    anchor, size = np.full(count, np.nan), np.zeros(count)
    fits = fitted >= MIN_LABEL_HEIGHT
    anchor[owner[fits]] = (free_lo[chosen] + free_hi[chosen])[fits] / 2.0
    size[owner[fits]] = fitted[fits]
    return anchor, size


def _engraving(ids: Characters, which: np.ndarray, id_shift: np.ndarray, node_seg: np.ndarray, height: float,
               labels: Characters, anchor: np.ndarray, size: np.ndarray, a: np.ndarray, edge_y: np.ndarray,
               slot_end_y: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int], list[int]]:
    """Every segment's engraving in one vertex array, in the order `pieces` draws it: the ids of its nodes (id
    which[i] at cap height `height`, moved by id_shift[i]), then its label and the label's arrow, shaft and head
    (as `pieces._label`, where `label_spots` found room). Each character and arrow stroke is one item of one
    `gather` from the glyph tables, sorted by segment first. Returns the points, each stroke's start counted from
    its segment's first point, and per segment (count + 1 bounds) its first stroke and first point."""
    count = len(a)
    labelled = ~np.isnan(anchor)
    placed = np.flatnonzero(labelled)
    mid_y = (slot_end_y + edge_y) / 2.0
    start = np.where(labelled, anchor, 0.0) - a - (labels.widths + 1.0 + ARROW_LENGTH) * size / 2.0
    shaft_x = (start + (labels.widths + 1.0) * size)[placed]
    mid, length = mid_y[placed], ARROW_LENGTH * size[placed]
    head = np.minimum(0.8 * size[placed], length / 3.0)
    tip = shaft_x + length
    shafts = np.stack([np.column_stack([shaft_x, mid]), np.column_stack([tip, mid])], axis=1)
    heads = np.stack([np.column_stack([tip - head, mid + head / 2.0]), np.column_stack([tip, mid]),
                      np.column_stack([tip - head, mid - head / 2.0])], axis=1)
    m = len(placed)
    arrows = TextBlock(np.concatenate([shafts.reshape(-1, 2), heads.reshape(-1, 2)]),
                       np.array([2] * m + [3] * m, dtype=int), np.concatenate([2 * np.arange(m), 2 * m + 3 * np.arange(m)]),
                       np.arange(2 * m), np.zeros(2 * m))
    table = join_blocks([ids.table, labels.table, arrows])
    id_glyphs, label_glyphs = len(ids.table.widths), len(ids.table.widths) + len(labels.table.widths)
    id_char, label_char = _spans(ids.first[which], ids.lengths[which]), _spans(labels.first[placed], labels.lengths[placed])
    id_node = np.repeat(np.arange(len(which)), ids.lengths[which])
    label_seg = np.repeat(placed, labels.lengths[placed])
    entry = np.concatenate([ids.glyph[id_char], id_glyphs + labels.glyph[label_char], label_glyphs + np.arange(2 * m)])
    advance = np.concatenate([ids.advance[id_char], labels.advance[label_char], np.zeros(2 * m)])
    scale = np.concatenate([np.full(len(id_char), height), size[label_seg], np.ones(2 * m)])
    shift = np.concatenate([id_shift[id_node], np.column_stack([start, mid_y - size / 2.0])[label_seg], np.zeros((2 * m, 2))])
    segment = np.concatenate([node_seg[id_node], label_seg, placed, placed])
    order = np.argsort(segment, kind="stable")
    text = gather(table, entry[order], scale[order], shift[order], advance[order])
    stroke_segment = segment[order][text.stroke_owner]
    stroke_at = np.searchsorted(stroke_segment, np.arange(count + 1))
    point_at = np.append(text.starts, len(text.points))[stroke_at]
    return text.points, text.starts - point_at[stroke_segment], stroke_at.tolist(), point_at.tolist()


def _spans(first: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The indices first[i], first[i] + 1, ..., first[i] + counts[i] - 1 of every i, one after another."""
    row = np.cumsum(counts) - counts
    return np.repeat(first - row, counts) + np.arange(counts.sum())


def _seam_holes(segments: list[Segment], a: np.ndarray, start_seam: np.ndarray, end_seam: np.ndarray,
                options: UnrollOptions) -> tuple[list[np.ndarray], list[int]]:
    """The six screw-hole circles at each seam end of every segment (as `pieces` orders them); holes per segment."""
    seam_x, overlap, owner = [], [], []
    for k, segment in enumerate(segments):
        for join, flag in ((segment.start_join, start_seam[k]), (segment.end_join, end_seam[k])):
            if flag:
                seam_x.append(join.x)
                overlap.append(join.overlap)
                owner.append(k)
    if not seam_x:
        return [], [0] * len(segments)
    owner = np.array(owner)
    columns = np.array(seam_x)[:, None] + SEAM_HOLE_COLUMNS[None, :] * np.array(overlap)[:, None]   # (seams, 3)
    rows = SEAM_HOLE_ROWS * options.profile.h
    # per segment: every column of its seams for the first row, then again for the second row (as pieces does)
    seam = np.repeat(np.arange(len(seam_x)), len(rows) * 3)
    row = np.tile(np.repeat(np.arange(len(rows)), 3), len(seam_x))
    column = np.tile(np.arange(3), len(rows) * len(seam_x))
    order = np.lexsort((column, seam, row, owner[seam]))
    seam, row, column = seam[order], row[order], column[order]
    centres = np.column_stack([columns[seam, column] - a[owner[seam]], rows[row]])
    return circles(centres, options.screw_hole / 2.0), (np.bincount(owner, minlength=len(segments)) * len(rows) * 3).tolist()
