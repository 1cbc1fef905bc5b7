"""`design minimal`: a discrete minimal surface spanning closed boundary curves, as a mesh the tracer takes.

One curve spans a disc (a Delaunay triangulation of its best-fit-plane projection), two curves a tube
between them (rows of points between the two resampled curves). The interior then minimises area with
the boundary fixed: each step solves the cotangent Laplace equation of the current mesh for the
interior vertices (Pinkall and Polthier's iteration, libigl's cotangent matrix), and a few sweeps of
tangential relaxation move vertices towards their neighbours' centroid within the tangent plane, so the
triangles stay well shaped while the surface converges. It stops when no vertex moves along the normal
by more than a micrometre-scale tolerance.
"""

from __future__ import annotations

from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.optimize import brentq
from scipy.sparse.linalg import splu
from scipy.spatial import Delaunay, cKDTree
from shapely.geometry import Point, Polygon

from fabline.errors import FablineError
from fabline.fileio import atomic_output
from fabline.model.surfaces.curves import read_curves
from fabline.model.surfaces.mesh import xyz_text

MAX_ITERATIONS = 400
RELAX_SWEEPS = 2
CONVERGED_FRACTION = 1e-6  # of the mesh size: the largest normal move that counts as converged
CLOSED_FRACTION = 1e-6  # ends of a curve closer than this fraction of its length: closed


def read_boundaries(path: str | Path, units: str | None = None) -> tuple[list[np.ndarray], str]:
    """Closed boundary curves from a DXF or JSON file (fabline.model.surfaces.curves), and their units.

    A JSON curve is closed when its last point repeats its first; a DXF polyline by its closed flag too.
    """
    curves, units = read_curves(path, units)
    return [_closed(points, where) for points, where in curves], units


def _closed(points: np.ndarray, where: str) -> np.ndarray:
    """The curve without its repeated closing point; refused when its ends do not meet."""
    length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    gap = float(np.linalg.norm(points[-1] - points[0]))
    if length == 0 or gap > CLOSED_FRACTION * length:
        raise FablineError(f"{where}: open curve (its ends ({xyz_text(points[0])}) and ({xyz_text(points[-1])}) are {gap:.4g} apart): "
                           "a boundary must be closed")
    return points[:-1]


def minimal_surface(boundaries: list[np.ndarray], mesh_size: float, source: str = "boundary") -> trimesh.Trimesh:
    """A discrete minimal surface with triangles about `mesh_size` across, spanning one or two closed curves."""
    if not (0 < mesh_size < np.inf):
        raise FablineError(f"--mesh-size must be a positive number, got {mesh_size:g}")
    lengths = [float(np.linalg.norm(np.diff(np.vstack([c, c[:1]]), axis=0), axis=1).sum()) for c in boundaries]
    if min(lengths) < 3 * mesh_size:
        raise FablineError(f"{source}: mesh size {mesh_size:g} is too coarse for a boundary curve {min(lengths):.4g} long")
    if len(boundaries) == 1:
        vertices, faces, fixed = _disc(boundaries[0], mesh_size, source)
    elif len(boundaries) == 2:
        vertices, faces, fixed = _tube(boundaries[0], boundaries[1], mesh_size)
    else:
        raise FablineError(f"{source}: {len(boundaries)} boundary curves; one (a disc) or two (a tube between them) are "
                           "supported")
    return trimesh.Trimesh(_minimise(vertices, faces, fixed, mesh_size), faces, process=False)


def _minimise(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, mesh_size: float) -> np.ndarray:
    """Cotangent-Laplace steps with the boundary fixed, and tangential relaxation, until the normal moves vanish."""
    free = np.flatnonzero(~fixed)
    neighbours = igl.adjacency_matrix(faces).astype(float)
    uniform = sp.diags(1.0 / np.asarray(neighbours.sum(axis=1)).ravel()) @ neighbours
    vertices = vertices.copy()
    for _ in range(MAX_ITERATIONS):
        laplacian = igl.cotmatrix(vertices, faces).tocsr()
        inner = laplacian[free][:, free].tocsc()
        rhs = -laplacian[free][:, fixed] @ vertices[fixed]
        solved = splu(inner).solve(rhs)
        normals = igl.per_vertex_normals(vertices, faces)[free]
        moved = np.abs(np.einsum("ij,ij->i", solved - vertices[free], normals)).max()
        vertices[free] = solved
        for _ in range(RELAX_SWEEPS):
            normals = igl.per_vertex_normals(vertices, faces)[free]
            delta = (uniform @ vertices)[free] - vertices[free]
            vertices[free] += 0.5 * (delta - np.einsum("ij,ij->i", delta, normals)[:, None] * normals)
        if moved < CONVERGED_FRACTION * mesh_size:
            break
    return vertices


def _resample(curve: np.ndarray, count: int) -> np.ndarray:
    """`count` points evenly spaced in arc length along a closed polyline."""
    closed = np.vstack([curve, curve[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], count, endpoint=False)
    return np.stack([np.interp(t, s, closed[:, i]) for i in range(3)], axis=1)


def _disc(curve: np.ndarray, size: float, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A triangulated disc inside the curve's projection onto its best-fit plane, the interior flat in that plane."""
    length = float(np.linalg.norm(np.diff(np.vstack([curve, curve[:1]]), axis=0), axis=1).sum())
    rim = _resample(curve, max(8, int(np.ceil(length / size))))
    centre = rim.mean(axis=0)
    _, _, axes = np.linalg.svd(rim - centre)
    flat = (rim - centre) @ axes[:2].T
    outline = Polygon(flat)
    if not outline.is_valid:
        raise FablineError(f"{source}: the boundary curve crosses itself seen along its best-fit plane's normal; "
                           "one closed curve must bound a disc")
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    rows = np.arange(lo[1], hi[1], size * np.sqrt(3) / 2)
    lattice = np.array([(x + (k % 2) * size / 2, y) for k, y in enumerate(rows) for x in np.arange(lo[0], hi[0], size)])
    keep = np.array([outline.contains(Point(p)) for p in lattice]) if len(lattice) else np.zeros(0, bool)
    lattice = lattice[keep] if len(lattice) else lattice.reshape(0, 2)
    if len(lattice):
        lattice = lattice[cKDTree(flat).query(lattice)[0] > 0.6 * size]
    points = np.vstack([flat, lattice])
    faces = Delaunay(points).simplices
    centroids = points[faces].mean(axis=1)
    faces = faces[[outline.contains(Point(c)) for c in centroids]]
    vertices = np.vstack([rim, centre + lattice @ axes[:2]])
    fixed = np.zeros(len(vertices), dtype=bool)
    fixed[:len(rim)] = True
    return vertices, faces, fixed


def _tube(first: np.ndarray, second: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of points between two closed curves (aligned in start and direction), triangulated as a strip."""
    longer = max(np.linalg.norm(np.diff(np.vstack([c, c[:1]]), axis=0), axis=1).sum() for c in (first, second))
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

