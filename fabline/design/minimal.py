"""`design minimal`: a discrete minimal surface spanning closed boundary curves, as a mesh the tracer takes.

Curves whose projections onto their mean plane nest (an outer curve, any number of openings or inner
rings inside it) start as the planar region between them, triangulated and lifted harmonically; two
curves that do not nest (coaxial rings) start as a tube of rows between them. The interior then
minimises area with the boundary fixed: rounds of isotropic remeshing (fabline.design.remesh)
alternate with steps that solve the cotangent Laplace equation of the current mesh for the interior
vertices (Pinkall and Polthier's iteration, libigl's cotangent matrix) and relax them tangentially
towards their neighbours' centroid, so the triangles stay well shaped while the surface converges;
last, steps along the normals only until no vertex moves by more than a micrometre-scale tolerance.
"""

from __future__ import annotations

from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
import shapely
import trimesh
from scipy.optimize import brentq
from scipy.sparse.linalg import splu
from scipy.spatial import Delaunay
from shapely.geometry import Polygon

from fabline.design.curves import read_curves
from fabline.design.mesh import tangent_basis, xyz_text
from fabline.design.remesh import remesh
from fabline.errors import FablineError
from fabline.fileio import atomic_output

MAX_ITERATIONS = 400
RELAX_SWEEPS = 2
REMESH_ROUNDS = 6  # splits, collapses and flips, each round followed by STEPS_PER_ROUND area steps
STEPS_PER_ROUND = 8
SETTLED_FRACTION = 0.01  # a remeshing round that changes fewer edges than this fraction of the faces ends the rounds
CONVERGED_FRACTION = 1e-6  # of the mesh size: the largest normal move that counts as converged
CLOSED_FRACTION = 1e-6  # ends of a curve closer than this fraction of its length: closed
MESH_SIZE_MM = (1.0, 10_000.0)
"""Triangle sizes a gridshell's surface (or its scale model's) can be meshed at: outside, a number is taken for
another unit (`--mesh-size 0.1` on curves in mm is a size in metres)."""
MAX_MESH_VERTICES = 1_000_000
"""Vertices a spanned surface may have at most (the reference pavilion, 9 x 12 m at 0.1 m, has about 12,500)."""


def read_boundaries(path: str | Path, units: str | None = None) -> tuple[list[np.ndarray], list[str], str]:
    """Closed boundary curves from a DXF or JSON file (fabline.design.curves), where each is (for messages), and the units.

    A JSON curve is closed when its last point repeats its first; a DXF polyline by its closed flag too.
    """
    curves, units = read_curves(path, units)
    return [_closed(points, where) for points, where in curves], [where for _, where in curves], units


def _closed(points: np.ndarray, where: str) -> np.ndarray:
    """The curve without its repeated closing point; refused when its ends do not meet."""
    length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    gap = float(np.linalg.norm(points[-1] - points[0]))
    if length == 0 or gap > CLOSED_FRACTION * length:
        raise FablineError(f"{where}: open curve (its ends ({xyz_text(points[0])}) and ({xyz_text(points[-1])}) are {gap:.4g} apart): "
                           "a boundary must be closed")
    return points[:-1]


def minimal_surface(boundaries: list[np.ndarray], mesh_size: float, source: str = "boundary",
                    names: list[str] | None = None) -> trimesh.Trimesh:
    """A discrete minimal surface with triangles about `mesh_size` across, spanning closed curves.

    Curves whose projections onto their mean plane nest (one outer curve, the others inside it and apart)
    span the planar domain between them; two curves that do not nest (coaxial rings) span a tube.
    `names` (default "curve k") say which curve a message is about.
    """
    if not (0 < mesh_size < np.inf):
        raise FablineError(f"--mesh-size must be a positive number, got {mesh_size:g}")
    names = names or [f"{source}: curve {k}" for k in range(len(boundaries))]
    lengths = [_length(c) for c in boundaries]
    if min(lengths) < 3 * mesh_size:
        short = int(np.argmin(lengths))
        raise FablineError(f"{names[short]}: mesh size {mesh_size:g} is too coarse for a boundary curve {lengths[short]:.4g} long")
    _check_mesh_size(boundaries, lengths, mesh_size, source)
    rims = [_resample(c, max(8, int(np.ceil(length / mesh_size)))) for c, length in zip(boundaries, lengths)]
    domain = _planar_domain(rims, mesh_size, source, names, tube_instead=len(rims) == 2)
    vertices, faces, fixed = domain if domain is not None else _tube(boundaries[0], boundaries[1], mesh_size)
    vertices, faces = _minimise(vertices, faces, fixed, mesh_size)
    return trimesh.Trimesh(vertices, faces, process=False)


def _check_mesh_size(boundaries: list[np.ndarray], lengths: list[float], mesh_size: float, source: str) -> None:
    """Refuse, before any array is made, a mesh estimated over MAX_MESH_VERTICES: the rims' points (length / size)
    and a lattice filling the curves' bounding box across its two largest sides (area / (size^2 sqrt(3)/2))."""
    sides = np.sort(np.ptp(np.vstack(boundaries), axis=0))
    rim = sum(length / mesh_size for length in lengths)
    vertices = rim + sides[1] * sides[2] / (mesh_size * mesh_size * np.sqrt(3) / 2)
    if vertices > MAX_MESH_VERTICES:
        raise FablineError(f"{source}: --mesh-size {mesh_size:g} on boundary curves {sides[2]:.4g} x {sides[1]:.4g} "
                           f"across would make about {vertices:.2g} vertices; the limit is {MAX_MESH_VERTICES:.0e}: "
                           "give a larger --mesh-size")


def _minimise(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, mesh_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Rounds of remeshing towards `mesh_size` and area steps with tangential relaxation (until a round hardly changes
    the mesh), then plain area steps until the normal moves vanish."""
    for _ in range(REMESH_ROUNDS):
        vertices, faces, fixed, changes = remesh(vertices, faces, fixed, mesh_size)
        if changes < SETTLED_FRACTION * len(faces):
            break
        vertices = _area_steps(vertices, faces, fixed, mesh_size, STEPS_PER_ROUND, RELAX_SWEEPS)
    return _area_steps(vertices, faces, fixed, mesh_size, MAX_ITERATIONS, 0), faces


def _area_steps(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, mesh_size: float, steps: int, sweeps: int
                ) -> np.ndarray:
    """Up to `steps` cotangent-Laplace solves with the boundary fixed, each followed by `sweeps` of tangential
    relaxation; stops early once no vertex moves along its normal.

    With sweeps the vertices take the solve's positions (Pinkall and Polthier's step); without, only its move along
    their normals, so that vertices do not drift along the surface and the iteration settles on the shape.
    """
    free = np.flatnonzero(~fixed)
    neighbours = igl.adjacency_matrix(faces).astype(float)
    uniform = sp.diags(1.0 / np.asarray(neighbours.sum(axis=1)).ravel()) @ neighbours
    vertices = vertices.copy()
    for _ in range(steps):
        laplacian = igl.cotmatrix(vertices, faces).tocsr()
        inner = laplacian[free][:, free].tocsc()
        rhs = -laplacian[free][:, fixed] @ vertices[fixed]
        solved = splu(inner, permc_spec="MMD_AT_PLUS_A").solve(rhs)  # the ordering for a symmetric matrix
        normals = igl.per_vertex_normals(vertices, faces)[free]
        along = np.einsum("ij,ij->i", solved - vertices[free], normals)
        if sweeps:
            vertices[free] = solved
        else:
            vertices[free] += along[:, None] * normals
        for _ in range(sweeps):
            normals = igl.per_vertex_normals(vertices, faces)[free]
            delta = (uniform @ vertices)[free] - vertices[free]
            vertices[free] += 0.5 * (delta - np.einsum("ij,ij->i", delta, normals)[:, None] * normals)
        if np.abs(along).max() < CONVERGED_FRACTION * mesh_size:
            break
    return vertices


def _resample(curve: np.ndarray, count: int) -> np.ndarray:
    """`count` points evenly spaced in arc length along a closed polyline."""
    closed = np.vstack([curve, curve[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], count, endpoint=False)
    return np.stack([np.interp(t, s, closed[:, i]) for i in range(3)], axis=1)


def _length(curve: np.ndarray) -> float:
    """Length of a closed polyline."""
    return float(np.linalg.norm(np.diff(np.vstack([curve, curve[:1]]), axis=0), axis=1).sum())


def _planar_domain(rims: list[np.ndarray], size: float, source: str, names: list[str], tube_instead: bool
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The region between the curves' projections onto their mean plane, triangulated and lifted harmonically.

    The plane's normal is the largest curve's vector area. The largest projection is the outer boundary; the
    others must lie inside it and apart from each other by at least half a triangle (holes). Interior points
    (a triangular lattice kept 0.6 `size` from every rim segment, so every rim edge is a Delaunay edge) are
    triangulated with the rims, and lifted by the Laplace equation of the flat triangulation with the rims
    fixed at their heights. When the projections do not nest, None if `tube_instead`, else refused.
    """
    centre = np.vstack(rims).mean(axis=0)
    areas = [0.5 * np.cross(r - centre, np.roll(r, -1, axis=0) - centre).sum(axis=0) for r in rims]
    largest = int(np.argmax([np.linalg.norm(a) for a in areas]))
    normal = areas[largest] / np.linalg.norm(areas[largest])
    t1, t2 = tangent_basis(normal[None])
    axes = np.vstack([t1, t2])
    flats = [(r - centre) @ axes.T for r in rims]
    outlines = [Polygon(f) for f in flats]
    for k, outline in enumerate(outlines):
        if not outline.is_valid:
            raise FablineError(f"{names[k]}: the boundary curve crosses itself seen along its mean plane's normal "
                               f"({xyz_text(normal)}); a spanned curve must not")
    outer = int(np.argmax([o.area for o in outlines]))
    holes = [k for k in range(len(rims)) if k != outer]
    clash = _clash(outlines, outer, holes, 0.5 * size)
    if clash is not None:
        if tube_instead:
            return None
        first, second = (names[k].removeprefix(f"{source}: ") for k in clash)
        raise FablineError(f"{source}: {first} and {second}: their projections onto the curves' mean plane (normal "
                           f"({xyz_text(normal)})) cross, overlap or come within {0.5 * size:.4g} of each other; the curves "
                           "can be spanned when one encloses the others, which lie apart inside it, or two form a tube")
    region = Polygon(flats[outer], [flats[k] for k in holes])
    lo, hi = flats[outer].min(axis=0), flats[outer].max(axis=0)
    rows = np.arange(lo[1], hi[1], size * np.sqrt(3) / 2)
    lattice = np.array([(x + (k % 2) * size / 2, y) for k, y in enumerate(rows) for x in np.arange(lo[0], hi[0], size)]).reshape(-1, 2)
    lattice = lattice[shapely.contains_xy(region, lattice[:, 0], lattice[:, 1])]
    lattice = lattice[shapely.distance(shapely.points(lattice), region.boundary) > 0.6 * size]
    rim_points = np.vstack([flats[outer]] + [flats[k] for k in holes])
    points = np.vstack([rim_points, lattice])
    faces = Delaunay(points).simplices
    centroids = points[faces].mean(axis=1)
    faces = faces[shapely.contains_xy(region, centroids[:, 0], centroids[:, 1])]
    vertices = np.vstack([rims[outer]] + [rims[k] for k in holes] + [centre + lattice @ axes])
    fixed = np.zeros(len(vertices), dtype=bool)
    fixed[:len(rim_points)] = True
    flat = np.c_[points, np.zeros(len(points))]
    laplacian = igl.cotmatrix(flat, faces).tocsr()
    free = np.flatnonzero(~fixed)
    vertices[free] = splu(laplacian[free][:, free].tocsc()).solve(-laplacian[free][:, fixed] @ vertices[fixed])
    return vertices, faces, fixed


def _clash(outlines: list[Polygon], outer: int, holes: list[int], gap: float) -> tuple[int, int] | None:
    """The first pair of curves that keep the holes from lying inside the outer outline and `gap` apart, or None."""
    for k in holes:
        if not outlines[outer].contains(outlines[k]) or outlines[k].distance(outlines[outer].exterior) < gap:
            return outer, k
    for i, first in enumerate(holes):
        for second in holes[i + 1:]:
            if outlines[first].distance(outlines[second]) < gap:
                return first, second
    return None


def _tube(first: np.ndarray, second: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of points between two closed curves (aligned in start and direction), triangulated as a strip."""
    longer = max(_length(c) for c in (first, second))
    count = max(8, int(np.ceil(longer / size)))
    a, b = _resample(first, count), _resample(second, count)
    options = [np.roll(candidate, -shift, axis=0) for candidate in (b, b[::-1]) for shift in range(count)]
    b = min(options, key=lambda c: float(np.linalg.norm(c - a, axis=1).sum()))
    gap = float(np.linalg.norm(b - a, axis=1).mean())
    layers = max(2, int(np.ceil(gap / (size * np.sqrt(3) / 2))))
    t = np.linspace(0.0, 1.0, layers + 1)
    vertices = (a[None] * (1 - t[:, None, None]) + b[None] * t[:, None, None]).reshape(-1, 3)
    index = np.arange((layers + 1) * count).reshape(layers + 1, count)
    nxt = np.roll(index, -1, axis=1)
    p, q, r, s = index[:-1], nxt[:-1], nxt[1:], index[1:]
    odd = (np.arange(layers) % 2 == 1)[:, None] ^ (np.arange(count) % 2 == 1)[None, :]
    faces = np.concatenate([np.stack([p[~odd], q[~odd], r[~odd]], axis=1), np.stack([p[~odd], r[~odd], s[~odd]], axis=1),
                            np.stack([p[odd], q[odd], s[odd]], axis=1), np.stack([q[odd], r[odd], s[odd]], axis=1)])
    fixed = np.zeros(len(vertices), dtype=bool)
    fixed[index[0]] = fixed[index[-1]] = True
    return vertices, faces, fixed


def write_mesh(mesh: trimesh.Trimesh, path: str | Path) -> None:
    """Write the surface (OBJ, STL, PLY, OFF by suffix) atomically."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in ("obj", "stl", "ply", "off"):
        raise FablineError(f"{path}: unknown mesh type .{suffix} (use .obj, .stl, .ply or .off)")
    data = mesh.export(file_type=suffix)
    with atomic_output(path, "wb" if isinstance(data, bytes) else "w") as handle:
        handle.write(data)


def coaxial_circles(radius: float, separation: float, count: int = 720) -> list[np.ndarray]:
    """Two circles of `radius` about the z axis at z = -separation/2 and +separation/2."""
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(count)], axis=1)
    return [ring + [0, 0, -separation / 2], ring + [0, 0, separation / 2]]


def catenoid_waist(radius: float, separation: float) -> float:
    """Waist a of the stable catenoid through two coaxial circles: the larger root of a cosh(separation / 2a) = radius."""
    half = separation / 2.0
    # a cosh(half / a) has its minimum where tanh(x) = 1/x, x = half / a (x = 1.19968); the stable branch is x below it
    x_min = brentq(lambda x: np.tanh(x) - 1.0 / x, 0.5, 3.0)
    if half / x_min * np.cosh(x_min) > radius:
        raise FablineError(f"circles of radius {radius:g} are too far apart ({separation:g}) for a catenoid between them")
    return float(brentq(lambda a: a * np.cosh(half / a) - radius, half / x_min, radius))

