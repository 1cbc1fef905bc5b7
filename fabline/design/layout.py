"""Lay out an asymptotic network at a requested spacing and turn the traced curves into a `Network`.

The rail strategy: the family A curve through the seed point is the rail; family B curves start on it
at equal arc-length spacing from the seed; then family A curves start at equal spacing along the middle
B curve (the one through the seed). On a surface whose asymptotic lines are coordinate lines (Enneper:
u, v) this reproduces the closed-form network with nodes at equal arc length along the two axes. The
crossings (found as the importer finds them) become nodes with the surface normal; lamella ends at the
edge become `edge-end` nodes, nodes matching the supports rule `support`.
"""

from __future__ import annotations

import operator
import re
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from fabline.design.field import asymptotic_directions
from fabline.design.mesh import SmoothMesh, xyz_text
from fabline.design.nurbs import NurbsPatch
from fabline.design.trace import STOP_REASONS, StopRule, TracedCurve, trace_family
from fabline.errors import FablineError
from fabline.geometry.offsets import strip_crossing_offsets
from fabline.model.importers.crossings import Crossings, find_crossings
from fabline.model.network import UNIT_TO_MM, Lamella, Network, Node, validate

TracingSurface = SmoothMesh | NurbsPatch

CROSSING_TOLERANCE_MM = 1.0  # traced curves of the two families that pass this close cross
SAMPLES_PER_STEP = 4  # output samples per tracing step (cubic spline through the traced points, projected)
SURE_ENDS = ("edge", "closed", "length")  # curve ends past which the surface goes on as the curve's spline does
SLOT_MARGIN_MM = 2.0  # the tangent-plane estimate of a slot is off by about k d^2: 2 mm where the surface bends at 3/m
RUN_ON_PAIRS = 2.0
"""Past an end crossing a curve runs on this many pair spacings: to where the strips of the pairs crossing there
lie, (d/2)(1/sin + |cot|) of the angle, 1.87 d at the joint's 30 degrees."""
END_MERGE_FRACTION = 0.1  # a crossing this fraction of the spacing from a lamella's end becomes that end
MAX_EXTENSIONS = 200  # passes of `_extend` at most (each continues one family along one curve)
REPORTED_STOPS = ("K>=0", "merging", "flat", "bend", "twist", "rough")
"""Curve ends worth telling the designer (the edge, a closed curve and the other family's curve nearby are not)."""
REMEDIES = {
    "K>=0": "move --seed into the anticlastic part (K < 0) or cut the synclastic region away",
    "merging": "move --seed away from where the surface turns synclastic, or cut that region away",
    "flat": "move --seed away from the flat region, or cut it away (a flat point needs a singular joint)",
    "bend": "give the --profile and --material of the strip (a thinner strip bends tighter) or smooth the surface there",
    "twist": "give the --profile and --material of the strip (a thinner strip twists more) or flatten the surface there",
    "rough": "smooth or remesh the surface there, or give a larger --step",
}
"""What a designer can change where curves stop for each reason."""


@dataclass
class SupportRule:
    """Nodes whose coordinate `axis` compares with `value` by `op` (e.g. z < 0.05) are supports."""

    axis: int
    op: str
    value: float

    OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}

    @classmethod
    def parse(cls, text: str) -> "SupportRule":
        match = re.fullmatch(r"\s*([xyzXYZ])\s*(<=|>=|<|>)\s*([-+0-9.eE]+)\s*", text)
        if not match:
            raise FablineError(f"--supports {text!r}: write it as AXIS OP VALUE, e.g. z<0.05 (axis x, y or z; op <, <=, >, >=)")
        try:
            value = float(match.group(3))
        except ValueError:
            raise FablineError(f"--supports {text!r}: {match.group(3)!r} is not a number") from None
        return cls("xyz".index(match.group(1).lower()), match.group(2), value)

    def holds(self, xyz: np.ndarray) -> bool:
        return bool(self.OPS[self.op](xyz[self.axis], self.value))

    def __str__(self) -> str:
        return f"{'xyz'[self.axis]}{self.op}{self.value:g}"


@dataclass
class Layout:
    """The traced curves of both families, their indices along the rail or middle curve, and stops not at the edge."""

    curves: list[np.ndarray]
    families: list[str]
    indices: list[int]
    rule: StopRule = field(default_factory=StopRule)
    stop_records: list[dict] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    dropped: int = 0
    end_reasons: list[list[str]] = field(default_factory=list)  # why each curve ends, at its start and its end
    trimmed: int = 0  # curve ends cut back before a crossing no pair of strips could be slotted at (`_clear_corners`)
    closed_runs: set[tuple[int, int]] = field(default_factory=set)

    def add(self, family: str, index: int, curve: TracedCurve, step: float) -> None:
        self.curves.append(_dense(curve, step)[0])
        self.end_reasons.append(list(curve.stops))
        self.families.append(family)
        self.indices.append(index)
        self.stop_records += [{"curve": f"{family} {index}", "reason": why, "xyz": curve.points[end].round(9).tolist()}
                              for end, why in zip((0, -1), curve.stops) if why in REPORTED_STOPS]


def rail_layout(surface: TracingSurface, seed: np.ndarray, spacing: float, step: float, tolerance: float, source: str,
                seed_curves: tuple[np.ndarray, ...] = (), rule: StopRule = StopRule(), units: str = "") -> Layout:
    """Rail through the seed, the other family's curves at equal spacing along it, then the first family at equal
    spacing along the middle one of those (the one through the seed).

    `seed_curves` replace the traced rail (first) and the middle curve (second): curves of any shape on the
    surface, along which the family more transverse to the first starts, then the other one.
    """
    reach = 4.0 * float(np.linalg.norm(np.ptp(surface.vertices, axis=0)))
    rail = None
    if seed_curves:
        rail_points, rail_seed = _given(surface, seed_curves[0], seed, step, f"{source}: seed curve 1")
        across = _transverse_family(surface, rail_points)
    else:
        rail = trace_family(surface, seed[None], "A", step, reach, rule)[0]
        rail_points, rail_seed = _dense(rail, step)
        across = "B"
    along = "A" if across == "B" else "B"
    starts, index_across = _spaced(rail_points, rail_seed, spacing, along, source, _ends(rail, units))
    curves_across = trace_family(surface, starts, across, step, reach, rule)
    if len(seed_curves) > 1:
        middle_points, middle_seed = _given(surface, seed_curves[1], seed, step, f"{source}: seed curve 2")
    else:
        middle = curves_across[index_across.tolist().index(0)]
        middle_points, middle_seed = _dense(middle, step)
    starts, index_along = _spaced(middle_points, middle_seed, spacing, across, source,
                                  "" if len(seed_curves) > 1 else _ends(middle, units))
    reuse = index_along == 0 if rail is not None else np.zeros(len(index_along), dtype=bool)
    traced_along = dict(zip(index_along[~reuse].tolist(), trace_family(surface, starts[~reuse], along, step, reach, rule)))
    if reuse.any():
        traced_along[0] = rail
    layout = Layout([], [], [], rule)
    for family, traced in ((along, sorted(traced_along.items())), (across, list(zip(index_across.tolist(), curves_across)))):
        for index, curve in traced:
            layout.add(family, index, curve, step)
    _extend(surface, layout, spacing, step, reach, tolerance, source)
    return layout


def _extend(surface: TracingSurface, layout: Layout, spacing: float, step: float, reach: float, tolerance: float,
            source: str) -> None:
    """And so on: where a curve runs on past the last crossing curve of the other family by more than a spacing,
    that family continues along it at the same spacing; repeated (longest open run first) until none is left.

    Covers what the two curves through the seed do not reach (a boundary that is not convex in the
    asymptotic directions, a surface that closes around).
    """
    for _ in range(MAX_EXTENSIONS):
        ids = [f"{f}{i}" for f, i in zip(layout.families, layout.indices)]
        crossings = find_crossings(layout.curves, layout.families, ids, tolerance, source)
        on_curve: list[list[tuple[float, int]]] = [[] for _ in layout.curves]
        for members in crossings.members:
            for c, arc in members:
                on_curve[c] += [(arc, layout.indices[o]) for o, _ in members if o != c]
        best = None
        for c, found in enumerate(on_curve):
            if not found:
                continue
            found.sort()
            family = "B" if layout.families[c] == "A" else "A"
            taken = {i for f, i in zip(layout.families, layout.indices) if f == family}
            trend = _trend(found)
            length = float(np.linalg.norm(np.diff(layout.curves[c], axis=0), axis=1).sum())
            for side, (arc, index), open_run in ((-1, found[0], found[0][0]), (1, found[-1], length - found[-1][0])):
                beyond = index + side * trend
                if (c, side) in layout.closed_runs or beyond in taken:
                    continue  # the family's next curve exists: a wide cell, not an uncovered region
                if open_run > 1.5 * spacing and (best is None or open_run > best[0]):
                    best = (open_run, c, side, arc, index, trend)
        if best is None:
            return
        open_run, host, side, arc, index, trend = best
        family = "B" if layout.families[host] == "A" else "A"
        steps = np.arange(1, int(open_run / spacing - 0.5) + 1)
        points = layout.curves[host]
        s = _arc_lengths(points)
        starts = np.stack([np.interp(arc + side * steps * spacing, s, points[:, i]) for i in range(3)], axis=1)
        taken = {i for f, i in zip(layout.families, layout.indices) if f == family}
        kin = cKDTree(np.vstack([c for c, f in zip(layout.curves, layout.families) if f == family]))
        added = False
        for start_index, curve in zip(index + side * trend * steps, trace_family(surface, starts, family, step, reach, layout.rule)):
            piece = _apart(curve, kin, 0.5 * spacing)
            if piece is None:
                continue
            number = int(start_index) if start_index not in taken else max(taken) + 1
            taken.add(number)
            layout.add(family, number, piece, step)
            added = True
        if not added:
            layout.closed_runs.add((host, side))


def _trend(found: list[tuple[float, int]]) -> int:
    """+1 or -1: whether the other family's indices grow along a curve, from its crossings (+1 if undecided)."""
    step = found[-1][1] - found[0][1] if len(found) > 1 else 0
    return -1 if step < 0 else 1


def _apart(curve: TracedCurve, kin: cKDTree, clearance: float) -> TracedCurve | None:
    """The piece of a new curve around its start that keeps `clearance` from the curves of its family already there."""
    clear = kin.query(curve.points)[0] > clearance
    start = curve.seed_index
    if not clear[start]:
        return None
    lo, hi = start, start
    while lo > 0 and clear[lo - 1]:
        lo -= 1
    while hi < len(clear) - 1 and clear[hi + 1]:
        hi += 1
    if hi - lo < 2:
        return None
    stops = (curve.stops[0] if lo == 0 else "near", curve.stops[1] if hi == len(clear) - 1 else "near")
    return TracedCurve(curve.points[lo:hi + 1], stops, start - lo)


def _given(surface: TracingSurface, points: np.ndarray, seed: np.ndarray, step: float, where: str) -> tuple[np.ndarray, int]:
    """A designer's seed curve on the surface, resampled like a traced one, and its point nearest the seed."""
    check_on_surface(surface, points, where)
    on = surface.project(points).xyz
    nearest = int(np.argmin(np.linalg.norm(on - seed, axis=1)))
    return _dense(TracedCurve(on, ("given", "given"), nearest), step)


def check_on_surface(surface: TracingSurface, points: np.ndarray, where: str) -> None:
    """Refuse a seed curve with a point farther from the surface than two mesh edges, naming the point."""
    _, _, squared = surface.closest(points)
    far = np.flatnonzero(np.sqrt(squared) > 2.0 * surface.edge_length)
    if far.size:
        raise FablineError(f"{where}: point {far[0]} ({xyz_text(points[far[0]])}) lies {np.sqrt(squared[far[0]]):.4g} off "
                           "the surface; a seed curve must lie on it")


def _transverse_family(surface: TracingSurface, points: np.ndarray) -> str:
    """The asymptotic family that crosses a curve more squarely on average: the one to start along it."""
    tangents = np.gradient(points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    lifted = surface.at(points)
    a, b, _ = asymptotic_directions(lifted.normal, lifted.shape)
    along_a = np.nanmean(np.abs(np.einsum("ij,ij->i", tangents, a)))
    along_b = np.nanmean(np.abs(np.einsum("ij,ij->i", tangents, b)))
    return "B" if along_a >= along_b else "A"


def _dense(curve: TracedCurve, step: float) -> tuple[np.ndarray, int]:
    """The traced polyline resampled on a cubic spline (SAMPLES_PER_STEP per step); the seed's index.

    The spline through the projected tracing points stays on the surface within micrometres and is
    smoother than projecting every sample again would be (the blended surface is only C1 across edges).
    """
    points = curve.points
    chord = _arc_lengths(points)
    keep = np.r_[True, np.diff(chord) > 1e-9 * step]
    points, chord = points[keep], chord[keep]
    seed_chord = chord[min(curve.seed_index, len(chord) - 1)]
    if len(points) < 2:
        return points, 0
    before = np.linspace(0.0, seed_chord, max(1, int(np.ceil(seed_chord * SAMPLES_PER_STEP / step))) + 1)
    after = np.linspace(seed_chord, chord[-1], max(1, int(np.ceil((chord[-1] - seed_chord) * SAMPLES_PER_STEP / step))) + 1)
    t = np.unique(np.r_[before, after])
    if len(points) > 2:
        dense = CubicSpline(chord, points)(t)
    else:
        dense = points[0] + np.outer(t / chord[-1], points[-1] - points[0])
    return dense, int(np.searchsorted(t, seed_chord))


def _ends(curve: TracedCurve | None, units: str) -> str:
    """Where and why a traced curve's ends stopped, for a refusal ("" for a designer's curve)."""
    if curve is None:
        return ""
    ends = [f"{STOP_REASONS[why]} near ({xyz_text(curve.points[end])}) {units}" for end, why in zip((0, -1), curve.stops)]
    remedy = next((REMEDIES[why] for why in curve.stops if why in REMEDIES), "lower --spacing")
    return f": it {' and '.join(ends)}; {remedy}"


def _spaced(points: np.ndarray, seed: int, spacing: float, family: str, source: str, ends: str = ""
            ) -> tuple[np.ndarray, np.ndarray]:
    """Points at arc lengths k * spacing from the seed along a dense polyline, and their signed indices k."""
    s = _arc_lengths(points)
    s -= s[seed]
    ks = np.arange(int(np.ceil(s[0] / spacing - 1e-9)), int(np.floor(s[-1] / spacing + 1e-9)) + 1)
    ks = ks[(ks * spacing > s[0] + 1e-9 * spacing) & (ks * spacing < s[-1] - 1e-9 * spacing) | (ks == 0)]
    if len(ks) < 2:
        raise FablineError(f"{source}: spacing {spacing:g} is longer than the family {family} curve through the seed, "
                           f"{s[-1] - s[0]:.3g} long" + (ends or " (lower --spacing)"))
    starts = np.stack([np.interp(ks * spacing, s, points[:, i]) for i in range(3)], axis=1)
    return starts, ks


def build_network(surface: TracingSurface, layout: Layout, spacing: float, units: str, supports: SupportRule | None,
                  name: str, meta: dict, source: str, pair_spacing: float, slot_pair: float) -> Network:
    """Nodes at the crossings of the traced curves, lamellas through them to the edge, validated; every crossing a
    pair of strips `pair_spacing` mm apart can be slotted at (`_clear_corners`, `slot_pair` mm between two nodes'
    slots on a strip).

    A curve that carries fewer than two crossings (with curves that carry two) holds nothing and is dropped, as is
    one the network check would refuse (each is checked alone, so one bad curve never rejects the design);
    `layout.dropped` counts them. Where nothing is left: refused, saying where the curves stopped and why.
    """
    first = {f: min(i for g, i in zip(layout.families, layout.indices) if g == f) for f in set(layout.families)}
    number = [i - first[f] for f, i in zip(layout.families, layout.indices)]
    ids = [f"{f}-{n:03d}" for f, n in zip(layout.families, number)]
    tolerance, pair = CROSSING_TOLERANCE_MM / UNIT_TO_MM[units], pair_spacing / UNIT_TO_MM[units]
    crossings = _clear_corners(surface, layout, ids, tolerance, pair, (slot_pair + SLOT_MARGIN_MM) / UNIT_TO_MM[units],
                               source)
    normals = surface.project(crossings.xyz).normal if len(crossings.xyz) else np.empty((0, 3))
    names = []
    for k, members in enumerate(crossings.members):
        by_family = {layout.families[c]: number[c] for c, _ in members}
        nid = f"N{by_family['B']:03d}-{by_family['A']:03d}"
        names.append(nid if nid not in names else f"{nid}-{k}")
    alive = np.ones(len(layout.curves), dtype=bool)
    while True:
        held = _held(crossings.members, alive)
        nodes: dict[str, Node] = {}
        per_curve: list[list[tuple[float, str]]] = [[] for _ in layout.curves]
        for k, members in enumerate(crossings.members):
            if held[k] < 2:
                continue
            nodes[names[k]] = Node(names[k], crossings.xyz[k], normals[k], "grid" if held[k] == 2 else "singularity")
            for c, arc in members:
                if alive[c]:
                    per_curve[c].append((arc, names[k]))
        enough = np.array([len(found) >= 2 for found in per_curve], dtype=bool)
        if (alive & ~enough).any():
            alive &= enough
            continue  # a curve fell below two crossings: its crossings go, so others may follow
        lamellas, refused = [], False
        for c in np.flatnonzero(alive):
            lamella = _lamella(surface, ids[c], layout.families[c], layout.curves[c], sorted(per_curve[c]), nodes, spacing,
                               pair)
            try:
                validate(Network(units, {nid: nodes[nid] for nid in lamella.nodes}, [lamella]), source)
            except FablineError as exc:
                layout.rejected.append(f"{layout.families[c]} curve {layout.indices[c]} near "
                                       f"({xyz_text(lamella.curve[len(lamella.curve) // 2])}) {units}: "
                                       f"{str(exc).split(': ', 2)[-1]}")
                alive[c], refused = False, True
                continue
            lamellas.append(lamella)
        if not refused:
            break
    layout.dropped = int(len(layout.curves) - alive.sum())
    if not {lam.family for lam in lamellas} >= {"A", "B"}:
        raise FablineError(f"{source}: no network of two asymptotic families at spacing {spacing:g} {units}: "
                           + no_network_reason(layout, units))
    used = {nid for lam in lamellas for nid in lam.nodes}
    nodes = {nid: node for nid, node in sorted(nodes.items()) if nid in used}
    if supports is not None:
        chosen = [node for node in nodes.values() if supports.holds(node.xyz)]
        if not chosen:  # as `import --supports` refuses a rule that picks no node
            raise FablineError(f"--supports {str(supports)!r}: no node of {source} lies where {supports} holds")
        for node in chosen:
            node.kind = "support"
    return validate(Network(units, nodes, sorted(lamellas, key=lambda lam: (lam.family, lam.id.split("-", 1)[1])), name, meta), source)


def _clear_corners(surface: TracingSurface, layout: Layout, ids: list[str], tolerance: float, pair: float,
                   slot_pair: float, source: str) -> Crossings:
    """The crossings once every one has its curves run on past it to where the strips of a pair (`pair` apart)
    cross there, unless the curve ends at the surface's edge: past where the tracer stopped those strips would
    meet only on an extrapolation of the curve, off the surface (unroll refuses it: they pass apart). A curve that
    stops short is cut back to before that crossing, keeping a run-on past its crossing before (RUN_ON_PAIRS,
    at most half-way). So is one of two curves whose
    crossings with a third leave its strips less than `slot_pair` (a slot and a web) between their slots, or the
    node marks out of order. Repeated until none is left, counted in `layout.trimmed`."""
    for _ in range(len(layout.curves) * 4 + 1):
        crossings = find_crossings(layout.curves, layout.families, ids, tolerance, source)
        twos = [k for k, members in enumerate(crossings.members) if len(members) == 2]
        if not twos:
            return crossings
        pairs = [crossings.members[k] for k in twos]
        ci, si = zip(*[members[0] for members in pairs])
        cj, sj = zip(*[members[1] for members in pairs])
        arcs = [_arc_lengths(curve) for curve in layout.curves]
        normals = surface.project(crossings.xyz[twos]).normal
        t_i, t_j = (np.array([_tangent(layout.curves[c], arcs[c], s) for c, s in zip(cs, ss)]) for cs, ss in
                    ((ci, si), (cj, sj)))
        fault = np.zeros((2, len(pairs)), dtype=bool)  # members i and j: a strip crossing lies past an unsure end
        for o_i, o_j in ((pair / 2, pair / 2), (pair / 2, -pair / 2), (-pair / 2, pair / 2), (-pair / 2, -pair / 2)):
            a, b = strip_crossing_offsets(t_i, t_j, normals, np.full(len(pairs), o_i), np.full(len(pairs), o_j))
            fault[0] |= _past_unsure_end(layout, arcs, ci, np.add(si, a))
            fault[1] |= _past_unsure_end(layout, arcs, cj, np.add(sj, b))
        faults = [[member for member, bad in zip(pairs[k], fault[:, k]) if bad] for k in range(len(pairs))]
        for m in _crowded_slots(ci, si, cj, sj, t_i, t_j, normals, pair, slot_pair):
            faults[m] = faults[m] or list(pairs[m])  # a neighbour's crossing too close: the one that ends sooner goes
        if not any(faults):
            return crossings
        cut_now: set[int] = set()
        for k in (k for k, fault in enumerate(faults) if fault):
            _, c, s = min((min(s, arcs[c][-1] - s), c, s) for c, s in faults[k])
            if cut_now & {d for d, _ in pairs[k]}:
                continue  # a curve of this crossing changed in this pass: seen again in the next
            cut_now.add(c)
            at_end = s > arcs[c][-1] / 2
            others = [arc for members in crossings.members for d, arc in members if d == c and (arc < s) == at_end
                      and arc != s]
            layout.end_reasons[c][int(at_end)] = "cut"
            if not others:
                layout.curves[c] = _cut(layout.curves[c], arcs[c], None, at_end)
            else:
                before = max(others) if at_end else min(others)
                run_on = min(RUN_ON_PAIRS * pair, abs(s - before) / 2.0)
                layout.curves[c] = _cut(layout.curves[c], arcs[c], before + (run_on if at_end else -run_on), at_end)
            layout.trimmed += 1
    raise FablineError(f"{source}: the traced curves keep stopping at their crossings; lower the spacing")


def _crowded_slots(ci, si, cj, sj, t_i, t_j, normals, pair, slot_pair) -> set[int]:
    """The crossings that follow another along a curve so closely that their slots on one of its strips come less
    than `slot_pair` apart (or the node marks, midway between their slots, come out of order)."""
    count = len(ci)
    curve, arc = np.r_[ci, cj], np.r_[si, sj]  # per member of each crossing: i's rows, then j's
    crossing = np.r_[np.arange(count), np.arange(count)]
    own, partner, normal = np.vstack([t_i, t_j]), np.vstack([t_j, t_i]), np.vstack([normals, normals])
    order = np.lexsort((arc, curve))
    same = curve[order][1:] == curve[order][:-1]
    found: set[int] = set()
    for side in (pair / 2, -pair / 2):
        slots = arc[:, None] + np.stack([strip_crossing_offsets(own, partner, normal, np.full(2 * count, side),
                                                                np.full(2 * count, o))[0] for o in (pair / 2, -pair / 2)],
                                        axis=1)
        first, second = slots[order][:-1], slots[order][1:]
        tight = (second.min(axis=1) - first.max(axis=1) < slot_pair) | (second.mean(axis=1) <= first.mean(axis=1))
        found.update(crossing[order[1:][same & tight]].tolist())
    return found


def _arc_lengths(points: np.ndarray) -> np.ndarray:
    """The arc length of a polyline at each of its points, from 0."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def _tangent(points: np.ndarray, arcs: np.ndarray, s: float) -> np.ndarray:
    """The unit tangent of a polyline at arc length `s` (of the segment there)."""
    k = int(np.clip(np.searchsorted(arcs, s) - 1, 0, len(points) - 2))
    step = points[k + 1] - points[k]
    return step / np.linalg.norm(step)


def _past_unsure_end(layout: Layout, arcs: list[np.ndarray], curves: tuple[int, ...], s: np.ndarray) -> np.ndarray:
    """Whether arc length s[k] lies off curve curves[k] past an end that is not the surface's: the tracer stopped
    there, and the surface does not go on as the curve's spline would (past the edge it does, near enough)."""
    side = [0 if x < 0.0 else 1 if x > arcs[c][-1] else None for c, x in zip(curves, s)]
    return np.array([end is not None and layout.end_reasons[c][end] not in SURE_ENDS for c, end in zip(curves, side)],
                    dtype=bool)


def _cut(points: np.ndarray, arcs: np.ndarray, at: float | None, keep_start: bool) -> np.ndarray:
    """The polyline up to (`keep_start`) or from arc length `at`; two points at the near end if there is no `at`."""
    if at is None:
        return points[:2] if keep_start else points[-2:]
    end = np.array([np.interp(at, arcs, points[:, i]) for i in range(3)])
    return np.vstack([points[arcs < at], end]) if keep_start else np.vstack([end, points[arcs > at]])


def _held(members: list[list[tuple[int, float]]], alive: np.ndarray) -> np.ndarray:
    """How many live curves pass each crossing."""
    return np.array([sum(bool(alive[c]) for c, _ in found) for found in members], dtype=int)


def no_network_reason(layout: Layout, units: str) -> str:
    """Why no network came out, for the refusal: where the traced curves stopped and why, and what to change."""
    if layout.stop_records:
        reasons = [r["reason"] for r in layout.stop_records]
        common = max(set(reasons), key=reasons.count)
        where = next(r for r in layout.stop_records if r["reason"] == common)
        return (f"the curves stop within two crossings, most where they {STOP_REASONS[common]} (e.g. near "
                f"({xyz_text(np.array(where['xyz']))}) {units}); {REMEDIES[common]}")
    return "the traced curves do not cross twice; lower the spacing or move the seed into the anticlastic part"


def _lamella(surface: TracingSurface, lamella_id: str, family: str, points: np.ndarray, crossings: list[tuple[float, str]],
             nodes: dict[str, Node], spacing: float, pair: float) -> Lamella:
    """A lamella through its crossing nodes to both ends of its curve (or cut at a crossing next to an end).

    The centreline is the spline of the traced curve resampled between its ends; the crossing nodes lie on
    it within micrometres and are not inserted as samples, which would kink the spline the geometry fits.
    """
    s = _arc_lengths(points)
    arcs = [arc for arc, _ in crossings]
    names = [nid for _, nid in crossings]
    merge = max(END_MERGE_FRACTION * spacing, pair)  # nearer, a pair's node mark (o cot(angle) off) passes the end
    ends = []
    for side, (arc_end, nearest) in enumerate(((0.0, arcs[0]), (s[-1], arcs[-1]))):
        if abs(arc_end - nearest) <= merge and len(arcs) > 1:
            ends.append(None)
            continue
        nid = f"E{lamella_id}-{'se'[side]}"
        end = points[0 if side == 0 else -1]
        nodes[nid] = Node(nid, end.copy(), surface.at(end[None]).normal[0], "edge-end")
        ends.append((arc_end, nid))
    # past an end node the curve runs on as traced (RUN_ON_PAIRS): unroll finds the strips of the pairs crossing
    # there on the curve, not on an extrapolation of it
    lo = max(0.0, arcs[0] - RUN_ON_PAIRS * pair) if ends[0] is None else 0.0
    hi = min(s[-1], arcs[-1] + RUN_ON_PAIRS * pair) if ends[1] is None else s[-1]
    if ends[0] is None:
        nodes[names[0]].kind = "edge-end"
    if ends[1] is None:
        nodes[names[-1]].kind = "edge-end"
    stations = [e for e in ends[:1] if e] + list(zip(arcs, names)) + [e for e in ends[1:] if e]
    gap = 0.5 * (s[1] - s[0])
    inner = s[(s > lo + gap) & (s < hi - gap)]
    curve = CubicSpline(s, points)(np.r_[lo, inner, hi])
    return Lamella(lamella_id, family, [nid for _, nid in stations], curve, surface.at(curve).normal)


def default_seed(surface: TracingSurface) -> np.ndarray:
    """The surface point closest to the mesh's area-weighted centroid."""
    return surface.project(surface.mesh.center_mass[None] if surface.mesh.is_watertight else
                           np.average(surface.mesh.triangles_center, axis=0, weights=surface.mesh.area_faces)[None]).xyz[0]


def check_seed(surface: TracingSurface, seed: np.ndarray, source: str) -> np.ndarray:
    """The seed on the surface; refused when it lies off the surface, beyond its edge, or where K >= 0."""
    _, foot, squared = surface.closest(seed[None])
    distance = float(np.sqrt(squared[0]))
    if distance <= max(2.0 * surface.edge_length, 1e-6) and surface.outside(seed[None])[0] and \
            distance < 1e-3 * surface.edge_length:
        raise FablineError(f"{source}: seed ({xyz_text(seed)}) lies on the surface's edge: the curves need room both "
                           "ways; give a point inside")
    if distance > max(2.0 * surface.edge_length, 1e-6) or surface.outside(seed[None])[0]:
        raise FablineError(f"{source}: seed ({xyz_text(seed)}) lies {distance:.4g} off the surface (closest surface point "
                           f"({xyz_text(foot[0])})); give a point on the surface")
    on = surface.project(seed[None])
    a, _, gauss = asymptotic_directions(on.normal, on.shape)
    if not np.isfinite(a).all():
        raise FablineError(f"{source}: seed ({xyz_text(seed)}) lies where K = {gauss[0]:.3g} >= 0 (no asymptotic directions); "
                           "choose a seed where the surface is anticlastic")
    return on.xyz[0]

