"""One strip segment to one flat part: notched outline, slots, seam screw holes, node marks, ids and label.

This is the reference construction, used for curved strips; `batch` builds straight ones the same way, faster.

Layout across the strip (family A slotted from the top edge, B from the bottom): node marks run from the
free edge to just short of the slot ends; node ids sit beside their marks along the free edge; the label
(segment id, which segments it joins, an arrow pointing along the node order) sits once per part in the
widest stretch of the free half that no node id or seam overlap takes. Six screw holes per seam end.
"""

from __future__ import annotations

import numpy as np

from fabline.unroll.flat import FlatCentreline, Notches, circles, strip_outline
from fabline.unroll.options import TEXT_GAP, UnrollOptions
from fabline.unroll.parts import Part, Polylines, Slot
from fabline.unroll.seams import SEAM_HOLE_COLUMNS, SEAM_HOLE_ROWS, Segment, node_text_reach
from fabline.unroll.stations import FAMILY_EDGE, OTHER_EDGE
from fabline.unroll.strokes import arrow, layout, split_rows

MIN_LABEL_HEIGHT = 1.5
ARROW_LENGTH = 3.0  # the label's orientation arrow, in cap heights
LABEL_TIE_MM = 1e-6  # free stretches this close in width count as equal: the label takes the first


def segment_part(segment: Segment, options: UnrollOptions, node_hole: float = 0.0) -> Part:
    """The flat part of one strip segment, in its own frame: x from 0 along the chord, centreline at y = 0; with
    `node_hole` (a diameter) a bolt hole on the centreline at every node (edge members' lamella connections)."""
    strip, a, b = segment.strip, segment.start, segment.end
    h, width, depth = options.profile.h, options.slot, options.slot_depth
    xs = strip.curve.s_at_samples
    inside = (xs > a) & (xs < b)
    stations = np.concatenate([[a], xs[inside], [b]])
    centre = FlatCentreline.build(stations, np.interp(stations, xs, strip.geometry.k_n), options.straight_tolerance)

    first, last = np.searchsorted(strip.slot_x, (a, b))  # slot_x is sorted
    slot_x = strip.slot_x[first:last]
    slot_nodes, slot_edges = strip.slot_nodes[first:last], strip.slot_edges[first:last]
    top = np.array([x for x, e in zip(slot_x, slot_edges) if e == "top"])
    bottom = np.array([x for x, e in zip(slot_x, slot_edges) if e == "bottom"])
    outline = strip_outline(centre, a, b, h, Notches(top, width, depth), Notches(bottom, width, depth))
    slots = [Slot(n, c, e) for n, c, e in zip(slot_nodes, slot_contours(centre, slot_x, slot_edges, options), slot_edges)]

    free_edge = OTHER_EDGE[FAMILY_EDGE[strip.family]]
    sign = -1.0 if free_edge == "bottom" else 1.0           # which way from the centreline the free edge lies
    edge_y = sign * h / 2.0
    slot_end_y = sign * (h / 2.0 - options.free_height)     # where the other edge's slots end
    first, last = np.searchsorted(strip.node_x, (a, b))  # node_x increases along the lamella
    in_nodes = list(zip(strip.node_ids[first:last], strip.node_x[first:last].tolist()))
    slotted = set(slot_nodes)
    marks_at = np.array([x for _, x in in_nodes])
    mark_far = np.array([slot_end_y + sign * TEXT_GAP if n in slotted else -edge_y + sign * TEXT_GAP for n, _ in in_nodes])
    marks = _marks(centre, marks_at, edge_y - sign * TEXT_GAP, mark_far)

    height = options.engrave_height
    reach = node_text_reach(options, [n for n, _ in in_nodes]) if in_nodes else 0.0
    baseline = edge_y - sign * TEXT_GAP - (height if sign > 0 else 0.0)
    seams = [(a, a + segment.start_join.overlap) if is_seam(segment.start_join) else (a, a),
             (b - segment.end_join.overlap, b) if is_seam(segment.end_join) else (b, b)]
    items, blocked = [], list(seams)
    for nid, x in in_nodes:
        glyphs = layout(nid)
        right = x + reach <= b - TEXT_GAP and not _inside_any(x + reach, seams)
        dx = TEXT_GAP if right else -TEXT_GAP - glyphs.width * height
        items.append((glyphs, x, dx, baseline, height))
        blocked.append((x - TEXT_GAP, x + reach) if right else (x - reach, x + TEXT_GAP))
    label = segment_label(segment)
    text = _engrave(centre, items)
    text += _label(centre, label, a, b, blocked, sign, slot_end_y, edge_y, height)

    holes = circles(_seam_holes(centre, segment, options), options.screw_hole / 2.0)
    if node_hole and len(marks_at):
        holes += circles(centre.place(marks_at, 0.0, 0.0), node_hole / 2.0)
    fixes = strip.fix_x[(strip.fix_x > a) & (strip.fix_x < b)]
    if len(fixes):
        holes += circles(centre.place(fixes, 0.0, 0.0), options.bolt_square / 2.0)
    nodes = [{"id": nid, "s": round(x - a, 4)} for nid, x in in_nodes]
    kind = "strip" if centre.straight else "curved-strip"
    meta = segment_meta(segment, _radius(centre))
    if len(fixes):
        meta["end_fixes"] = len(fixes)
    return Part(segment.id, kind, outline, lamella=strip.lamella, holes=holes, slots=slots, marks=marks,
                text=Polylines.of(text), nodes=nodes, label=label, grain=True, meta=meta)


def segment_meta(segment: Segment, radius: float | None) -> dict:
    """The part's `meta`: strip, side, offset, segment k of n, range along the strip, in-plane radius, joins."""
    strip = segment.strip
    return {
        "strip": strip.id, "family": strip.family, "side": strip.side, "offset_mm": strip.offset,
        "segment": segment.index, "segments": segment.count,
        "strip_range_mm": [round(segment.start, 3), round(segment.end, 3)],
        "length_mm": round(segment.end - segment.start, 3), "in_plane_radius_mm": radius,
        "joins": {"start": join_meta(segment, -1), "end": join_meta(segment, +1)},
    }


def slot_contours(centre: FlatCentreline, x: np.ndarray, edges: list[str], options: UnrollOptions) -> list[np.ndarray]:
    """Closed counter-clockwise outline of each edge slot: straight sides, a half-circle end (bulge 1)."""
    if not len(x):
        return []
    half, h = options.slot / 2.0, options.profile.h
    top = np.array([e == "top" for e in edges])[:, None]
    sign = np.where(top, 1.0, -1.0)
    y_edge = sign * h / 2.0
    y_end = sign * (h / 2.0 - options.slot_depth + half)
    dx = -sign * half * np.array([1.0, 1.0, -1.0, -1.0])
    ys = np.hstack([y_edge, y_end, y_end, y_edge])
    points = centre.place(np.repeat(x, 4), dx.ravel(), ys.ravel()).reshape(-1, 4, 2)
    contours = np.empty((len(x), 5, 3))
    contours[:, :4, :2] = points
    contours[:, 4, :2] = points[:, 0]
    contours[:, :, 2] = [0.0, 1.0, 0.0, 0.0, 0.0]
    return list(contours)


def segment_label(segment: Segment) -> str:
    """The engraved label: segment id, k/n, which segments it joins at seams, and singularity joints at its ends."""
    parts = [segment.id]
    if segment.count > 1:
        parts.append(f"{segment.index}/{segment.count}")
    strip_id = segment.strip.id
    for join, step, fmt in ((segment.start_join, -1, "<{}"), (segment.end_join, +1, "{}>")):
        if join is None:
            continue
        if join.kind == "seam":
            parts.append(fmt.format(f"{strip_id}.{segment.index + step}"))
        else:
            parts.append(fmt.format(f"J {join.node}"))
    return " ".join(parts)


def is_seam(join) -> bool:
    """True when a segment end is a seam (an overlap with the next segment of the strip)."""
    return join is not None and join.kind == "seam"


def _inside_any(x: float, spans: list[tuple[float, float]]) -> bool:
    return any(lo < x < hi for lo, hi in spans)


def join_meta(segment: Segment, step: int) -> dict | None:
    """The part's record of what its start (step -1) or end (+1) joins: a seam's partner part, or a joint node."""
    join = segment.start_join if step < 0 else segment.end_join
    if join is None:
        return None
    if join.kind == "seam":
        return {"kind": "seam", "part": f"{segment.strip.id}.{segment.index + step}", "between": list(join.interval),
                "seam_mm": round(join.x - segment.start, 3), "overlap_mm": round(join.overlap, 3)}
    return {"kind": "joint", "node": join.node}


def _radius(centre: FlatCentreline) -> float | None:
    """Smallest in-plane radius of the flat centreline (None when straight), mm."""
    if centre.straight:
        return None
    kappa = float(np.abs(centre.kappa).max())
    return round(1.0 / kappa, 3) if kappa > 0 else None


def _marks(centre: FlatCentreline, x: np.ndarray, y_from: float, y_to: np.ndarray) -> Polylines:
    """Engrave lines across the strip at stations x, from y_from to y_to, all placed in one call."""
    if not len(x):
        return Polylines.of([])
    points = centre.place(np.repeat(x, 2), np.zeros(2 * len(x)), np.column_stack([np.full(len(x), y_from), y_to]).ravel())
    return Polylines(points, 2 * np.arange(len(x)))


def _engrave(centre: FlatCentreline, items: list) -> list[np.ndarray]:
    """Strokes of several texts, each (glyphs, anchor, dx, baseline y, height), placed in one vectorised call, each
    point at station anchor + dx and its y across the centreline there: on a curved strip the text follows the curve
    (set out along the tangent it would leave the strip's outline)."""
    items = [item for item in items if len(item[0].points)]
    if not items:
        return []
    anchors, dx, y, splits, offset = [], [], [], [], 0
    for glyphs, anchor, x0, y0, height in items:
        anchors.append(np.full(len(glyphs.points), anchor))
        dx.append(x0 + glyphs.points[:, 0] * height)
        y.append(y0 + glyphs.points[:, 1] * height)
        splits.extend(glyphs.starts + offset)
        offset += len(glyphs.points)
    points = centre.place(np.concatenate(anchors) + np.concatenate(dx), 0.0, np.concatenate(y))
    return split_rows(points, splits)


def label_spot(width: float, a: float, b: float, blocked: list[tuple[float, float]],
               height: float) -> tuple[float, float] | None:
    """Centre station and cap height of a label `width` cap heights wide (arrow included), or None if nothing fits.

    The label goes in the middle of the widest stretch of [a, b] that no span in `blocked` takes, shrunk to fit;
    of stretches equally wide (a regular grid has many) the first, so rounding noise cannot move it.
    """
    spans = sorted((max(a, lo), min(b, hi)) for lo, hi in blocked if hi > a and lo < b)
    free, cursor = [], a + TEXT_GAP
    for lo, hi in spans:
        if lo > cursor:
            free.append((cursor, lo))
        cursor = max(cursor, hi)
    if b - TEXT_GAP > cursor:
        free.append((cursor, b - TEXT_GAP))
    if not free:
        return None
    widest = max(hi - lo for lo, hi in free)
    lo, hi = next((lo, hi) for lo, hi in free if hi - lo >= widest - LABEL_TIE_MM)  # the first of equals, stably
    room = hi - lo - 2.0 * TEXT_GAP
    size = min(height, room / (width + ARROW_LENGTH + 1.0)) if room > 0 else 0.0
    return ((lo + hi) / 2.0, size) if size >= MIN_LABEL_HEIGHT else None


def _label(centre: FlatCentreline, label: str, a: float, b: float, blocked: list[tuple[float, float]],
           sign: float, slot_end_y: float, edge_y: float, height: float) -> list[np.ndarray]:
    """The label and an arrow along +x, centred in the widest free stretch of the free half, shrunk to fit."""
    glyphs = layout(label)
    spot = label_spot(glyphs.width, a, b, blocked, height)
    if spot is None:
        return []
    anchor, size = spot
    mid_y = (slot_end_y + edge_y) / 2.0
    start = -(glyphs.width + 1.0 + ARROW_LENGTH) * size / 2.0
    strokes = _engrave(centre, [(glyphs, anchor, start, mid_y - size / 2.0, size)])
    shaft_start = start + (glyphs.width + 1.0) * size
    for line in arrow(ARROW_LENGTH * size, size * 0.8):
        strokes.append(centre.place(anchor + shaft_start + line[:, 0], 0.0, mid_y + line[:, 1]))
    return strokes


def _seam_holes(centre: FlatCentreline, segment: Segment, options: UnrollOptions) -> np.ndarray:
    """Centres (M, 2) of the six screw holes at each seam end of the segment."""
    seams = [join for join in (segment.start_join, segment.end_join) if is_seam(join)]
    if not seams:
        return np.zeros((0, 2))
    x = (np.array([join.x for join in seams])[:, None]
         + SEAM_HOLE_COLUMNS[None, :] * np.array([join.overlap for join in seams])[:, None]).ravel()
    rows = SEAM_HOLE_ROWS * options.profile.h
    return centre.place(np.tile(x, len(rows)), 0.0, np.repeat(rows, len(x)))
