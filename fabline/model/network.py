"""The network model: nodes where lamellas cross, lamellas as ordered node chains with dense centrelines.

A model declares its units; every coordinate in it is in those units. `Network.in_mm()` gives the
millimetre copy that fabrication stages work in.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from fabline.errors import FablineError
from fabline.fileio import MAX_MM

UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "ft": 304.8}
NODE_KINDS = ("grid", "singularity", "support", "edge-end")
FAMILIES = ("A", "B")


@dataclass
class Node:
    """A point of the network: where lamellas cross, a support, or a lamella's end at the edge."""

    id: str
    xyz: np.ndarray
    normal: np.ndarray
    kind: str = "grid"


@dataclass
class Lamella:
    """One continuous strip: its family, the nodes it passes in order, its centreline and surface normals."""

    id: str
    family: str
    nodes: list[str]
    curve: np.ndarray
    normals: np.ndarray


@dataclass
class Network:
    """A gridshell's network model: nodes by id and lamellas, in the declared units."""

    units: str
    nodes: dict[str, Node]
    lamellas: list[Lamella]
    name: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def mm_per_unit(self) -> float:
        return UNIT_TO_MM[self.units]

    def in_mm(self) -> "Network":
        """A copy with every coordinate in millimetres (the same object if already in mm)."""
        if self.units == "mm":
            return self
        k = self.mm_per_unit
        nodes = {nid: replace(n, xyz=n.xyz * k) for nid, n in self.nodes.items()}
        lamellas = [replace(lam, curve=lam.curve * k) for lam in self.lamellas]
        return Network("mm", nodes, lamellas, self.name, dict(self.meta))

    def lamellas_at(self) -> dict[str, list[str]]:
        """Node id -> ids of the lamellas passing through it."""
        at: dict[str, list[str]] = {nid: [] for nid in self.nodes}
        for lam in self.lamellas:
            for nid in lam.nodes:
                at[nid].append(lam.id)
        return at

    def node_array(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        """Node ids, positions (N, 3) and normals (N, 3) as arrays, in dict order."""
        ids = list(self.nodes)
        xyz = np.array([self.nodes[i].xyz for i in ids], dtype=float).reshape(-1, 3)
        normals = np.array([self.nodes[i].normal for i in ids], dtype=float).reshape(-1, 3)
        return ids, xyz, normals


MAX_NORMAL_TILT_DEG = 10.0  # surface normals along a lamella lie in its normal plane, up to sampling noise
NODE_OFF_CURVE_MM = 1.0     # a lamella's node farther than this from its centreline is an error in the model


def validate(network: Network, source: str = "model") -> Network:
    """Check a network for the mistakes that would silently spoil fabrication; raise naming the element.

    Checks units, finite coordinates, unit normals, unique ids, known families and kinds, curves with
    at least two distinct points that neither double back nor overlap themselves (within 1 mm), node references,
    that every lamella lists nodes, each on its centreline (within 1 mm) and in order along it, and that every
    node lies on a lamella.
    """
    if network.units not in UNIT_TO_MM:
        raise FablineError(f"{source}: unknown units {network.units!r} (use one of {', '.join(UNIT_TO_MM)})")
    if not network.lamellas:
        raise FablineError(f"{source}: the model has no lamellas")
    for nid, node in network.nodes.items():
        where = f"{source}: node {nid}"
        _check_vector(node.xyz, f"{where}: xyz")
        _check_vector(node.normal, f"{where}: normal")
        if np.abs(node.xyz).max() > MAX_MM / network.mm_per_unit:
            raise FablineError(f"{where}: xyz {node.xyz.tolist()} lies more than {MAX_MM / 1e6:g} km from the origin")
        length = math.hypot(*node.normal)  # no overflow (and no numpy warning) for huge components
        if abs(length - 1.0) > 1e-3:
            raise FablineError(f"{where}: normal is not a unit vector (length {length:.4g})")
        if node.kind not in NODE_KINDS:
            raise FablineError(f"{where}: unknown kind {node.kind!r} (use one of {', '.join(NODE_KINDS)})")
    seen: set[str] = set()
    for lam in network.lamellas:
        where = f"{source}: lamella {lam.id}"
        if lam.id in seen:
            raise FablineError(f"{where}: duplicate lamella id")
        seen.add(lam.id)
        if lam.family not in FAMILIES:
            raise FablineError(f"{where}: unknown family {lam.family!r} (use A or B)")
        _check_curve(lam, where, network.mm_per_unit)
        if not lam.nodes:
            raise FablineError(f"{where}: lists no nodes (a lamella is held by the nodes along it)")
        for nid in lam.nodes:
            if nid not in network.nodes:
                raise FablineError(f"{where}: refers to node {nid}, which the model does not define")
        if len(set(lam.nodes)) != len(lam.nodes):
            raise FablineError(f"{where}: passes the same node twice")
        tau = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(lam.curve, axis=0), axis=1))])
        xyz = np.array([network.nodes[nid].xyz for nid in lam.nodes], dtype=float).reshape(-1, 3)
        check_node_stations(lam, *project_onto_curve(lam.curve, tau, xyz), network.mm_per_unit, where)
    for nid, lams in network.lamellas_at().items():
        if not lams:
            raise FablineError(f"{source}: node {nid} lies on no lamella")
    return network


def _check_vector(value: np.ndarray, where: str) -> None:
    if value.shape != (3,):
        raise FablineError(f"{where}: expected 3 numbers, got shape {value.shape}")
    if not np.all(np.isfinite(value)):
        raise FablineError(f"{where}: contains NaN or infinite values")


def _check_no_self_overlap(curve: np.ndarray, lengths: np.ndarray, where: str, tolerance: float) -> None:
    """A curve whose segments come within `tolerance` of each other away from their neighbours (a figure 8, a
    loop that runs over itself) overlaps itself: a strip cannot pass through itself."""
    midpoints = (curve[1:] + curve[:-1]) / 2
    pairs = cKDTree(midpoints).query_pairs(float(lengths.max()) + tolerance, output_type="ndarray")
    if not len(pairs):
        return
    s = np.concatenate([[0.0], np.cumsum(lengths)])
    i, j = pairs.min(axis=1), pairs.max(axis=1)
    apart = s[j] - s[i + 1] > 2 * float(lengths.max())  # not neighbours along the curve
    i, j = i[apart], j[apart]
    close = np.flatnonzero(_segment_distance(curve[i], curve[i + 1], curve[j], curve[j + 1]) < tolerance)
    if close.size:
        k = close[np.argmin(i[close])]
        raise FablineError(f"{where}: curve overlaps itself (segments at points {i[k]} and {j[k]} come within "
                           f"{tolerance:.3g} of each other)")


def _segment_distance(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Shortest distances between segments a0-a1 and b0-b1 (rows of (N, 3) arrays), clamped closest points."""
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    a, b, c = np.einsum("ij,ij->i", u, u), np.einsum("ij,ij->i", u, v), np.einsum("ij,ij->i", v, v)
    d, e = np.einsum("ij,ij->i", u, w), np.einsum("ij,ij->i", v, w)
    denominator = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.where(denominator > 1e-12 * a * c, (b * e - c * d) / denominator, 0.0), 0.0, 1.0)
        t = np.clip((b * s + e) / c, 0.0, 1.0)
        s = np.clip((b * t - d) / a, 0.0, 1.0)
    return np.linalg.norm(w + s[:, None] * u - t[:, None] * v, axis=1)


def project_onto_curve(curve: np.ndarray, tau: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest points of a sampled curve (the polyline through `curve`, parameter `tau` at its samples) to each of
    `points`: their parameters and distances. The nearest sample (KD-tree) decides the neighbourhood; the exact
    foot lies on one of its two segments."""
    p = curve
    nearest = np.clip(cKDTree(p).query(points)[1], 1, len(p) - 2) if len(p) > 2 else np.ones(len(points), int)
    best_tau, best_dist = None, None
    for start in (nearest - 1, np.minimum(nearest, len(p) - 2)):
        a, seg = p[start], p[start + 1] - p[start]
        rel = points - a
        f = np.clip(np.einsum("ij,ij->i", rel, seg) / np.einsum("ij,ij->i", seg, seg), 0.0, 1.0)
        dist = np.linalg.norm(rel - f[:, None] * seg, axis=1)
        at = tau[start] + f * (tau[start + 1] - tau[start])
        if best_tau is None:
            best_tau, best_dist = at, dist
        else:
            closer = dist < best_dist
            best_tau, best_dist = np.where(closer, at, best_tau), np.minimum(dist, best_dist)
    return best_tau, best_dist


def check_node_stations(lamella: Lamella, tau: np.ndarray, off: np.ndarray, mm_per_unit: float, where: str) -> None:
    """A lamella's nodes, projected onto its curve (parameters `tau`, distances `off` in model units), must lie on
    it (within NODE_OFF_CURVE_MM) and in the order the lamella lists them."""
    far = np.flatnonzero(off * mm_per_unit > NODE_OFF_CURVE_MM)
    if far.size:
        k = far[0]
        raise FablineError(f"{where}: node {lamella.nodes[k]} lies {off[k] * mm_per_unit:.2f} mm off its centreline "
                           f"(more than {NODE_OFF_CURVE_MM:g} mm): it is on no lamella there")
    if np.any(np.diff(tau) <= 0):
        k = int(np.flatnonzero(np.diff(tau) <= 0)[0])
        raise FablineError(f"{where}: nodes {lamella.nodes[k]} and {lamella.nodes[k + 1]} are not in order along "
                           "the curve")


def _check_curve(lam: Lamella, where: str, mm_per_unit: float) -> None:
    curve, normals = lam.curve, lam.normals
    if curve.ndim != 2 or curve.shape[1] != 3 or len(curve) < 2:
        raise FablineError(f"{where}: curve needs at least two [x, y, z] points")
    if normals.shape != curve.shape:
        raise FablineError(f"{where}: {len(normals)} normals for {len(curve)} curve points")
    bad = np.flatnonzero(~np.isfinite(curve).all(axis=1))
    if bad.size:
        raise FablineError(f"{where}: curve point {bad[0]} contains NaN or infinite values")
    bad = np.flatnonzero(np.abs(curve).max(axis=1) > MAX_MM / mm_per_unit)
    if bad.size:
        raise FablineError(f"{where}: curve point {bad[0]} lies more than {MAX_MM / 1e6:g} km from the origin")
    bad = np.flatnonzero(~np.isfinite(normals).all(axis=1))
    if bad.size:
        raise FablineError(f"{where}: normal {bad[0]} contains NaN or infinite values")
    lengths = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    if lengths.sum() == 0:
        raise FablineError(f"{where}: curve has zero length")
    zero = np.flatnonzero(lengths == 0)
    if zero.size:
        raise FablineError(f"{where}: curve points {zero[0]} and {zero[0] + 1} coincide")
    steps = np.diff(curve, axis=0) / lengths[:, None]
    reversal = np.flatnonzero(np.einsum("ij,ij->i", steps[1:], steps[:-1]) < -0.5)
    if reversal.size:
        raise FablineError(f"{where}: curve doubles back on itself at point {reversal[0] + 1}")
    _check_no_self_overlap(curve, lengths, where, NODE_OFF_CURVE_MM / mm_per_unit)
    norms = np.hypot(np.hypot(normals[:, 0], normals[:, 1]), normals[:, 2])  # no overflow for huge components
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
    if bad.size:
        raise FablineError(f"{where}: normal {bad[0]} is not a unit vector (length {norms[bad[0]]:.4g})")
    tangents = np.vstack([steps[:1], steps[:-1] + steps[1:], steps[-1:]])
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    tilt = np.degrees(np.arcsin(np.clip(np.abs(np.einsum("ij,ij->i", tangents, normals)), 0.0, 1.0)))
    if tilt.max() > MAX_NORMAL_TILT_DEG:
        k = int(np.argmax(tilt))
        raise FablineError(f"{where}: normal {k} is not perpendicular to the curve ({tilt[k]:.1f} degrees off; the "
                           f"surface normal along a lamella must be, within {MAX_NORMAL_TILT_DEG:g} degrees)")
