"""Edge members: the network's boundary curves as flat curved bars with a bolt hole where each lamella meets them.

The thesis (6.2.4, "Edge Profiles and Joints") fits the edge with curved lamellas at top and bottom, running
tangential to the surface, laser cut individually, then bent and twisted into place; each lamella pair is bolted
between them. Such a bar's WIDE face lies in the tangent plane, its width along the conormal u = n x t: it is the
strip the unroller already makes when the conormal is given as the strip's "normal". Its in-plane curvature is
then the boundary's geodesic curvature k_g, its weak-axis bending the normal curvature k_n, its twist the
geodesic torsion; so the same stations, seams, parts and structural check serve, with node holes and no slots.

The boundary of a built-in design whose grid ends inside a curved domain (Enneper) is that domain's boundary on the
exact surface (`domain_edge`), scaled just clear of the nodes; its lamellas run on along their grid lines to it
(`extend_to_edge`), and the bars hold each there. Any other network's boundary runs through its lamella ends (the
first and last node of each lamella): ends at most NEIGHBOUR_HOPS node intervals apart along the lamellas are
neighbours on one boundary; each group is ordered into the shortest tour (nearest neighbour, then 2-opt), closed
unless exactly one step joins ends that are not neighbours, and split into separate bars at corners where it turns
more than CORNER_TURN_DEG; between the ends the curve is the exact surface's for the catenoid and helicoid (a cubic
spline through the nodes' parameters), else a spline through the nodes and their normals. Two copies, top and
bottom, sit on the node washers (`layer_offset`) either side of the surface along its normal, each developed by its
own offset curve's geodesic curvature (`offset_turning`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fabline.errors import FablineError
from fabline.geometry.darboux import CurveFit, LamellaGeometry
from fabline.geometry.offsets import OffsetCurve
from fabline.mechanics.materials import Profile
from fabline.mechanics.structure import check_lamellas
from fabline.model.designs import SAMPLE_STEP_M, DomainBoundary, design_boundary, design_surface
from fabline.model.network import Lamella, Network
from fabline.unroll.options import UnrollOptions
from fabline.unroll.parts import Part
from fabline.unroll.pieces import segment_part
from fabline.unroll.seams import Segment, split_strip
from fabline.unroll.stations import Strip

EDGE_FAMILY = "E"
NEIGHBOUR_HOPS = 3        # boundary neighbours: lamella ends at most this many node intervals apart along lamellas
CORNER_TURN_DEG = 60.0    # a boundary turning more than this at a node is split there into two bars
SAMPLE_MM = 20.0          # sample spacing of a boundary curve (every node is a sample)
LAYERS = (("T", -1.0), ("B", 1.0))  # top (+n side) and bottom bars; the sign of their offset along u' = -n
NODE_CLEARANCE = 15.0     # mm from a bar's edge to any node's bolt axis: a carriage bolt's head (M8: 20 across) + 5
DENSE = 20000             # samples of a domain boundary for distances and arc lengths (3 mm apart on the pavilion)


@dataclass
class BoundaryCurve:
    """One edge member's curve (mm): nodes in order (a closed loop lists its first node again at its end), dense
    samples with the surface normals, and each node's sample row."""

    id: str
    node_ids: list[str]
    closed: bool
    points: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    node_rows: np.ndarray


def boundary_chains(network: Network) -> list[tuple[list[str], bool]]:
    """The lamella ends of the network grouped into boundaries, each in order along it: (node ids, closed), split at
    corners; a FablineError names the lamella and node where no boundary can be found."""
    network = _in_mm(network)
    owner: dict[str, str] = {}
    links: dict[str, set[str]] = {}
    for lam in network.lamellas:
        owner.setdefault(lam.nodes[0], lam.id)
        owner.setdefault(lam.nodes[-1], lam.id)
        for a, b in zip(lam.nodes[:-1], lam.nodes[1:]):
            links.setdefault(a, set()).add(b)
            links.setdefault(b, set()).add(a)
    ids = list(owner)
    index = {nid: k for k, nid in enumerate(ids)}
    hops = _end_hops(ids, index, links)
    xyz = np.array([network.nodes[nid].xyz for nid in ids], dtype=float).reshape(-1, 3)
    near = np.array([(i, j) for i, row in enumerate(hops) for j in row], dtype=int).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(near)), (near[:, 0], near[:, 1])), shape=(len(ids), len(ids)))
    count, label = connected_components(graph, directed=False)
    mean_normal = np.mean([network.nodes[nid].normal for nid in ids], axis=0)
    chains = []
    for group in range(count):
        members = np.flatnonzero(label == group)
        if len(members) < 2:
            nid = ids[members[0]]
            raise FablineError(f"lamella {owner[nid]}: no other lamella end lies within {NEIGHBOUR_HOPS} lamella "
                               f"intervals of its end node {nid}, so no boundary runs through it")
        local = {int(m): k for k, m in enumerate(members)}
        adjacent = np.zeros((len(members), len(members)), dtype=bool)
        for m in members:
            adjacent[local[int(m)], [local[j] for j in hops[m]]] = True
        order = _tour(xyz[members], adjacent)
        gaps = np.flatnonzero(~adjacent[order, np.roll(order, -1)])
        chain = [ids[members[k]] for k in order]
        if len(gaps) > 1:
            a, b = chain[gaps[1]], chain[(gaps[1] + 1) % len(chain)]
            raise FablineError(f"lamella {owner[a]}: the boundary through its end node {a} breaks off towards {b} "
                               f"(not within {NEIGHBOUR_HOPS} lamella intervals) in {len(gaps)} places: the lamella "
                               "ends do not line up into one edge")
        closed = not len(gaps) and len(chain) > 2
        if len(gaps):
            chain = chain[gaps[0] + 1:] + chain[:gaps[0] + 1]
        points = np.array([network.nodes[nid].xyz for nid in chain])
        centre = points.mean(axis=0)
        turning = np.cross(points - centre, np.roll(points, -1, axis=0) - centre).sum(axis=0)
        if np.dot(turning, mean_normal) < 0:
            chain = chain[::-1]
        if closed:
            first = chain.index(min(chain))
            chain = chain[first:] + chain[:first]
        chains.extend(_corners(chain, closed, network))
    return sorted(chains, key=lambda item: item[0][0])


def _in_mm(network: Network) -> Network:
    """The network in millimetres, itself when it is already (the unroller's is: no copy of every node)."""
    return network if network.units == "mm" else network.in_mm()


def _end_hops(ids: list[str], index: dict[str, int], links: dict[str, set[str]]) -> list[dict[int, int]]:
    """Per lamella end, the other ends within NEIGHBOUR_HOPS steps along the lamellas (breadth first) and their hops."""
    rows = []
    for nid in ids:
        seen, frontier, found = {nid}, [nid], {}
        for hop in range(1, NEIGHBOUR_HOPS + 1):
            frontier = [b for a in frontier for b in links.get(a, ()) if b not in seen]
            seen.update(frontier)
            for b in frontier:
                if b in index and index[b] not in found:
                    found[index[b]] = hop
        rows.append(found)
    return rows


def _tour(points: np.ndarray, adjacent: np.ndarray) -> np.ndarray:
    """A short closed tour through the points, steps between `adjacent` ones first: nearest neighbour from the
    first point, then 2-opt until no move shortens it (a step between non-adjacent points costs a long detour)."""
    n = len(points)
    distance = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    distance = np.where(adjacent | np.eye(n, dtype=bool), distance, distance + 100.0 * distance.max())
    order, free = [0], np.ones(n, dtype=bool)
    free[0] = False
    for _ in range(n - 1):
        row = np.where(free, distance[order[-1]], np.inf)
        order.append(int(np.argmin(row)))
        free[order[-1]] = False
    order = np.array(order)
    for _ in range(10 * n):
        a, b = order, np.roll(order, -1)
        # reversing order[i+1..j] swaps edges (a_i, b_i), (a_j, b_j) for (a_i, a_j), (b_i, b_j)
        gain = (distance[a, b][:, None] + distance[a, b][None, :] - distance[a[:, None], a[None, :]]
                - distance[b[:, None], b[None, :]])
        gain = np.triu(gain, 2)
        i, j = np.unravel_index(np.argmax(gain), gain.shape)
        if gain[i, j] <= 1e-9:
            break
        order[i + 1:j + 1] = order[i + 1:j + 1][::-1].copy()
    return order


def _corners(chain: list[str], closed: bool, network: Network) -> list[tuple[list[str], bool]]:
    """The chain split into separate bars at nodes where it turns more than CORNER_TURN_DEG (each corner node ends one
    bar and starts the next)."""
    points = np.array([network.nodes[nid].xyz for nid in chain], dtype=float)
    if closed:
        before, after = points - np.roll(points, 1, axis=0), np.roll(points, -1, axis=0) - points
        inner = np.arange(len(chain))
    else:
        before, after, inner = points[1:-1] - points[:-2], points[2:] - points[1:-1], np.arange(1, len(chain) - 1)
    cosine = np.einsum("ij,ij->i", before, after) / (np.linalg.norm(before, axis=1) * np.linalg.norm(after, axis=1))
    corners = inner[cosine < np.cos(np.radians(CORNER_TURN_DEG))].tolist()
    if not corners:
        return [(chain + [chain[0]] if closed else chain, closed)]
    if closed:
        chain = chain[corners[0]:] + chain[:corners[0] + 1]
        corners = [c - corners[0] if c >= corners[0] else c + len(chain) - 1 - corners[0] for c in corners]
        corners = sorted(set(corners) | {len(chain) - 1})
    else:
        corners = [0] + corners + [len(chain) - 1]
    return [(chain[a:b + 1], False) for a, b in zip(corners[:-1], corners[1:]) if b > a]


def boundary_curves(network: Network, options: UnrollOptions | None = None) -> list[BoundaryCurve]:
    """Every edge member's curve of the network (mm), ids E1, E2, ...: a built-in design with a curved domain
    (Enneper) has its domain's boundary on the exact surface (`domain_edge`), split at the domain's corners, through
    the points where the lamellas meet it; other built-ins the exact surface through their end nodes; else a cubic
    spline through the boundary nodes and their normals."""
    edge = domain_edge(network, options or UnrollOptions())
    if edge is not None:
        return domain_curves(edge)
    exact = design_surface(network)
    mm = _in_mm(network)
    return [_sample(f"E{k}", chain, closed, mm, exact) for k, (chain, closed) in enumerate(boundary_chains(network), 1)]


@dataclass
class DomainEdge:
    """A built-in design's edge: its domain boundary scaled by `rho` (1, or just over where a node would lie under a
    bar or closer than NODE_CLEARANCE to its edge), and where each lamella's grid line meets it: per (lamella, end
    0 or -1) the meeting point's id (the lamella's id, .1 at its first end, .2 at its last) and parameters (a, b)."""

    boundary: DomainBoundary
    rho: float
    meetings: dict[tuple[str, int], tuple[str, float, float]]


def domain_edge(network: Network, options: UnrollOptions) -> DomainEdge | None:
    """The edge of a built-in design with a curved domain (`designs.design_boundary`), for bars `edge_options`
    wide; None for any other network."""
    boundary = design_boundary(network)
    if boundary is None:
        return None
    params = design_surface(network)[1]
    width = edge_options(options).profile.h
    xyz = np.array([boundary.surface.point(*params[nid]) for nid in network.nodes]) * 1000.0
    need = width / 2.0 + NODE_CLEARANCE
    theta = np.linspace(0.0, 2.0 * np.pi, DENSE, endpoint=False)

    def clearance(rho: float) -> float:
        """The nearest node's distance (mm) from the boundary scaled by rho."""
        return float(cKDTree(boundary.surface.point(*boundary.at(theta, rho)) * 1000.0).query(xyz)[0].min())

    rho = 1.0
    if clearance(1.0) < need:  # every node lies inside: the distance grows with rho
        low, high = 1.0, 1.01
        while clearance(high) < need:
            low, high = high, 1.0 + 2.0 * (high - 1.0)
        for _ in range(30):
            low, high = (low, (low + high) / 2.0) if clearance((low + high) / 2.0) >= need else ((low + high) / 2.0, high)
        rho = high
    meetings = {}
    for lam in network.lamellas:
        for end, inner, mark in ((0, 1, 1), (-1, -2, 2)):
            (a, b), (pa, pb) = params[lam.nodes[end]], params[lam.nodes[inner]]
            run = boundary.meeting(a, b, a - pa, b - pb, rho)
            meetings[(lam.id, end)] = (f"{lam.id}.{mark}", a + run * (a - pa), b + run * (b - pb))
    return DomainEdge(boundary, rho, meetings)


def extend_to_edge(network: Network, options: UnrollOptions) -> Network:
    """The network with every lamella's centreline run on along its grid line, on the exact surface, from its end
    nodes to where it meets the `domain_edge` (the same nodes); the network itself when it has no such edge."""
    edge = domain_edge(network, options)
    if edge is None:
        return network
    surface, params = edge.boundary.surface, design_surface(network)[1]
    to_units = 1.0 / network.mm_per_unit * 1000.0  # the surface's metres in the network's units
    lamellas = []
    for lam in network.lamellas:
        pieces = []
        for end in (0, -1):
            (a, b), (_, ma, mb) = params[lam.nodes[end]], edge.meetings[(lam.id, end)]
            chord = np.linalg.norm(surface.point(ma, mb) - surface.point(a, b))
            t = np.linspace(0.0, 1.0, max(2, int(np.ceil(chord / SAMPLE_STEP_M))) + 1)[1:]
            t = t[::-1] if end == 0 else t   # the start's run from the meeting towards the node
            pa, pb = a + t * (ma - a), b + t * (mb - b)
            pieces.append((surface.point(pa, pb) * to_units, surface.normal(pa, pb)))
        (start, start_n), (stop, stop_n) = pieces
        lamellas.append(dataclasses.replace(lam, curve=np.vstack([start, lam.curve, stop]),
                                            normals=np.vstack([start_n, lam.normals, stop_n])))
    return Network(network.units, network.nodes, lamellas, network.name, dict(network.meta))


def domain_curves(edge: DomainEdge) -> list[BoundaryCurve]:
    """The edge members along a `domain_edge` (mm): one closed loop round a domain without corners (from the
    meeting of the smallest id, the lap one meeting interval past it each way), else one bar per side from corner to
    corner, the corners nodes that both bars hold (the lamella end that meets the edge there, else K1, K2, ... by
    angle). Each through its meetings in order, counter-clockwise in the parameter plane, sampled as `_sample` does."""
    boundary = edge.boundary
    ids = {mid: boundary.angle(a, b) for mid, a, b in edge.meetings.values()}
    stops = sorted(ids.items(), key=lambda item: (item[1], item[0]))
    if not len(boundary.corners):
        names, angles = [n for n, _ in stops], np.array([a for _, a in stops])
        first = names.index(min(names))
        names, angles = names[first:] + names[:first], np.concatenate([angles[first:], angles[:first] + 2 * np.pi])
        loop = np.concatenate([[angles[-1] - 2 * np.pi], angles, [angles[0] + 2 * np.pi]])
        knots = np.concatenate([[angles[-1] - 2 * np.pi], angles, angles[:2] + 2 * np.pi])  # a lap each way
        return [_domain_sample("E1", names + names[:1], True, knots, boundary, edge.rho)]
    corners = boundary.corners
    # a corner's bolt: the lamella end that meets the edge there, if one does
    at_corner = [next((n for n, a in stops if abs((a - c + np.pi) % (2 * np.pi) - np.pi) < 1e-9), f"K{k}")
                 for k, c in enumerate(corners, 1)]
    curves = []
    for k, (lo, hi) in enumerate(zip(corners, np.append(corners[1:], corners[0] + 2 * np.pi)), 1):
        inside = [(n, a if a >= lo else a + 2 * np.pi) for n, a in stops if n not in at_corner]
        inside = sorted((item for item in inside if lo < item[1] < hi), key=lambda item: item[1])
        names = [at_corner[k - 1]] + [n for n, _ in inside] + [at_corner[k % len(corners)]]
        curves.append(_domain_sample(f"E{k}", names, False, np.array([lo] + [a for _, a in inside] + [hi]),
                                     boundary, edge.rho))
    return curves


def _sample(curve_id: str, chain: list[str], closed: bool, network: Network, exact) -> BoundaryCurve:
    """Sample one boundary every SAMPLE_MM or less with every node a sample; a closed loop runs on past its first
    node by one interval at each end, so its bars' lap there has a curve to follow."""
    nodes = chain[:-1] if closed else chain
    xyz = np.array([network.nodes[nid].xyz for nid in nodes], dtype=float)
    loop = np.vstack([xyz, xyz[:1]]) if closed else xyz
    t = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(loop, axis=0), axis=1))])
    if exact is not None:
        surface, params, period = exact
        values = np.array([params[nid] for nid in nodes] + ([params[nodes[0]]] if closed else []), dtype=float)
        if period:  # a loop round the catenoid: a and b grow together by the period
            values[1:] -= np.cumsum(np.round(np.diff(values[:, 0]) / period))[:, None] * period
    else:
        normals = np.array([network.nodes[nid].normal for nid in nodes], dtype=float)
        values = np.hstack([loop, np.vstack([normals, normals[:1]]) if closed else normals])
    # a loop's values may grow once round it (the catenoid's period): a periodic spline of the rest, the drift added
    slope = (values[-1] - values[0]) / t[-1] if closed else np.zeros(values.shape[1])
    spline = CubicSpline(t, values - np.outer(t, slope),
                         bc_type="periodic" if closed else ("not-a-knot" if len(t) > 3 else "natural"),
                         extrapolate="periodic" if closed else True)
    knots = np.concatenate([t[-2:-1] - t[-1], t, t[-1] + t[1:2]]) if closed else t
    pieces = [np.linspace(a, b, max(2, int(np.ceil((b - a) / SAMPLE_MM))) + 1)[:-1]
              for a, b in zip(knots[:-1], knots[1:])]
    tau = np.concatenate(pieces + [knots[-1:]])
    node_at = knots[1:-1] if closed else knots
    rows = np.searchsorted(tau, node_at - 1e-9)

    def value(x: np.ndarray, derivative: int = 0) -> np.ndarray:
        """The interpolated values at parameters x, or their first derivative."""
        return spline(x, 1) + slope if derivative else spline(x) + np.outer(x, slope)

    if exact is not None:
        a, b = value(tau).T
        da, db = value(tau, 1).T
        xa, xb = surface.partials(a, b)
        points = surface.point(a, b) * 1000.0
        normals = surface.normal(a, b)
        tangents = xa * da[:, None] + xb * db[:, None]
    else:
        both = value(tau)
        points, normals, tangents = both[:, :3], both[:, 3:], value(tau, 1)[:, :3]
    tangents = tangents / np.linalg.norm(tangents, axis=1)[:, None]
    normals = normals - np.einsum("ij,ij->i", normals, tangents)[:, None] * tangents
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    return BoundaryCurve(curve_id, list(chain), closed, points, normals, tangents, rows)


def _domain_sample(curve_id: str, names: list[str], closed: bool, knots: np.ndarray, boundary: DomainBoundary,
                   rho: float) -> BoundaryCurve:
    """A boundary curve on the scaled domain boundary through the angles `knots` (a closed loop's first and last
    knot one interval past its ends): every node a sample, at most SAMPLE_MM between samples, all on the exact
    surface with its normals, the tangents from the closed form (one-sided at the ends, where corners are)."""
    fine = np.union1d(np.linspace(knots[0], knots[-1], DENSE), knots)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(
        boundary.surface.point(*boundary.at(fine, rho)) * 1000.0, axis=0), axis=1))])
    at = np.interp(knots, fine, arc)
    pieces = [np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / SAMPLE_MM))) + 1)[:-1] for lo, hi in zip(at[:-1], at[1:])]
    s = np.concatenate(pieces + [at[-1:]])
    theta = np.interp(s, arc, fine)
    a, b = boundary.at(theta, rho)
    step = 1e-7
    ahead, behind = np.minimum(theta + step, knots[-1]), np.maximum(theta - step, knots[0])
    (a1, b1), (a0, b0) = boundary.at(ahead, rho), boundary.at(behind, rho)
    xa, xb = boundary.surface.partials(a, b)
    tangents = xa * ((a1 - a0) / (ahead - behind))[:, None] + xb * ((b1 - b0) / (ahead - behind))[:, None]
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    normals = boundary.surface.normal(a, b)
    normals = normals - np.einsum("ij,ij->i", normals, tangents)[:, None] * tangents
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    rows = np.searchsorted(s, (at[1:-1] if closed else at) - 1e-9)
    return BoundaryCurve(curve_id, names, closed, boundary.surface.point(a, b) * 1000.0, normals, tangents, rows)


def edge_geometry(curve: BoundaryCurve) -> LamellaGeometry:
    """The boundary as a strip whose "normal" is the conormal u = n x t: its frame's in-plane curvature k_n is the
    boundary's geodesic curvature, its k_g minus the normal curvature (weak-axis bending), its tau_g the twist."""
    conormals = np.cross(curve.normals, curve.tangents)
    lamella = Lamella(curve.id, EDGE_FAMILY, list(curve.node_ids), curve.points, conormals)
    fit = CurveFit.of(curve.points, conormals)
    frame = fit.frame(fit.tau)
    return LamellaGeometry(lamella, fit, fit.s_at_samples, frame["t"], frame["u"], frame["n"], frame["k_g"],
                           frame["k_n"], frame["tau_g"], frame["k_n_curve"], list(curve.node_ids),
                           fit.s_at_samples[curve.node_rows], frame["t"][curve.node_rows])


def layer_offset(options: UnrollOptions, bar_thickness: float) -> float:
    """How far the bars' centre planes lie from the surface (mm): on the lamellas' edges (h/2), on top of the node's
    star washer there (one sheet thickness t, cut with the strips), plus half the bar's own thickness. The edge nodes
    get no cable clamp (the cables end at the edge bars), so nothing else lies between washer and bar."""
    return options.profile.h / 2.0 + options.profile.t + bar_thickness / 2.0


def edge_options(options: UnrollOptions) -> UnrollOptions:
    """The options an edge bar is cut with: the lamella's thickness at the edge width (default the lamella height)."""
    width = options.edge_width if options.edge_width is not None else options.profile.h
    return dataclasses.replace(options, profile=Profile(width, options.profile.t), pair_spacing=0.0,
                               compensate_twist=False)


def edge_strips(curves: list[BoundaryCurve], offset: float) -> tuple[list[Strip], list[LamellaGeometry]]:
    """Top and bottom strips of every edge member, `offset` from the surface either side along its normal, each bar
    developed by its own offset curve's geodesic curvature (`offset_turning`); and the centre geometries."""
    strips, geometries = [], []
    for curve in curves:
        geo = edge_geometry(curve)
        geometries.append(geo)
        for side, sign in LAYERS:
            layer = OffsetCurve.of(geo, sign * offset)
            bent = dataclasses.replace(geo, k_n=offset_turning(geo, sign * offset) / layer.ratio)
            layer = dataclasses.replace(layer, geometry=bent)
            strips.append(Strip(bent, side, layer, list(curve.node_ids), layer.s_at_samples[curve.node_rows]))
    return strips, geometries


def offset_turning(geo: LamellaGeometry, offset: float) -> np.ndarray:
    """The turning per centre arc length (1/mm) of the curve p = c + o u in its own face plane, at the samples.

    The bar's face is the plane (t, n) of the edge frame (n the conormal) carried along p; p' = (1 - o k_g) t +
    o tau_g n, so p's tangent is turned from t by the skew angle phi = atan(o tau_g / (1 - o k_g)) in that plane,
    and its geodesic curvature in its own tangent plane is (k_n + dphi/ds) ds / ds_o: the centre curve's turning
    plus the change of skew angle (the surface's k_n and tau_g about the surface normal, in the surface's terms).
    """
    phi = np.arctan2(offset * geo.tau_g, 1.0 - offset * geo.k_g)
    return geo.k_n + np.gradient(phi, geo.s)


def end_fixes(strips: list[Strip], options: UnrollOptions, to_edge: bool) -> None:
    """Give every lamella strip its end-fix holes (`Strip.fix_x`): one on the centreline at each end, halfway between
    its outermost slot, node or edge crossing and its end, for the bolt through the pair's two strips and the square
    tube cleat between them that the edge bars clamp (the thesis's detail; one per lamella end, in the bill of
    materials). `to_edge`: the lamellas run on to the edge (`extend_to_edge`), which crosses them at their curves'
    ends (`Strip.edge_x`), where the edge bolt passes between the pair."""
    for strip in strips:
        if to_edge:
            strip.edge_x = np.array([0.0, strip.curve.length])
        xs = np.concatenate([strip.node_x, strip.slot_x, strip.edge_x])
        strip.fix_x = np.array([xs.min() - options.end / 2.0, xs.max() + options.end / 2.0])


def nodes_near(curves: list[BoundaryCurve], network: Network, reach: float) -> set[str]:
    """The nodes of a network within `reach` (mm) of an edge member's curve (measured to its samples, so within
    reach plus half a sample spacing: never fewer)."""
    if not curves:
        return set()
    mm = _in_mm(network)
    ids = list(mm.nodes)
    distance, _ = cKDTree(np.vstack([c.points for c in curves])).query(np.array([mm.nodes[n].xyz for n in ids]))
    return {nid for nid, d in zip(ids, distance) if d < reach + SAMPLE_MM / 2.0}


def curve_parts(curves: list[BoundaryCurve], options: UnrollOptions, bolt_hole: float) -> tuple[list[Part], dict]:
    """The edge members' parts (a `bolt_hole` at every node) and their report: per bar its nodes, length, segments,
    seams, and the structural check of the bar (weak-axis bending by k_n, twist by tau_g)."""
    bar = edge_options(options)
    try:
        bar.check()
    except FablineError as exc:
        raise FablineError(f"edge members ({bar.profile.h:g} x {bar.profile.t:g} mm bars): {exc}") from None
    strips, geometries = edge_strips(curves, layer_offset(options, bar.profile.t))
    parts, rows, avoid = [], [], {}
    for strip in strips:
        taken = avoid.setdefault(strip.lamella, set())
        segments: list[Segment] = split_strip(strip, bar, 0.0, taken)
        taken.update(s.end_join.interval for s in segments[:-1])
        for segment in segments:
            part = segment_part(segment, bar, node_hole=bolt_hole)
            part.meta["member"] = "edge"
            parts.append(part)
        rows.append({"strip": strip.id, "edge": strip.lamella, "layer": "top" if strip.side == "T" else "bottom",
                     "offset_mm": round(-strip.offset, 3), "length_mm": round(segments[-1].end - segments[0].start, 3),
                     "segments": [s.id for s in segments]})
    checks = check_lamellas(geometries, options.material, bar.profile)
    members = []
    for curve, geo, check in zip(curves, geometries, checks):
        summary = check.summary(options.material, bar.profile)
        summary = {"edge": summary.pop("lamella"), "closed": curve.closed, "nodes": curve.node_ids, **summary,
                   "length_mm": round(float(geo.node_s[-1] - geo.node_s[0]), 3)}  # a loop's, without its lap
        members.append(summary)
    warnings = ["edge member " + line.removeprefix("lamella ") for check in checks for line in check.warnings]
    report = {"width_mm": bar.profile.h, "thickness_mm": bar.profile.t, "bolt_hole_mm": bolt_hole,
              "members": members, "bars": rows, "warnings": warnings}
    return parts, report
