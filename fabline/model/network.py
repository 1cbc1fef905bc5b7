"""The network model: nodes where lamellas cross, lamellas as ordered node chains with dense centrelines.

A model declares its units; every coordinate in it is in those units. `Network.in_mm()` gives the
millimetre copy that fabrication stages work in.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from fabline.errors import FablineError

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


def validate(network: Network, source: str = "model") -> Network:
    """Check a network for the mistakes that would silently spoil fabrication; raise naming the element.

    Checks units, finite coordinates, unit normals, unique ids, known families and kinds, curves with
    at least two distinct points that neither double back nor overlap themselves, node references, and that every node lies on a
    lamella (a crossing on two of different families unless it is an edge end or support).
    """
    if network.units not in UNIT_TO_MM:
        raise FablineError(f"{source}: unknown units {network.units!r} (use one of {', '.join(UNIT_TO_MM)})")
    if not network.lamellas:
        raise FablineError(f"{source}: the model has no lamellas")
    for nid, node in network.nodes.items():
        where = f"{source}: node {nid}"
        _check_vector(node.xyz, f"{where}: xyz")
        _check_vector(node.normal, f"{where}: normal")
        if abs(np.linalg.norm(node.normal) - 1.0) > 1e-3:
            raise FablineError(f"{where}: normal is not a unit vector (length {np.linalg.norm(node.normal):.4g})")
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
        _check_curve(lam, where)
        for nid in lam.nodes:
            if nid not in network.nodes:
                raise FablineError(f"{where}: refers to node {nid}, which the model does not define")
        if len(set(lam.nodes)) != len(lam.nodes):
            raise FablineError(f"{where}: passes the same node twice")
    for nid, lams in network.lamellas_at().items():
        if not lams:
            raise FablineError(f"{source}: node {nid} lies on no lamella")
    return network


def _check_vector(value: np.ndarray, where: str) -> None:
    if value.shape != (3,):
        raise FablineError(f"{where}: expected 3 numbers, got shape {value.shape}")
    if not np.all(np.isfinite(value)):
        raise FablineError(f"{where}: contains NaN or infinite values")


def _check_no_self_overlap(curve: np.ndarray, lengths: np.ndarray, where: str) -> None:
    """A curve that comes back within half a sample step of itself, away from its neighbours, overlaps itself."""
    radius = 0.5 * float(np.min(lengths))
    pairs = cKDTree(curve).query_pairs(radius, output_type="ndarray")
    if len(pairs):
        s = np.concatenate([[0.0], np.cumsum(lengths)])
        apart = np.abs(s[pairs[:, 0]] - s[pairs[:, 1]]) > 4 * radius
        if np.any(apart):
            i, j = sorted(pairs[np.argmax(apart)])
            raise FablineError(f"{where}: curve overlaps itself (points {i} and {j} coincide within {radius:.3g})")


def _check_curve(lam: Lamella, where: str) -> None:
    curve, normals = lam.curve, lam.normals
    if curve.ndim != 2 or curve.shape[1] != 3 or len(curve) < 2:
        raise FablineError(f"{where}: curve needs at least two [x, y, z] points")
    if normals.shape != curve.shape:
        raise FablineError(f"{where}: {len(normals)} normals for {len(curve)} curve points")
    bad = np.flatnonzero(~np.isfinite(curve).all(axis=1))
    if bad.size:
        raise FablineError(f"{where}: curve point {bad[0]} contains NaN or infinite values")
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
    _check_no_self_overlap(curve, lengths, where)
    norms = np.linalg.norm(normals, axis=1)
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
