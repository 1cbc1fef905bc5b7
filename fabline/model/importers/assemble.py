"""Build a validated network model from curves alone: nodes at the crossings, normals from the surface."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from fabline.errors import FablineError
from fabline.model.importers.crossings import NEAR_MISS_FACTOR, find_crossings
from fabline.model.importers.curves import CurveSource
from fabline.model.importers.nodes import SupportRule, match_points, named_nodes
from fabline.model.importers.surface import SurfaceNormals
from fabline.model.network import UNIT_TO_MM, Lamella, Network, Node, validate


@dataclass
class NearMissReport:
    """Two lamellas that pass close by without crossing within the tolerance."""

    lamella_a: str
    lamella_b: str
    distance_mm: float
    xyz: tuple[float, float, float]


@dataclass
class ImportReport:
    """What an import found and assumed, for the user to check."""

    source: str
    format: str
    units: str
    tolerance_mm: float
    lamellas: int
    nodes: int
    singularities: int = 0
    extent_m: tuple[float, float, float] | None = None
    kinds: dict[str, int] = field(default_factory=dict)
    surface: str | None = None
    max_surface_distance_mm: float | None = None
    near_misses: list[NearMissReport] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def summary(self, max_near_misses: int = 20) -> list[str]:
        """Human-readable lines: counts, units, surface fit, near-misses and notes."""
        lines = [f"{self.source} ({self.format}): {self.lamellas} lamellas, {self.nodes} nodes"
                 f" ({self.singularities} singularities), units {self.units}"]
        if self.extent_m is not None:
            lines.append("extent {:.3f} x {:.3f} x {:.3f} m (x, y, z)".format(*self.extent_m))
        if self.kinds:
            lines.append("node kinds: " + ", ".join(f"{count} {kind}" for kind, count in sorted(self.kinds.items())))
        if self.surface:
            lines.append(f"normals from {self.surface}; curves lie within "
                         f"{self.max_surface_distance_mm:.3g} mm of it")
        if self.format != "json":
            lines.append(f"crossings within {self.tolerance_mm:g} mm; {len(self.near_misses)} near-miss(es) "
                         f"up to {NEAR_MISS_FACTOR * self.tolerance_mm:g} mm")
        for miss in self.near_misses[:max_near_misses]:
            x, y, z = miss.xyz
            lines.append(f"  near-miss: {miss.lamella_a} and {miss.lamella_b} pass {miss.distance_mm:.3f} mm "
                         f"apart at ({x:.6g}, {y:.6g}, {z:.6g})")
        if len(self.near_misses) > max_near_misses:
            lines.append(f"  ... and {len(self.near_misses) - max_near_misses} more near-misses")
        lines.extend(f"note: {note}" for note in self.notes)
        return lines


def build_network(source: CurveSource, units: str, tolerance_mm: float, mesh: trimesh.Trimesh | None,
                  surface_label: str | None, file_format: str,
                  supports: SupportRule | None = None) -> tuple[Network, ImportReport]:
    """The network of a file's curves: crossings of the two families as nodes, ordered along each lamella.

    Nodes the file names (NODES points, as `fabline.model.writers` writes them) give their ids and kinds to the
    crossings they sit on, and a named node at a lamella end that crosses nothing is kept there. Kinds: three
    lamellas make a singularity; else the file's kind; else a lamella's first or last node is an `edge-end`,
    others `grid`; then the nodes `supports` picks are `support`."""
    path = source.path
    curves = source.curves
    for family in ("A", "B"):
        if not any(c.family == family for c in curves):
            raise FablineError(f"{path}: no curves of family {family} (name their layers or groups "
                               f"{family}, {family}-017, FAMILY-{family}, ...)")
    if mesh is None:
        raise FablineError(f"{path}: missing normals: give --surface (a mesh of the reference surface)")
    mm = UNIT_TO_MM[units]
    tolerance = tolerance_mm / mm
    ids = [c.id for c in curves]
    found = find_crossings([c.points for c in curves], [c.family for c in curves], ids, tolerance, path)
    near_misses = [NearMissReport(ids[m.curve_a], ids[m.curve_b], m.distance * mm, tuple(m.xyz.tolist()))
                   for m in found.near_misses]
    if len(found.xyz) == 0:
        closest = (f"; closest approach {near_misses[0].distance_mm:.3g} mm between {near_misses[0].lamella_a} "
                   f"and {near_misses[0].lamella_b}" if near_misses else "")
        raise FablineError(f"{path}: the curves never cross: no lamella of family A comes within "
                           f"{tolerance_mm:g} mm of one of family B{closest}")

    # nodes the file names: each crossing takes the id of the named node on it; a named node on no crossing is
    # kept where it sits at a lamella's end (a lamella end that crosses nothing, as the designs have)
    named = named_nodes(source)
    named_xyz = np.array([n.xyz for n in named], dtype=float).reshape(-1, 3)
    at_crossing = match_points(found.xyz, named_xyz, tolerance)
    ends = np.array([[c.points[0], c.points[-1]] for c in curves]).reshape(-1, 3)
    lengths = [float(np.sum(np.linalg.norm(np.diff(c.points, axis=0), axis=1))) for c in curves]
    unplaced = sorted(set(range(len(named))) - set(at_crossing[at_crossing >= 0].tolist()))
    end_nodes = []  # (named node index, curve index, arc)
    for k in unplaced:
        close = np.flatnonzero(np.linalg.norm(ends - named_xyz[k], axis=1) <= tolerance)
        if not close.size:
            source.notes.append(f"{path}: node {named[k].id} ({named[k].where}) lies on no crossing and at no lamella "
                                f"end within {tolerance_mm:g} mm: left out")
        end_nodes += [(k, int(e) // 2, 0.0 if e % 2 == 0 else lengths[int(e) // 2]) for e in close.tolist()]

    # number the other nodes along the lamellas in file order, so ids read naturally
    first_member = np.array([min(m) for m in found.members])
    order = np.lexsort((first_member[:, 1], first_member[:, 0]))
    width = len(str(len(order)))
    taken = {n.id for n in named}
    node_ids = [""] * len(order)
    rank = 0
    for k in order:
        if at_crossing[k] >= 0:
            node_ids[k] = named[at_crossing[k]].id
            continue
        rank += 1
        while f"N{rank:0{width}d}" in taken:
            rank += 1
        node_ids[k] = f"N{rank:0{width}d}"

    # one closest-point query for every curve sample and node (building the search tree is the costly part)
    end_xyz = np.array([named_xyz[k] for k, _, _ in end_nodes]).reshape(-1, 3)
    all_normals, all_distance = SurfaceNormals(mesh).at(np.concatenate([c.points for c in curves]
                                                                        + [found.xyz, end_xyz]))
    splits = np.cumsum([len(c.points) for c in curves])
    curve_normals = np.split(all_normals[:splits[-1]], splits[:-1])
    node_normals, max_distance = all_normals[splits[-1]:], float(all_distance.max()) * mm
    nodes = {}
    on_curve: list[list[tuple[float, str]]] = [[] for _ in curves]
    for k in order:
        members = found.members[k]
        kind = "singularity" if len(members) == 3 else named[at_crossing[k]].kind if at_crossing[k] >= 0 else None
        if kind == "singularity":
            _refuse_running_together(curves, members, found.xyz[k], path)
        nodes[node_ids[k]] = Node(node_ids[k], found.xyz[k], node_normals[k], kind or "")
        for curve_index, arc in members:
            on_curve[curve_index].append((arc, node_ids[k]))
    for row, (k, curve_index, arc) in enumerate(end_nodes):
        node = named[k]
        nodes.setdefault(node.id, Node(node.id, node.xyz, node_normals[len(found.xyz) + row], node.kind or ""))
        on_curve[curve_index].append((arc, node.id))
    lamellas = []
    for curve, normal, passes in zip(curves, curve_normals, on_curve):
        if not passes:
            raise FablineError(f"{path}: lamella {curve.id} ({curve.where}) crosses no lamella of the other "
                               f"family within {tolerance_mm:g} mm")
        lamellas.append(Lamella(curve.id, curve.family, [nid for _, nid in sorted(passes)], curve.points, normal))
    lamella_ends = {lam.nodes[0] for lam in lamellas} | {lam.nodes[-1] for lam in lamellas}
    for node in nodes.values():
        node.kind = node.kind or ("edge-end" if node.id in lamella_ends else "grid")
    if supports is not None:
        for nid in supports.select(nodes, source, tolerance):
            if nodes[nid].kind != "singularity":
                nodes[nid].kind = "support"
    network = Network(units, nodes, lamellas, Path(path).stem.split(".")[0],
                      {"source": Path(path).name, "tolerance_mm": tolerance_mm})
    validate(network, path)
    kinds: dict[str, int] = {}
    for node in nodes.values():
        kinds[node.kind] = kinds.get(node.kind, 0) + 1
    points = np.concatenate([c.points for c in curves])
    report = ImportReport(path, file_format, units, tolerance_mm, len(lamellas), len(nodes),
                          kinds.get("singularity", 0), tuple((np.ptp(points, axis=0) * mm / 1000.0).tolist()),
                          kinds, surface_label, max_distance, near_misses, list(source.notes))
    if max_distance > tolerance_mm:
        report.notes.append(f"curves lie up to {max_distance:.3g} mm off the surface {surface_label}; "
                            "check that it is the right surface")
    return network, report


def _refuse_running_together(curves: list, members: list[tuple[int, float]], xyz: np.ndarray, path: str) -> None:
    """A singularity's two lamellas of one family must cross; running side by side means a curve drawn twice."""
    same = [(i, arc) for i, arc in members if sum(curves[j].family == curves[i].family for j, _ in members) == 2]
    (first, arc_first), (second, arc_second) = same
    if abs(np.dot(_tangent(curves[first].points, arc_first), _tangent(curves[second].points, arc_second))) > np.cos(
            np.radians(1.0)):
        x, y, z = xyz
        raise FablineError(f"{path}: lamellas {curves[first].id} and {curves[second].id} (both family "
                           f"{curves[first].family}) run together at ({x:.6g}, {y:.6g}, {z:.6g}): a curve drawn twice?")


def _tangent(points: np.ndarray, arc: float) -> np.ndarray:
    """Unit direction of the polyline segment at arc length `arc`."""
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    k = int(np.clip(np.searchsorted(along, arc, side="right") - 1, 0, len(points) - 2))
    step = points[k + 1] - points[k]
    return step / np.linalg.norm(step)

