"""Built-in designs: asymptotic networks on minimal surfaces from closed forms (domain.md section 3).

Each surface is written in coordinates (a, b) whose lines are its asymptotic curves: family A
lamellas run along a (b fixed), family B along b (a fixed), and nodes sit at the grid (a_i, b_j).
Public entry points: `enneper_network`, `catenoid_network`, `helicoid_network`, and `DESIGNS`, the
name -> builder table that the CLI and job files use. All models are in metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import brentq, fsolve

from fabline.errors import FablineError
from fabline.model.network import Lamella, Network, Node

SAMPLE_STEP_M = 0.02  # centreline sample spacing: spline arc lengths are then exact to well below 0.01 mm/m
MAX_GRID_NODES = 2_000_000  # a larger (a, b) grid would not fit in memory


@dataclass
class AsymptoticSurface:
    """A minimal surface in asymptotic coordinates: position, partial derivatives, and |k1| as functions of (a, b)."""

    name: str
    point: Callable[[np.ndarray, np.ndarray], np.ndarray]
    partials: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    k1: Callable[[np.ndarray, np.ndarray], np.ndarray]

    def normal(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Unit normal X_a x X_b, shape (..., 3)."""
        xa, xb = self.partials(a, b)
        n = np.cross(xa, xb)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


def enneper_surface(scale: float) -> AsymptoticSurface:
    """Enneper surface of domain.md 5.3 in metres (`scale` metres per unit); u, v lines are asymptotic."""

    def point(u, v):
        return scale * np.stack([6 * u * u * v - 2 * v**3 - 6 * v, 6 * u * v * v - 2 * u**3 - 6 * u, -12 * u * v], axis=-1)

    def partials(u, v):
        xu = np.stack([12 * u * v, 6 * v * v - 6 * u * u - 6, -12 * v + 0 * u], axis=-1)
        xv = np.stack([6 * u * u - 6 * v * v - 6, 12 * u * v, -12 * u + 0 * v], axis=-1)
        return scale * xu, scale * xv

    return AsymptoticSurface("enneper", point, partials, lambda u, v: 1.0 / (3 * scale * (1 + u * u + v * v) ** 2))


def catenoid_surface(waist: float) -> AsymptoticSurface:
    """Catenoid with waist radius `waist` (m), axis z, waist at z = 0; a = theta + z/waist, b = theta - z/waist."""

    def theta_z(a, b):
        return (a + b) / 2, waist * (a - b) / 2

    def point(a, b):
        theta, z = theta_z(a, b)
        r = waist * np.cosh(z / waist)
        return np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=-1)

    def partials(a, b):
        theta, z = theta_z(a, b)
        ch, sh = np.cosh(z / waist), np.sinh(z / waist)
        x_theta = np.stack([-waist * ch * np.sin(theta), waist * ch * np.cos(theta), 0 * theta], axis=-1)
        x_z = np.stack([sh * np.cos(theta), sh * np.sin(theta), 1 + 0 * theta], axis=-1)
        return x_theta / 2 + x_z * waist / 2, x_theta / 2 - x_z * waist / 2

    return AsymptoticSurface("catenoid", point, partials, lambda a, b: 1.0 / (waist * np.cosh(theta_z(a, b)[1] / waist) ** 2))


def helicoid_surface(pitch: float) -> AsymptoticSurface:
    """Helicoid rising `pitch` metres per turn; a = radius along the straight rulings, b = turn angle (helices)."""
    p = pitch / (2 * np.pi)

    def point(rho, theta):
        return np.stack([rho * np.cos(theta), rho * np.sin(theta), p * theta], axis=-1)

    def partials(rho, theta):
        x_rho = np.stack([np.cos(theta), np.sin(theta), 0 * theta + 0 * rho], axis=-1)
        x_theta = np.stack([-rho * np.sin(theta), rho * np.cos(theta), p + 0 * rho], axis=-1)
        return x_rho, x_theta

    return AsymptoticSurface("helicoid", point, partials, lambda rho, theta: p / (p * p + rho * rho))


def network_on_grid(surface: AsymptoticSurface, a_values: np.ndarray, b_values: np.ndarray,
                    inside: Callable[[np.ndarray, np.ndarray], np.ndarray], name: str, meta: dict) -> Network:
    """Nodes at the grid points (a_i, b_j) inside the domain; A lamellas along a, B lamellas along b.

    Each lamella is the longest contiguous run of inside nodes on its grid line (at least two), its
    centreline sampled every SAMPLE_STEP_M with every node as a sample, normals from the surface.
    Node N{i:03d}-{j:03d} lies at (a_i, b_j); meta["grid"] records both lists for reproducibility.
    """
    ai, bj = np.meshgrid(np.arange(len(a_values)), np.arange(len(b_values)), indexing="ij")
    mask = inside(a_values[ai], b_values[bj])
    node_index: dict[tuple[int, int], int] = {}
    lamellas: list[Lamella] = []
    for family, lines in (("A", mask.T), ("B", mask)):
        for line, on in enumerate(lines):
            run = _longest_run(on)
            if run is None:
                continue
            first, last = run
            params = np.arange(first, last + 1)
            if family == "A":
                grid = [(int(i), line) for i in params]
                along, fixed = a_values[params], np.full(len(params), b_values[line])
            else:
                grid = [(line, int(j)) for j in params]
                along, fixed = a_values[np.full(len(params), line)], b_values[params]
            lamellas.append(_sampled_lamella(surface, family, line, grid, along, fixed))
            for g in grid:
                node_index.setdefault(g, 0)
                node_index[g] += 1
    nodes = {}
    for (i, j) in sorted(node_index):
        nid = _node_id(i, j)
        a, b = np.array(a_values[i]), np.array(b_values[j])
        nodes[nid] = Node(nid, surface.point(a, b), surface.normal(a, b))
    _assign_kinds(nodes, lamellas)
    grid = {"a": np.round(a_values, 12).tolist(), "b": np.round(b_values, 12).tolist()}
    return Network("m", nodes, lamellas, name, {**meta, "grid": grid})


def _node_id(i: int, j: int) -> str:
    return f"N{i:03d}-{j:03d}"


def _longest_run(on: np.ndarray) -> tuple[int, int] | None:
    best, start = None, None
    for k, flag in enumerate(list(on) + [False]):
        if flag and start is None:
            start = k
        elif not flag and start is not None:
            if k - start >= 2 and (best is None or k - start > best[1] - best[0] + 1):
                best = (start, k - 1)
            start = None
    return best


def _sampled_lamella(surface: AsymptoticSurface, family: str, line: int, grid: list[tuple[int, int]],
                     a_nodes: np.ndarray, b_nodes: np.ndarray) -> Lamella:
    """Sample a grid line between its nodes finely enough, keeping every node as a sample point."""
    segments_a, segments_b = [a_nodes[:1]], [b_nodes[:1]]
    for k in range(len(grid) - 1):
        fine = np.linspace(0.0, 1.0, 33)
        pa = a_nodes[k] + fine * (a_nodes[k + 1] - a_nodes[k])
        pb = b_nodes[k] + fine * (b_nodes[k + 1] - b_nodes[k])
        length = np.linalg.norm(np.diff(surface.point(pa, pb), axis=0), axis=1).sum()
        steps = max(2, int(np.ceil(length / SAMPLE_STEP_M)))
        t = np.linspace(0.0, 1.0, steps + 1)[1:]
        segments_a.append(a_nodes[k] + t * (a_nodes[k + 1] - a_nodes[k]))
        segments_b.append(b_nodes[k] + t * (b_nodes[k + 1] - b_nodes[k]))
    a, b = np.concatenate(segments_a), np.concatenate(segments_b)
    return Lamella(f"{family}-{line:03d}", family, [_node_id(*g) for g in grid], surface.point(a, b), surface.normal(a, b))


def _assign_kinds(nodes: dict[str, Node], lamellas: list[Lamella]) -> None:
    """Lamella ends are 'edge-end' nodes; those in the lowest tenth of the height are where the shell stands: 'support'."""
    ends = {lam.nodes[0] for lam in lamellas} | {lam.nodes[-1] for lam in lamellas}
    z = np.array([n.xyz[2] for n in nodes.values()])
    low = z.min() + 0.1 * (z.max() - z.min())
    for nid, node in nodes.items():
        node.kind = "grid" if nid not in ends else "support" if node.xyz[2] <= low else "edge-end"


def _check_grid(design: str, option: str, a_count: int, b_count: int) -> None:
    """Refuse, naming `option`, a grid with under two nodes along a line (no lamella) or over MAX_GRID_NODES nodes."""
    if min(a_count, b_count) < 2:
        raise FablineError(f"design {design}: {option} leaves {min(a_count, b_count)} node along a grid line "
                           f"(a lamella needs at least 2)")
    if a_count * b_count > MAX_GRID_NODES:
        raise FablineError(f"design {design}: {option} makes a {a_count} x {b_count} grid, {a_count * b_count:,} nodes "
                           f"(at most {MAX_GRID_NODES:,})")


def _axis_count(arc_length: Callable[[float], float], extent: float, spacing: float) -> int:
    """How many nodes `spacing` apart in arc length fit on the positive half of the axis, beyond the centre."""
    return int(np.floor(arc_length(extent) / spacing + 1e-9))


def _axis_grid(arc_length: Callable[[float], float], extent: float, spacing: float) -> np.ndarray:
    """Parameters from -extent to +extent whose nodes are `spacing` apart in arc length along the axis."""
    count = _axis_count(arc_length, extent, spacing)
    targets = spacing * np.arange(-count, count + 1)
    return np.array([brentq(lambda p, s=s: arc_length(p) - s, -extent - 1, extent + 1) if s else 0.0 for s in targets])


BOUNDARIES = ("ellipse", "diamond", "rectangle")


def _inside(boundary: str, half_a: float, half_b: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    tol = 1e-9
    if boundary == "ellipse":
        return lambda a, b: (a / half_a) ** 2 + (b / half_b) ** 2 <= 1 + tol
    if boundary == "diamond":
        return lambda a, b: np.abs(a) / half_a + np.abs(b) / half_b <= 1 + tol
    if boundary == "rectangle":
        return lambda a, b: (np.abs(a) <= half_a + tol) & (np.abs(b) <= half_b + tol)
    raise FablineError(f"unknown boundary {boundary!r} (use one of {', '.join(BOUNDARIES)})")


def enneper_network(size: tuple[float, float] = (9.0, 12.0), spacing: float = 0.35, k_max: float = 1.1,
                    boundary: str = "ellipse") -> Network:
    """An asymptotic network on the Enneper surface, footprint `size` (x by y, m), node spacing along the axes.

    The scale is set so the largest principal curvature (at the centre) is `k_max` 1/m; the parameter
    domain (an ellipse, diamond or rectangle in u, v) is sized so the footprint spans `size`.
    """
    if not all(0 < v < np.inf for v in (spacing, k_max, *size)):
        raise FablineError("design enneper: size, spacing and k_max must be positive finite numbers")
    scale = 1.0 / (3.0 * k_max)
    surface = enneper_surface(scale)
    half_u, half_v, reach = _fit_domain(surface, boundary, size)
    if reach >= np.sqrt(3):
        raise FablineError(f"design enneper: a {size[0]:g} x {size[1]:g} m footprint at k_max {k_max:g} 1/m reaches "
                           f"where the Enneper surface overlaps itself; lower k_max or the size")

    def axis_length(p: float) -> float:
        return 6 * scale * (p + p**3 / 3)

    _check_grid("enneper", f"spacing {spacing:g} m", 2 * _axis_count(axis_length, half_u, spacing) + 1,
                2 * _axis_count(axis_length, half_v, spacing) + 1)
    u_values = _axis_grid(axis_length, half_u, spacing)
    v_values = _axis_grid(axis_length, half_v, spacing)
    meta = {"design": "enneper", "size_m": list(size), "spacing_m": spacing, "k_max": k_max, "boundary": boundary,
            "scale_m_per_unit": scale, "domain": {"u": half_u, "v": half_v}}
    return network_on_grid(surface, u_values, v_values, _inside(boundary, half_u, half_v), "enneper", meta)


def _fit_domain(surface: AsymptoticSurface, boundary: str, size: tuple[float, float]) -> tuple[float, float, float]:
    """Half-extents of the (a, b) domain whose image spans `size` in x and y, and its largest parameter radius."""
    t = np.linspace(0, 2 * np.pi, 721)
    shape = {"ellipse": (np.cos(t), np.sin(t)),
             "diamond": (np.cos(t) / (np.abs(np.cos(t)) + np.abs(np.sin(t))), np.sin(t) / (np.abs(np.cos(t)) + np.abs(np.sin(t)))),
             "rectangle": (np.clip(np.sqrt(2) * np.cos(t), -1, 1), np.clip(np.sqrt(2) * np.sin(t), -1, 1))}
    if boundary not in shape:
        raise FablineError(f"design: unknown boundary {boundary!r} (use one of {', '.join(BOUNDARIES)})")
    su, sv = shape[boundary]
    fill = np.linspace(0, 1, 25)[:, None]

    def extents(h: np.ndarray) -> np.ndarray:
        p = surface.point(fill * h[0] * su, fill * h[1] * sv)
        return np.array([np.ptp(p[..., 0]), np.ptp(p[..., 1])]) - np.asarray(size)

    halves, _, ok, _ = fsolve(extents, np.array([0.8, 0.8]), full_output=True)
    if ok != 1 or np.any(halves <= 0):
        raise FablineError(f"design: no {boundary} domain gives a {size[0]:g} x {size[1]:g} m footprint")
    return float(halves[0]), float(halves[1]), float(np.max(np.hypot(halves[0] * su, halves[1] * sv)))


def enneper_mesh(network: Network, count: int = 61, margin: float = 1.05):
    """The reference surface of an `enneper_network` as a trimesh: its (u, v) domain, `margin` times larger, meshed
    on a count x count grid, faces wound along X_u x X_v (the design's normals), for writers and importers."""
    import trimesh

    surface = enneper_surface(network.meta["scale_m_per_unit"])
    half_u, half_v = network.meta["domain"]["u"] * margin, network.meta["domain"]["v"] * margin
    u, v = np.meshgrid(np.linspace(-half_u, half_u, count), np.linspace(-half_v, half_v, count), indexing="ij")
    index = np.arange(count * count).reshape(count, count)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return trimesh.Trimesh(surface.point(u, v).reshape(-1, 3), np.r_[np.c_[a, b, c], np.c_[a, c, d]], process=False)


def catenoid_network(waist: float = 1.0, height: float = 3.0, count: int = 16) -> Network:
    """Asymptotic network on a catenoid (axis z, waist circle at z = 0): `count` helical lamellas per family.

    Lamellas follow theta +/- z/waist = const and run from z = -height/2 to +height/2.
    """
    if not (0 < waist < np.inf and 0 < height < np.inf and count >= 3):
        raise FablineError("design catenoid: waist and height must be positive finite numbers and count at least 3")
    surface = catenoid_surface(waist)
    step = 2 * np.pi / count
    reach = int(np.floor(height / waist / step + 1e-9))
    # a = theta + z/w, b = theta - z/w: node (i, j) at a = i*step, b = (i - d)*step with |z| <= height/2.
    _check_grid("catenoid", f"count {count} (height {height:g} m, waist {waist:g} m)", count + 2 * reach, count + 2 * reach)
    values = step * np.arange(-reach, count + reach)
    offset = reach

    def inside(a, b):
        return (np.abs(waist * (a - b) / 2) <= height / 2 + 1e-9)

    network = network_on_grid(surface, values, values, inside, "catenoid",
                              {"design": "catenoid", "waist_m": waist, "height_m": height, "count": count})
    return _close_periodic(network, count, offset)


def _close_periodic(network: Network, count: int, offset: int) -> Network:
    """Identify the grid copies of a closed surface: (i, j) and (i + count, j + count) are one node.

    Keeps one lamella per family and residue class (the complete one), renaming nodes to canonical ids.
    """
    def canonical(nid: str) -> str:
        i, j = (int(x) for x in nid[1:].split("-"))
        shift = (i - offset) // count * count
        return _node_id(i - shift, j - shift)

    lamellas, seen = [], set()
    for lam in sorted(network.lamellas, key=lambda lm: -len(lm.nodes)):
        ids = [canonical(n) for n in lam.nodes]
        index = int(lam.id.split("-")[1])
        key = (lam.family, (index - offset) % count)
        if key in seen:
            continue
        seen.add(key)
        lamellas.append(Lamella(f"{lam.family}-{key[1]:03d}", lam.family, ids, lam.curve, lam.normals))
    lamellas.sort(key=lambda lm: lm.id)
    nodes = {}
    for nid, node in network.nodes.items():
        cid = canonical(nid)
        nodes.setdefault(cid, Node(cid, node.xyz, node.normal))
    used = {n for lam in lamellas for n in lam.nodes}
    nodes = {nid: node for nid, node in sorted(nodes.items()) if nid in used}
    _assign_kinds(nodes, lamellas)
    return Network("m", nodes, lamellas, network.name, network.meta)


def helicoid_network(pitch: float = 6.0, radius: float = 3.0, turns: float = 0.5, spacing: float = 0.35) -> Network:
    """Asymptotic network on a helicoid: straight rulings through the axis and helices `spacing` apart.

    The patch spans radii -radius..+radius and `turns` turns; the rulings are `spacing` apart on the outer helix.
    """
    if not all(0 < v < np.inf for v in (pitch, radius, turns, spacing)):
        raise FablineError("design helicoid: pitch, radius, turns and spacing must be positive finite numbers")
    surface = helicoid_surface(pitch)
    count = int(np.floor(radius / spacing + 1e-9))
    rho = spacing * np.arange(-count, count + 1)
    outer = np.hypot(radius, pitch / (2 * np.pi))
    angle = 2 * np.pi * turns
    theta_count = max(2, int(np.ceil(angle * outer / spacing))) + 1
    _check_grid("helicoid", f"spacing {spacing:g} m", 2 * count + 1, theta_count)
    theta = np.linspace(0, angle, theta_count)
    return network_on_grid(surface, rho, theta, lambda a, b: np.ones(np.broadcast(a, b).shape, bool), "helicoid",
                           {"design": "helicoid", "pitch_m": pitch, "radius_m": radius, "turns": turns, "spacing_m": spacing})


def design_surface(network: Network) -> tuple[AsymptoticSurface, dict[str, tuple[float, float]], float | None] | None:
    """The exact surface (metres) of a built-in design's network, every node's grid parameters (a, b) from its id
    N{i}-{j} and meta["grid"], and the parameters' period (the catenoid's 2 pi, shifting a and b together; else None).
    None for any other network, or one whose nodes no longer lie where the meta puts them (edited since)."""
    meta, grid = network.meta, network.meta.get("grid") or {}
    builders = {"enneper": ("scale_m_per_unit", enneper_surface), "catenoid": ("waist_m", catenoid_surface),
                "helicoid": ("pitch_m", helicoid_surface)}
    key, build = builders.get(meta.get("design"), (None, None))
    if key is None or key not in meta or "a" not in grid or "b" not in grid:
        return None
    surface, a_values, b_values = build(float(meta[key])), np.asarray(grid["a"]), np.asarray(grid["b"])
    params = {}
    for nid in network.nodes:
        try:
            i, j = (int(x) for x in nid[1:].split("-"))
        except ValueError:
            return None
        if not (nid.startswith("N") and 0 <= i < len(a_values) and 0 <= j < len(b_values)):
            return None
        params[nid] = (float(a_values[i]), float(b_values[j]))
    ab = np.array(list(params.values()))
    xyz = np.array([network.nodes[nid].xyz for nid in params], dtype=float) * network.mm_per_unit / 1000.0
    if np.abs(surface.point(ab[:, 0], ab[:, 1]) - xyz).max() > 1e-5:
        return None
    return surface, params, 2 * np.pi if meta["design"] == "catenoid" else None


# a domain boundary's norm of normalised parameters (a / half_a, b / half_b): 1 on the boundary, 1-homogeneous
DOMAIN_NORMS = {"ellipse": lambda x, y: np.hypot(x, y), "diamond": lambda x, y: np.abs(x) + np.abs(y),
                "rectangle": lambda x, y: np.maximum(np.abs(x), np.abs(y))}
DOMAIN_CORNERS = {"ellipse": (), "diamond": (0.0, 0.5, 1.0, 1.5), "rectangle": (0.25, 0.75, 1.25, 1.75)}  # x pi


@dataclass(frozen=True)
class DomainBoundary:
    """The boundary curve of a built-in design's (a, b) domain (an ellipse, diamond or rectangle about the origin),
    on its exact surface (metres): where its lamellas end. `at(theta, rho)` is the point of the boundary scaled by
    rho in the direction theta of the normalised plane (a / half_a, b / half_b); corners at `corners` (radians)."""

    surface: AsymptoticSurface
    shape: str
    half_a: float
    half_b: float

    @property
    def corners(self) -> np.ndarray:
        return np.pi * np.array(DOMAIN_CORNERS[self.shape])

    def norm(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """1 on the boundary, below inside, rho on the boundary scaled by rho."""
        return DOMAIN_NORMS[self.shape](np.asarray(a) / self.half_a, np.asarray(b) / self.half_b)

    def at(self, theta: np.ndarray, rho: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Parameters (a, b) of the scaled boundary at the angles theta."""
        c, s = np.cos(theta), np.sin(theta)
        r = rho / DOMAIN_NORMS[self.shape](c, s)
        return r * c * self.half_a, r * s * self.half_b

    def angle(self, a: float, b: float) -> float:
        """The angle theta (0 .. 2 pi) of parameters (a, b)."""
        return float(np.arctan2(b / self.half_b, a / self.half_a) % (2.0 * np.pi))

    def meeting(self, a: float, b: float, da: float, db: float, rho: float = 1.0) -> float:
        """How far (in steps (da, db)) the parameter line from (a, b) runs until it meets the scaled boundary."""
        if self.norm(a, b) >= rho:
            return 0.0
        far = 1.0
        while self.norm(a + far * da, b + far * db) < rho:
            far *= 2.0
        return float(brentq(lambda x: float(self.norm(a + x * da, b + x * db)) - rho, 0.0, far, xtol=1e-14))


def design_boundary(network: Network) -> DomainBoundary | None:
    """The domain boundary of a built-in design whose lamellas end inside a curved domain (Enneper), None for any
    other network (the catenoid's and helicoid's ends lie on their domain's edges: their nodes are the boundary)."""
    exact = design_surface(network)
    meta = network.meta
    if exact is None or meta.get("design") != "enneper" or meta.get("boundary") not in DOMAIN_NORMS:
        return None
    return DomainBoundary(exact[0], meta["boundary"], float(meta["domain"]["u"]), float(meta["domain"]["v"]))


DESIGNS = {"enneper": enneper_network, "catenoid": catenoid_network, "helicoid": helicoid_network}
