"""Contours with arcs (vertices [x, y, bulge]) for toolpaths: lengths, reversal, splitting and kerf offset.

The kerf offset moves every line sideways and turns every arc into a concentric arc of a different
radius, joined with sharp (mitre) corners as shapely's mitre buffer does, so arcs stay arcs for G2/G3;
where that offset degenerates, shapely's buffer of the flattened contour is used instead.
"""

from __future__ import annotations

import numpy as np
import shapely

from fabline.unroll.parts import flatten_contour

FLATTEN_TOLERANCE = 0.002   # mm sagitta when arcs must become lines (checks, fallbacks)
MITRE_LIMIT = 5.0           # mitre length / offset distance before a corner is bevelled (shapely's default)


def with_bulges(contour: np.ndarray) -> np.ndarray:
    """Any (N, 2) or (N, 3) contour as a float (N, 3) array with a bulge column."""
    contour = np.asarray(contour, dtype=float)
    if contour.shape[1] == 3:
        return contour.copy()
    return np.column_stack([contour, np.zeros(len(contour))])


def stack_contours(contours: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Many (N, 2) or (N, 3) contours as one float [x, y, bulge] array, the row where each ends, and whether each is
    closed (its last vertex equals its first, np.allclose's test written out), all at once: a part has hundreds
    of short label strokes, where numpy calls per contour would dominate."""
    sizes = np.array([len(contour) for contour in contours], dtype=int)
    ends = np.cumsum(sizes)
    starts = ends - sizes
    stacked = np.zeros((int(ends[-1]) if len(ends) else 0, 3))
    for contour, start in zip(contours, starts.tolist()):
        stacked[start:start + len(contour), :contour.shape[1]] = contour
    first, last = stacked[starts, :2], stacked[ends - 1, :2]
    closed = (sizes >= 3) & np.all(np.abs(first - last) <= 1e-9 + 1e-5 * np.abs(last), axis=1)
    return stacked, ends, closed


def arc_centres(contour: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each segment: centre (N-1, 2), radius and signed sweep (radians, + is counter-clockwise); lines get sweep 0."""
    p0, p1, bulge = contour[:-1, :2], contour[1:, :2], contour[:-1, 2]
    sweep = 4.0 * np.arctan(bulge)
    chord_vec = p1 - p0
    chord = np.hypot(chord_vec[:, 0], chord_vec[:, 1])
    arc = bulge != 0
    radius = np.zeros(len(p0))
    centre = (p0 + p1) / 2.0
    if np.any(arc):
        half = sweep[arc] / 2.0
        radius[arc] = chord[arc] / (2.0 * np.abs(np.sin(half)))
        left = np.column_stack([-chord_vec[arc, 1], chord_vec[arc, 0]]) / chord[arc, None]
        centre[arc] = centre[arc] + left * (chord[arc] / (2.0 * np.tan(half)))[:, None]
    return centre, radius, sweep


def segment_lengths(contour: np.ndarray) -> np.ndarray:
    """Length of every segment, arcs measured along the arc."""
    _, radius, sweep = arc_centres(contour)
    chord = np.hypot(*(contour[1:, :2] - contour[:-1, :2]).T)
    return np.where(sweep != 0, radius * np.abs(sweep), chord)


def signed_area(contour: np.ndarray) -> float:
    """Area enclosed by a closed contour with arcs; positive when it runs counter-clockwise."""
    x, y = contour[:, 0], contour[:, 1]
    area = 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))
    _, radius, sweep = arc_centres(contour)
    return area + float(np.sum(0.5 * radius ** 2 * (sweep - np.sin(sweep))))


def reverse(contour: np.ndarray) -> np.ndarray:
    """The same path run backwards: vertex order reversed, each arc's bulge negated and moved to its new start."""
    out = contour[::-1].copy()
    out[:-1, 2] = -contour[-2::-1, 2]
    out[-1, 2] = 0.0
    return out


def rotate_start(contour: np.ndarray, index: int) -> np.ndarray:
    """A closed contour started at vertex `index` instead of vertex 0."""
    if index % (len(contour) - 1) == 0:
        return contour
    body = contour[:-1]
    rolled = np.vstack([body[index:], body[:index], body[index:index + 1]])
    rolled[-1, 2:] = 0.0
    return rolled


def sub_path(contour: np.ndarray, start: float, end: float) -> np.ndarray:
    """The open piece of a path between arc lengths `start` < `end` from its first vertex, arcs kept as arcs."""
    lengths = segment_lengths(contour)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    centre, _, sweep = arc_centres(contour)
    out: list[list[float]] = []

    def point(i: int, s: float) -> np.ndarray:
        f = 0.0 if lengths[i] == 0 else (s - cumulative[i]) / lengths[i]
        p0 = contour[i, :2]
        if sweep[i] == 0:
            return p0 + f * (contour[i + 1, :2] - p0)
        a = sweep[i] * f
        c, s_ = np.cos(a), np.sin(a)
        v = p0 - centre[i]
        return centre[i] + np.array([c * v[0] - s_ * v[1], s_ * v[0] + c * v[1]])

    for i in range(len(lengths)):
        s0, s1 = max(start, cumulative[i]), min(end, cumulative[i + 1])
        if s1 <= s0:
            continue
        fraction = 0.0 if lengths[i] == 0 else (s1 - s0) / lengths[i]
        out.append([*point(i, s0), np.tan(sweep[i] * fraction / 4.0)])
        last = point(i, s1)
    out.append([*last, 0.0])
    return np.array(out)


def remove_intervals(contour: np.ndarray, removed: list[tuple[float, float]]) -> list[np.ndarray]:
    """A closed contour without the arc-length intervals in `removed` (tabs, shared edges): the open pieces left."""
    perimeter = float(np.sum(segment_lengths(contour)))
    merged: list[list[float]] = []
    for a, b in sorted((max(0.0, a), min(perimeter, b)) for a, b in removed if b > a):
        if merged and a <= merged[-1][1] + 1e-9:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    if not merged:
        return [contour]
    kept, cursor = [], 0.0
    for a, b in merged:
        if a - cursor > 1e-6:
            kept.append((cursor, a))
        cursor = b
    if perimeter - cursor > 1e-6:
        kept.append((cursor, perimeter))
    pieces = [sub_path(contour, a, b) for a, b in kept]
    if len(kept) > 1 and kept[0][0] == 0.0 and kept[-1][1] == perimeter:
        pieces = [np.vstack([pieces[-1][:-1], pieces[0]])] + pieces[1:-1]
    return pieces


def to_polygon(contour: np.ndarray) -> shapely.Polygon:
    """The closed contour as a shapely polygon, arcs flattened within FLATTEN_TOLERANCE."""
    return shapely.Polygon(flatten_contour(contour, FLATTEN_TOLERANCE))


def shapely_offset(contour: np.ndarray, distance: float) -> np.ndarray | None:
    """shapely's mitre buffer of a closed contour (+ grows the area); None when the contour vanishes or splits."""
    grown = to_polygon(contour).buffer(distance, join_style="mitre", mitre_limit=MITRE_LIMIT)
    if grown.geom_type != "Polygon" or grown.is_empty:
        return None
    ring = with_bulges(np.asarray(grown.exterior.coords))
    return ring if signed_area(ring) > 0 else reverse(ring)


def offset(contour: np.ndarray, distance: float) -> np.ndarray | None:
    """A closed contour offset by `distance` (positive grows its area) with sharp corners and arcs kept as arcs.

    Falls back to shapely's flattened mitre buffer when the analytic offset degenerates (a segment or arc
    vanishing, the contour crossing itself); None when the contour vanishes altogether.
    """
    contour = with_bulges(contour)
    if distance == 0:
        return contour
    if signed_area(contour) < 0:
        contour = reverse(contour)
    analytic = _analytic_offset(contour, distance)
    if analytic is not None and signed_area(analytic) > 0 and to_polygon(analytic).is_valid:
        return analytic
    return shapely_offset(contour, distance)


def _analytic_offset(contour: np.ndarray, distance: float) -> np.ndarray | None:
    """Offset of a counter-clockwise closed contour to its right (outside) by `distance`; None if it degenerates."""
    p0, p1 = contour[:-1, :2], contour[1:, :2]
    centre, radius, sweep = arc_centres(contour)
    direction = p1 - p0
    length = np.hypot(direction[:, 0], direction[:, 1])
    if np.any(length < 1e-9):
        return None
    direction = direction / length[:, None]
    right = np.column_stack([direction[:, 1], -direction[:, 0]])
    is_arc = sweep != 0
    new_radius = np.where(sweep > 0, radius + distance, radius - distance)
    if np.any(new_radius[is_arc] <= 1e-6):
        return None
    scale = (new_radius / np.where(is_arc, radius, 1.0))[:, None]
    starts = np.where(is_arc[:, None], centre + (p0 - centre) * scale, p0 + distance * right)
    ends = np.where(is_arc[:, None], centre + (p1 - centre) * scale, p1 + distance * right)

    # joint k joins the end of segment k-1 to the start of segment k
    prev_end, prev_dir, prev_arc = np.roll(ends, 1, axis=0), np.roll(direction, 1, axis=0), np.roll(is_arc, 1)
    joint = starts.copy()
    smooth = np.hypot(*(prev_end - starts).T) < 1e-9
    lines = ~smooth & ~is_arc & ~prev_arc
    cross = prev_dir[:, 0] * direction[:, 1] - prev_dir[:, 1] * direction[:, 0]
    parallel = np.abs(cross) < 1e-12
    gap = starts - prev_end
    t = (gap[:, 0] * direction[:, 1] - gap[:, 1] * direction[:, 0]) / np.where(parallel, 1.0, cross)
    joint[lines] = (prev_end + t[:, None] * prev_dir)[lines]
    found = smooth | (lines & ~parallel)
    for k in np.flatnonzero(~smooth & ~lines):
        point = _intersect(k - 1, k, starts, ends, direction, centre, new_radius, is_arc, contour[k, :2])
        if point is not None:
            joint[k], found[k] = point, True
    mitred = found & (np.hypot(*(joint - contour[:-1, :2]).T) <= MITRE_LIMIT * abs(distance) + 1e-12)
    bevel = ~mitred       # a mitre beyond the limit (or none at all) is cut off straight, as shapely does
    seg_start = np.where(bevel[:, None], starts, joint)
    seg_end = np.roll(np.where(bevel[:, None], prev_end, joint), -1, axis=0)

    chord = seg_end - seg_start
    if np.any(np.einsum("ij,ij->i", chord, direction)[~is_arc] <= 1e-9):
        return None
    a0 = np.arctan2(seg_start[:, 1] - centre[:, 1], seg_start[:, 0] - centre[:, 0])
    a1 = np.arctan2(seg_end[:, 1] - centre[:, 1], seg_end[:, 0] - centre[:, 0])
    new_sweep = np.where(sweep > 0, (a1 - a0) % (2 * np.pi), -((a0 - a1) % (2 * np.pi)))
    if np.any(np.abs(new_sweep - sweep)[is_arc] > np.pi / 2):
        return None
    bulge = np.where(is_arc, np.tan(new_sweep / 4.0), 0.0)
    rows = []
    for k in range(len(p0)):
        if bevel[k]:
            rows.append((prev_end[k, 0], prev_end[k, 1], 0.0))
        rows.append((seg_start[k, 0], seg_start[k, 1], bulge[k]))
    rows.append((rows[0][0], rows[0][1], 0.0))
    return np.array(rows)


def _intersect(a: int, b: int, starts, ends, direction, centre, radius, is_arc, near) -> np.ndarray | None:
    """The intersection of offset segments a and b (as full lines/circles) nearest to `near`."""
    if not is_arc[a] and not is_arc[b]:
        d1, d2 = direction[a], direction[b]
        cross = d1[0] * d2[1] - d1[1] * d2[0]
        if abs(cross) < 1e-12:
            return None
        t = ((starts[b][0] - ends[a][0]) * d2[1] - (starts[b][1] - ends[a][1]) * d2[0]) / cross
        return ends[a] + t * d1
    if is_arc[a] and is_arc[b]:
        candidates = _circle_circle(centre[a], radius[a], centre[b], radius[b])
    else:
        line, arc = (b, a) if is_arc[a] else (a, b)
        candidates = _line_circle(starts[line], direction[line], centre[arc], radius[arc])
    if not candidates:
        return None
    return min(candidates, key=lambda p: np.hypot(*(p - near)))


def _line_circle(point, direction, centre, radius) -> list[np.ndarray]:
    offset_vec = point - centre
    b = np.dot(offset_vec, direction)
    c = np.dot(offset_vec, offset_vec) - radius ** 2
    disc = b * b - c
    if disc < 0:
        return []
    root = np.sqrt(disc)
    return [point + (-b - root) * direction, point + (-b + root) * direction]


def _circle_circle(c1, r1, c2, r2) -> list[np.ndarray]:
    gap = c2 - c1
    d = np.hypot(*gap)
    if d < 1e-12 or d > r1 + r2 or d < abs(r1 - r2):
        return []
    a = (r1 * r1 - r2 * r2 + d * d) / (2 * d)
    h = np.sqrt(max(r1 * r1 - a * a, 0.0))
    mid = c1 + a * gap / d
    perp = np.array([-gap[1], gap[0]]) / d
    return [mid + h * perp, mid - h * perp]
