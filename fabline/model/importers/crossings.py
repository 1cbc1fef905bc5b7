"""Find a network's nodes in curves alone: where lamellas of family A cross lamellas of family B.

Every polyline is cut into segments; k-d trees over short pieces of them give the candidate pairs
(family A pieces against family B pieces for crossings, all pieces for a curve touching itself), and
the exact closest points of each candidate segment pair decide. A crossing is a closest approach
within the tolerance; one between the tolerance and ten times it is reported as a near-miss. Three
lamellas through one point make a singularity node. A curve that comes back to itself is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fabline.errors import FablineError

NEAR_MISS_FACTOR = 10.0
"""Closest approaches up to this many tolerances are reported as near-misses."""


@dataclass
class NearMiss:
    """Two lamellas of different families that come close without crossing within the tolerance."""

    curve_a: int
    curve_b: int
    distance: float
    xyz: np.ndarray


@dataclass
class Crossings:
    """Nodes found in a set of curves: positions, and per node the curves through it with arc lengths."""

    xyz: np.ndarray
    """(N, 3) node positions: the mean of the midpoints of the closest points of the crossing curves."""
    members: list[list[tuple[int, float]]]
    """Per node, (curve index, arc length along that curve) for each curve through the node."""
    near_misses: list[NearMiss]
    """Closest approaches between one and NEAR_MISS_FACTOR tolerances, nearest first."""


@dataclass
class _Segments:
    """All curves' segments in flat arrays."""

    start: np.ndarray
    end: np.ndarray
    curve: np.ndarray
    local: np.ndarray
    arc_start: np.ndarray
    length: np.ndarray


def find_crossings(curves: list[np.ndarray], families: list[str], ids: list[str], tolerance: float,
                   source: str) -> Crossings:
    """Nodes where curves of family A cross curves of family B within `tolerance` (model units).

    Raises FablineError naming `source` and the lamella when a curve touches itself, or when more than
    three lamellas meet at one point.
    """
    segments = _segments(curves)
    near = NEAR_MISS_FACTOR * tolerance
    pieces = _Pieces.of(segments, near)
    _refuse_self_contact(segments, pieces, tolerance, ids, source)

    in_b = np.array([f == "B" for f in families])[segments.curve]
    seg_a, seg_b = pieces.pairs_across(in_b, near)
    p, q, t_a, t_b = closest_points(segments.start[seg_a], segments.end[seg_a],
                                    segments.start[seg_b], segments.end[seg_b])
    distance = np.linalg.norm(p - q, axis=1)
    close = distance <= near
    seg_a, seg_b, distance = seg_a[close], seg_b[close], distance[close]
    arc_a = segments.arc_start[seg_a] + t_a[close] * segments.length[seg_a]
    arc_b = segments.arc_start[seg_b] + t_b[close] * segments.length[seg_b]
    midpoint = (p[close] + q[close]) / 2

    best = _closest_per_approach(segments, seg_a, seg_b, distance)
    curve_a, curve_b = segments.curve[seg_a[best]], segments.curve[seg_b[best]]
    hit = distance[best] <= tolerance
    near_misses = [NearMiss(int(a), int(b), float(d), xyz) for a, b, d, xyz in
                   zip(curve_a[~hit], curve_b[~hit], distance[best][~hit], midpoint[best][~hit])]
    near_misses.sort(key=lambda miss: miss.distance)
    xyz, members = _nodes(curve_a[hit], curve_b[hit], arc_a[best][hit], arc_b[best][hit],
                          midpoint[best][hit], tolerance, ids, source)
    return Crossings(xyz, members, near_misses)


def closest_points(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segment pairs p0-p1 and q0-q1 (rows), and their parameters in [0, 1].

    The clamped closed-form solution (Ericson, Real-Time Collision Detection, 5.1.9), vectorised;
    segments must have non-zero length.
    """
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    general = denom > 1e-12 * a * e
    s = np.where(general, np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    below, above = t < 0, t > 1
    s = np.where(below, np.clip(-c / a, 0.0, 1.0), np.where(above, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return p0 + d1 * s[:, None], q0 + d2 * t[:, None], s, t


def _segments(curves: list[np.ndarray]) -> _Segments:
    starts, ends, curve_index, local, arc_start, lengths = [], [], [], [], [], []
    for index, points in enumerate(curves):
        step = np.linalg.norm(np.diff(points, axis=0), axis=1)
        starts.append(points[:-1])
        ends.append(points[1:])
        curve_index.append(np.full(len(step), index))
        local.append(np.arange(len(step)))
        arc_start.append(np.r_[0.0, np.cumsum(step)[:-1]])
        lengths.append(step)
    return _Segments(*(np.concatenate(a) for a in (starts, ends, curve_index, local, arc_start, lengths)))


@dataclass
class _Pieces:
    """Segments cut into pieces no longer than `size`, by their midpoints: for finding close segment pairs.

    Any two points within `reach` lie on pieces whose midpoints are within `reach + size`, so k-d trees
    over the midpoints with that radius find every close segment pair whatever the segment lengths.
    """

    owner: np.ndarray
    middle: np.ndarray
    size: float
    segment_count: int

    @classmethod
    def of(cls, segments: _Segments, reach: float) -> "_Pieces":
        # most segments whole (fewer pieces), a few long ones cut (a bounded search radius)
        size = max(float(np.percentile(segments.length, 90)), reach / NEAR_MISS_FACTOR)
        count = np.ceil(segments.length / size).astype(np.int64)
        owner = np.repeat(np.arange(len(count)), count)
        offset = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
        fraction = (offset + 0.5) / count[owner]
        middle = segments.start[owner] + (segments.end[owner] - segments.start[owner]) * fraction[:, None]
        return cls(owner, middle, size, len(count))

    def pairs_across(self, in_b: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
        """(family A segment, family B segment) pairs that may come within `reach`, each pair once."""
        piece_b = in_b[self.owner]
        owner_a, owner_b = self.owner[~piece_b], self.owner[piece_b]
        if len(owner_a) == 0 or len(owner_b) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        found = cKDTree(self.middle[~piece_b]).sparse_distance_matrix(
            cKDTree(self.middle[piece_b]), reach + self.size, output_type="ndarray")
        return self._unique(owner_a[found["i"]], owner_b[found["j"]])

    def pairs_within(self, reach: float) -> tuple[np.ndarray, np.ndarray]:
        """Segment pairs (first < second) that may come within `reach`, each pair once."""
        pairs = cKDTree(self.middle).query_pairs(reach + self.size, output_type="ndarray")
        first, second = self.owner[pairs[:, 0]], self.owner[pairs[:, 1]]
        return self._unique(np.minimum(first, second), np.maximum(first, second))

    def _unique(self, first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key, _ = _unique(first.astype(np.int64) * self.segment_count + second)
        return key // self.segment_count, key % self.segment_count


def _refuse_self_contact(segments: _Segments, pieces: _Pieces, tolerance: float, ids: list[str],
                         source: str) -> None:
    """Raise if a curve comes within the tolerance of itself between points far apart along it."""
    first, second = pieces.pairs_within(tolerance)
    same = (segments.curve[first] == segments.curve[second]) & (second - first > 1)
    first, second = first[same], second[same]
    p, q, t_first, t_second = closest_points(segments.start[first], segments.end[first],
                                             segments.start[second], segments.end[second])
    arc_first = segments.arc_start[first] + t_first * segments.length[first]
    arc_second = segments.arc_start[second] + t_second * segments.length[second]
    touching = (np.linalg.norm(p - q, axis=1) <= tolerance) & (np.abs(arc_second - arc_first) > 3 * tolerance)
    if touching.any():
        k = np.flatnonzero(touching)[0]
        x, y, z = p[k]
        raise FablineError(
            f"{source}: lamella {ids[segments.curve[first[k]]]}: curve overlaps itself at ({x:.6g}, {y:.6g}, {z:.6g}) "
            f"(arc lengths {arc_first[k]:.6g} and {arc_second[k]:.6g} meet)")


def _unique(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted distinct integer keys and each key's index among them (np.unique by one stable sort, which
    is many times faster than numpy's hashing path for millions of keys)."""
    order = np.argsort(keys, kind="stable")
    ordered = keys[order]
    first = np.r_[True, ordered[1:] != ordered[:-1]] if len(ordered) else np.zeros(0, dtype=bool)
    inverse = np.empty(len(keys), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return ordered[first], inverse


def _clusters(points: np.ndarray, reach: float, norm: float = 2.0) -> tuple[int, np.ndarray]:
    """Group points chained by distances within `reach` (Minkowski `norm`): the group count and each point's group."""
    links = cKDTree(points).query_pairs(reach, p=norm, output_type="ndarray")
    graph = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(len(points),) * 2)
    return connected_components(graph, directed=False)


def _closest_per_approach(segments: _Segments, seg_a: np.ndarray, seg_b: np.ndarray,
                          distance: np.ndarray) -> np.ndarray:
    """Index of the closest candidate of each approach: candidates of one curve pair on adjacent segments."""
    if len(seg_a) == 0:
        return np.zeros(0, dtype=np.int64)
    n_curves = int(segments.curve.max()) + 1
    _, pair = _unique(segments.curve[seg_a] * n_curves + segments.curve[seg_b])
    # candidates of one pair whose segments are neighbours (Chebyshev distance 1) form one approach
    grid = np.c_[pair * 4, segments.local[seg_a], segments.local[seg_b]].astype(float)
    _, approach = _clusters(grid, 1.0, norm=np.inf)
    order = np.lexsort((distance, approach))
    first_of_each = np.r_[True, approach[order][1:] != approach[order][:-1]]
    return order[first_of_each]


def _nodes(curve_a: np.ndarray, curve_b: np.ndarray, arc_a: np.ndarray, arc_b: np.ndarray,
           midpoint: np.ndarray, tolerance: float, ids: list[str], source: str
           ) -> tuple[np.ndarray, list[list[tuple[int, float]]]]:
    """Merge crossings within the tolerance of each other into nodes of two (or, at a singularity, three) curves."""
    if len(midpoint) == 0:
        return np.zeros((0, 3)), []
    n_nodes, node = _clusters(midpoint, tolerance)
    count = np.bincount(node, minlength=n_nodes)
    xyz = np.stack([np.bincount(node, midpoint[:, k], n_nodes) for k in range(3)], axis=1) / count[:, None]
    # one row per (node, curve): the curve's arc length there, averaged over the crossings it takes part in
    rows_node = np.r_[node, node]
    rows_curve = np.r_[curve_a, curve_b]
    rows_arc = np.r_[arc_a, arc_b]
    n_curves = int(rows_curve.max()) + 1
    key, inverse = _unique(rows_node * n_curves + rows_curve)
    arc = np.bincount(inverse, rows_arc) / np.bincount(inverse)
    key_node, key_curve = key // n_curves, key % n_curves
    valence = np.bincount(key_node, minlength=n_nodes)
    crowded = np.flatnonzero(valence > 3)
    if crowded.size:
        k = crowded[0]
        names = ", ".join(ids[c] for c in key_curve[key_node == k])
        x, y, z = xyz[k]
        raise FablineError(f"{source}: {valence[k]} lamellas meet at ({x:.6g}, {y:.6g}, {z:.6g}) within the "
                           f"tolerance ({names}); a node joins two lamellas, or three at a singularity")
    bounds = np.r_[0, np.cumsum(valence)]
    members = [list(zip(key_curve[bounds[k]:bounds[k + 1]].tolist(), arc[bounds[k]:bounds[k + 1]].tolist()))
               for k in range(n_nodes)]
    return xyz, members
