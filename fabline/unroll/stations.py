"""Where every slot and node mark lies along each strip: the crossings of the lamella pairs' offset curves.

Each lamella of a pair runs d/2 beside the network curve on the surface (side "L" along u = n x t, side
"R" against it) and is unrolled along its own offset curve: its slots sit where it crosses the other
pair's two offset curves, measured along its own arc length, and its node mark midway between them.
All crossings of a network are solved together (one Gauss-Newton run), so the work is vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from fabline.errors import FablineError
from fabline.geometry.darboux import LamellaGeometry, NetworkGeometry
from fabline.geometry.offsets import (Location, OffsetCurve, OffsetCurves, SplineTable, closest_approach,
                                      offset_arc_lengths, strip_crossing_offsets)
from fabline.mechanics.structure import helix_strains
from fabline.unroll.options import UnrollOptions

NEWTON_STEPS = 3  # from the tangent-plane guess (error ~ k d^2 < 1 mm) each step gains a factor ~100
CROSSING_GAP_MM = 1.0  # two strips whose offset curves pass farther apart than this at a node do not cross there
FAMILY_EDGE = {"A": "top", "B": "bottom", "E": "top"}  # E: edge members, no slots, engraved from the bottom
OTHER_EDGE = {"top": "bottom", "bottom": "top"}


@dataclass
class Strip:
    """One strip to cut (before seams): its offset curve and, along its arc length x, its nodes and slots."""

    geometry: LamellaGeometry
    side: str
    curve: OffsetCurve
    node_ids: list[str]
    node_x: np.ndarray
    slot_nodes: list[str] = field(default_factory=list)
    slot_x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    slot_edges: list[str] = field(default_factory=list)
    joint_nodes: set[str] = field(default_factory=set)
    fix_x: np.ndarray = field(default_factory=lambda: np.zeros(0))  # end-fix holes (edges.end_fixes), sorted
    edge_x: np.ndarray = field(default_factory=lambda: np.zeros(0))  # where edge members cross it (edges.end_fixes)

    @property
    def lamella(self) -> str:
        return self.geometry.lamella.id

    @property
    def family(self) -> str:
        return self.geometry.lamella.family

    @cached_property
    def id(self) -> str:
        """The strip's id: the lamella's, with -L or -R for the two strips of a pair."""
        return f"{self.lamella}-{self.side}" if self.side else self.lamella

    @property
    def offset(self) -> float:
        return self.curve.offset


def side_offsets(options: UnrollOptions) -> list[tuple[str, float]]:
    """The strips of one lamella: ("L", +d/2) and ("R", -d/2) for pairs, ("", 0) for single lamellas."""
    half = options.pair_spacing / 2.0
    return [("L", half), ("R", -half)] if half > 0 else [("", 0.0)]


def singular_nodes(geometry: NetworkGeometry) -> set[str]:
    """Nodes where three or more lamellas meet (valence 6 and up): the network's singularities."""
    count: dict[str, int] = {}
    for geo in geometry.lamellas.values():
        for nid in geo.node_ids:
            count[nid] = count.get(nid, 0) + 1
    return {nid for nid, c in count.items() if c >= 3}


def helix_stretch(geo: LamellaGeometry, options: UnrollOptions) -> np.ndarray | float:
    """Length element factor 1 / (1 + eps_H,min) that undoes the twisted centre fibre's contraction (6.8, 6.9)."""
    if not options.compensate_twist:
        return 1.0
    return 1.0 / (1.0 + helix_strains(options.profile, geo.tau_g)[0])


def strip_stations(geometry: NetworkGeometry, options: UnrollOptions) -> list[Strip]:
    """Every strip of the network with its node and slot positions; bad crossings raise naming node and lamellas.

    All lamellas are evaluated together (`SplineTable`): node parameters, crossings and arc lengths each in one
    batch; only the Strip objects and their spacing checks are made one by one.
    """
    geos = list(geometry.lamellas.values())
    sides = side_offsets(options)
    table = SplineTable([geo.fit for geo in geos])
    node_counts = np.array([len(geo.node_ids) for geo in geos])
    node_lamella = np.repeat(np.arange(len(geos)), node_counts)
    node_tau = table.parameter_at(node_lamella, np.concatenate([geo.node_s for geo in geos]))
    curves = OffsetCurves.of([geo for geo in geos for _ in sides], [offset for _ in geos for _, offset in sides],
                             [helix_stretch(geo, options) for geo in geos for _ in sides])
    fit_of_curve = np.repeat(np.arange(len(geos)), len(sides))
    # every node on every strip: curve index = lamella * len(sides) + side, the lamella's nodes in order
    per_curve = np.repeat(node_counts, len(sides))
    curve_of_node = np.repeat(np.arange(len(curves.curves)), per_curve)
    lamella_rows = np.split(np.arange(len(node_tau)), np.cumsum(node_counts)[:-1])
    node_row = np.concatenate([rows for rows in lamella_rows for _ in sides])
    # where each node lies on each of its lamellas' splines: its strips' queries there and the crossing guesses
    # nearby start from it instead of searching the network's table again
    node_location = table.locate(node_lamella, node_tau)
    node_x = offset_arc_lengths(table, curves, fit_of_curve, curve_of_node, node_tau[node_row],
                                node_location.take(node_row))
    singular = singular_nodes(geometry)
    joint_mode = options.singularity == "joint"
    pairs = _crossing_pairs(geos, geometry, singular if joint_mode else set(), options)
    slot_curve, slot_x, slot_node, slot_names, slot_edges = _solve_crossings(
        geos, geometry, table, node_tau, node_location, pairs, sides, options, curves, fit_of_curve)
    # a paired strip's node mark lies midway between the slots it gets at that node
    node_first = np.cumsum(per_curve) - per_curve
    row = node_first[slot_curve] + slot_node
    total = np.bincount(row, weights=slot_x, minlength=len(node_x))
    count = np.bincount(row, minlength=len(node_x))
    paired = np.array([curve.offset != 0.0 for curve in curves.curves])[curve_of_node]
    node_x = np.where(paired & (count > 0), total / np.maximum(count, 1), node_x)
    node_bounds = np.append(node_first, len(node_x)).tolist()
    slot_bounds = np.searchsorted(slot_curve, np.arange(len(curves.curves) + 1)).tolist()
    strips = []
    for c, curve in enumerate(curves.curves):
        geo = geos[c // len(sides)]
        lo, hi = slot_bounds[c], slot_bounds[c + 1]
        strip = Strip(geo, sides[c % len(sides)][0], curve, list(geo.node_ids), node_x[node_bounds[c]:node_bounds[c + 1]],
                      slot_names[lo:hi], slot_x[lo:hi], slot_edges[lo:hi],
                      joint_nodes={n for n in geo.node_ids if n in singular} if joint_mode else set())
        _check_slot_spacing(strip, options)
        strips.append(strip)
    return strips


def _crossing_pairs(geos: list[LamellaGeometry], geometry: NetworkGeometry, skip: set[str],
                    options: UnrollOptions) -> list[tuple[str, int, int, int, int]]:
    """(node, lamella i, its node index, lamella j, its node index) for every two lamellas crossing at a node."""
    at: dict[str, list[tuple[int, int]]] = {}
    for li, geo in enumerate(geos):
        for k, nid in enumerate(geo.node_ids):
            at.setdefault(nid, []).append((li, k))
    pairs = []
    for nid, members in at.items():
        if len(members) < 2 or nid in skip:
            continue
        angle = geometry.crossing_angles.get(nid)
        if angle is not None and angle < options.min_crossing_angle:
            names = " and ".join(geos[li].lamella.id for li, _ in members)
            raise FablineError(f"node {nid}: lamellas {names} cross at {angle:.1f} degrees, under the "
                               f"{options.min_crossing_angle:g} degrees the slotted joint can rotate to")
        for a in range(len(members)):
            for b in range(a + 1, len(members)):
                pairs.append((nid, *members[a], *members[b]))
    return pairs


def _solve_crossings(geos: list[LamellaGeometry], geometry: NetworkGeometry, table: SplineTable, node_tau: np.ndarray,
                     node_location: Location, pairs: list[tuple[str, int, int, int, int]], sides: list[tuple[str, float]], options: UnrollOptions,
                     curves: OffsetCurves, fit_of_curve: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], list[str]]:
    """Solve every strip-strip crossing: per slot its strip (curve index = lamella * len(sides) + side), arc length
    along it, node index within the lamella, node id and edge; sorted by strip, then along it. `node_tau` holds
    every lamella's node parameters in order, `node_location` where they lie in `table`."""
    if not pairs:
        return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0, dtype=int), [], []
    nodes = [p[0] for p in pairs]
    li, ki, lj, kj = (np.array([p[c] for p in pairs], dtype=int) for c in range(1, 5))
    normals = np.array([geometry.network.nodes[n].normal for n in nodes], dtype=float)
    # every lamella's node tangents and parameters in one table, row = first row of the lamella + node index
    first_row = np.cumsum([0] + [len(geo.node_ids) for geo in geos[:-1]])
    tangents, taus = np.concatenate([geo.node_tangents for geo in geos]), node_tau
    row_i, row_j = first_row[li] + ki, first_row[lj] + kj
    t_i, t_j = tangents[row_i], tangents[row_j]
    tau_i0, tau_j0 = taus[row_i], taus[row_j]
    offsets = np.array([o for _, o in sides])
    count = len(sides)
    # every pair crossed with every side combination: index = pair * count^2 + side_i * count + side_j
    rep = count * count
    side_i = np.tile(np.repeat(np.arange(count), count), len(pairs))
    side_j = np.tile(np.tile(np.arange(count), count), len(pairs))
    o_i, o_j = offsets[side_i], offsets[side_j]
    a, b = strip_crossing_offsets(*(np.repeat(v, rep, axis=0) for v in (t_i, t_j, normals)), o_i, o_j)
    reach = options.end + abs(offsets).max() * 2.0
    near = node_location.take(np.concatenate([np.repeat(row_i, rep), np.repeat(row_j, rep)]))
    tau_i, tau_j, gap, location = closest_approach(table, np.repeat(li, rep), np.repeat(tau_i0, rep) + a, o_i,
                                                   np.repeat(lj, rep), np.repeat(tau_j0, rep) + b, o_j,
                                                   iterations=NEWTON_STEPS, reach=reach, near=near)
    bad = np.flatnonzero(gap > CROSSING_GAP_MM)
    if bad.size:
        k = int(bad[np.argmax(gap[bad])])
        p = pairs[k // rep]
        raise FablineError(f"node {p[0]}: the strips of lamellas {geos[p[1]].lamella.id} and {geos[p[3]].lamella.id} "
                           f"pass {gap[k]:.2f} mm apart instead of crossing (over {CROSSING_GAP_MM:g} mm)")
    fam_i = [geos[p[1]].lamella.family for p in pairs]
    fam_j = [geos[p[3]].lamella.family for p in pairs]
    edge_i = [FAMILY_EDGE[f] for f in fam_i]
    edge_j = [FAMILY_EDGE[g] if g != f else OTHER_EDGE[FAMILY_EDGE[g]] for f, g in zip(fam_i, fam_j)]
    pair_of = np.arange(len(tau_i)) // rep
    lam = np.concatenate([np.repeat(li, rep), np.repeat(lj, rep)])
    key = lam * count + np.concatenate([side_i, side_j])
    x = offset_arc_lengths(table, curves, fit_of_curve, key, np.concatenate([tau_i, tau_j]), location)
    node_index = np.concatenate([np.repeat(ki, rep), np.repeat(kj, rep)])
    # object arrays hand back the same str objects in tolist (numpy strings would each become a new one)
    edges = np.concatenate([np.array(edge_i, dtype=object)[pair_of], np.array(edge_j, dtype=object)[pair_of]])
    node_names = np.array(nodes, dtype=object)[np.tile(pair_of, 2)]
    order = np.lexsort((x, key))
    return key[order], x[order], node_index[order], node_names[order].tolist(), edges[order].tolist()


def _check_slot_spacing(strip: Strip, options: UnrollOptions) -> None:
    """Nodes must follow each other along the strip, and two neighbouring slots need a slot width plus a web."""
    backwards = np.flatnonzero(np.diff(strip.node_x) <= 0)
    if backwards.size:
        k = int(backwards[0])
        raise FablineError(f"lamella {strip.lamella}, strip {strip.id}: nodes {strip.node_ids[k]} and "
                           f"{strip.node_ids[k + 1]} come out of order along the strip "
                           f"({strip.node_x[k]:.2f} and {strip.node_x[k + 1]:.2f} mm): they are too close for the pair")
    if len(strip.slot_x) < 2:
        return
    need = options.slot + options.web
    gaps = np.diff(strip.slot_x)
    close = np.flatnonzero(gaps < need)
    if close.size:
        k = int(close[np.argmin(gaps[close])])
        a, b = strip.slot_nodes[k], strip.slot_nodes[k + 1]
        where = f"node {a}" if a == b else f"nodes {a} and {b}"
        raise FablineError(f"lamella {strip.lamella}, strip {strip.id}: slots at {where} are {gaps[k]:.2f} mm apart; "
                           f"a slot pair needs at least {need:.2f} mm (slot {options.slot:g} + web {options.web:g} mm)")
