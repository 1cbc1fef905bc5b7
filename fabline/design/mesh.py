"""A designer's triangle mesh as a smooth surface: cubic jets fitted per vertex, blended over each triangle.

Each vertex gets a least-squares cubic height function (an osculating jet) over its two-ring of
neighbours (three-ring where that has too few points, e.g. at the boundary), in a frame of its vertex
normal. A point on the mesh is lifted to the smooth surface by blending the three corner jets with its
barycentric weights: position, normal and second fundamental form vary continuously across edges, and
the curvature comes from the fitted jet, not from the triangles' angles, so irregular, anisotropic or
slightly noisy triangulations give the same field. A noisy mesh (scanned, exported with rounding) is
first denoised: its vertices move a few times onto wider cubic jets (about four rings), which keep the
surface's shape to third order, unlike Laplacian smoothing, and only then get their two-ring jets.
Closest points come from libigl's AABB tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
import scipy.sparse as sp
import trimesh

from fabline.errors import FablineError

JET_TERMS = 10  # 1, x, y, x^2, xy, y^2, x^3, x^2 y, x y^2, y^3
MIN_JET_POINTS = 16  # fewer neighbours than this in the two-ring: take the three-ring
MAX_JET_POINTS = 24  # the nearest this many of the ring (with the vertex) enter the fit
JET_REACH = 2.0  # edge lengths a two-ring jet averages over
SIGNAL_TO_NOISE = 160.0  # wanted |k| r^2 / noise for the weakest-curved tenth of the surface on a noisy mesh
DENOISE_POINTS = 60  # a noisy mesh's vertices move onto cubic jets fitted to this many neighbours (about four rings)
DENOISE_PASSES = 3  # ... this many times (measured on 0.5 mm noise: 1 pass 0.42, 3 passes 0.18 deg median field error)
NOISE_RATIO = 3.0  # wide jets' residual under this many times the two-ring jets': noise (measured 1.0 to 2.4 with
# 0.2 to 0.5 mm of noise, 7.9 to 9.4 on clean meshes from 5,000 to 80,000 triangles and a coarse minimal surface)
DENOISED_JET_POINTS = 40  # then the jets take this many (20k-triangle helicoid, 0.5 mm noise: 7.6 mm max node error, 12.5 with 24)
PROJECTION_ITERATIONS = 2  # Newton steps for the foot point of a normal projection onto the blended surface


@dataclass
class SurfacePoints:
    """Points on the smooth surface: position, unit normal, second fundamental form (3 x 3, tangent), face, flat foot."""

    xyz: np.ndarray
    normal: np.ndarray
    shape: np.ndarray
    face: np.ndarray
    foot: np.ndarray


class SmoothMesh:
    """A triangle mesh with per-vertex cubic jets; `project` maps any point to the blended smooth surface."""

    def __init__(self, mesh: trimesh.Trimesh):
        vertices = np.ascontiguousarray(mesh.vertices, dtype=float)
        self.faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self.edge_length = float(mesh.edges_unique_length.mean())
        self.frames, self.jets, self.scale, residual = fit_jets(vertices, self.faces, np.asarray(mesh.vertex_normals))
        self.denoised = 0
        if self._noisy(vertices, residual):
            wide = fit_jets(vertices, self.faces, np.asarray(mesh.vertex_normals), DENOISE_POINTS)
            # noise leaves the residual the same at a wider reach; a clean mesh's coarseness makes it grow (as reach^4)
            if np.median(wide[3]) < NOISE_RATIO * np.median(residual):
                vertices = self._denoise(vertices, wide)
                mesh = trimesh.Trimesh(vertices, self.faces, process=False)
                self.frames, self.jets, self.scale, _ = fit_jets(vertices, self.faces, np.asarray(mesh.vertex_normals),
                                                                 DENOISED_JET_POINTS)
                self.denoised = DENOISE_PASSES
        self.mesh, self.vertices = mesh, np.ascontiguousarray(vertices)
        self.tree = igl.AABB()
        self.tree.init(self.vertices, self.faces)
        self.boundary_side = _boundary_sides(self.faces)
        self.boundary_vertex = np.zeros(len(self.vertices), dtype=bool)
        self.boundary_vertex[np.c_[self.faces[:, [1, 2]], self.faces[:, [2, 0]], self.faces[:, [0, 1]]].reshape(-1, 3, 2)[self.boundary_side]] = True

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points on the flat triangles: face index, the point, and its squared distance."""
        squared, face, foot = self.tree.squared_distance(self.vertices, self.faces, np.ascontiguousarray(points, dtype=float))
        return np.asarray(face, dtype=np.int64), foot, squared

    def lift(self, face: np.ndarray, foot: np.ndarray, above: np.ndarray | None = None) -> SurfacePoints:
        """The smooth surface over points `above` (default: the feet), blending the jets of the corners of the feet's faces.

        Beyond the boundary the feet stop at the edge while the jets go on: a smooth continuation of the surface.
        """
        above = foot if above is None else above
        weights = _barycentric(self.vertices[self.faces[face]], foot)
        corner = self.faces[face].T.ravel()
        p, n, s = jet_at(self.vertices[corner], self.frames[corner], self.jets[corner], self.scale[corner], np.tile(above, (3, 1)))
        w = weights.T.reshape(3, -1)
        xyz = np.einsum("cv,cvi->vi", w, p.reshape(3, -1, 3))
        normal = np.einsum("cv,cvi->vi", w, n.reshape(3, -1, 3))
        shape = np.einsum("cv,cvij->vij", w, s.reshape(3, -1, 3, 3))
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        tangent = np.eye(3)[None] - normal[:, :, None] * normal[:, None, :]
        shape = tangent @ shape @ tangent
        return SurfacePoints(xyz, normal, shape, face, foot)

    def _denoise(self, vertices: np.ndarray, wide: tuple[np.ndarray, ...]) -> np.ndarray:
        """DENOISE_PASSES times, every vertex moved along its normal onto its jet over DENOISE_POINTS neighbours
        (`wide`: the first pass's fit)."""
        for done in range(DENOISE_PASSES):
            if done:
                normals = trimesh.Trimesh(vertices, self.faces, process=False).vertex_normals
                wide = fit_jets(vertices, self.faces, np.asarray(normals), DENOISE_POINTS)
            frames, jets, scale, _ = wide
            vertices = vertices + (jets[:, 0] * scale)[:, None] * frames[:, 2]
        return vertices

    def _noisy(self, vertices: np.ndarray, residual: np.ndarray) -> bool:
        """Whether the jets' noise (their median fit residual) is too large for the weakest-curved tenth of the surface:
        it would need jets reaching sqrt(SIGNAL_TO_NOISE noise / |k|) to stand SIGNAL_TO_NOISE times above the noise's
        curvature error, further than their own two rings reach."""
        noise = float(np.median(residual))
        _, normal, shape = jet_at(vertices, self.frames, self.jets, self.scale, vertices)
        k1, k2, _, _ = principal(normal, shape)
        weak = float(np.percentile(np.maximum(np.abs(k1), np.abs(k2)), 10))
        return np.sqrt(SIGNAL_TO_NOISE * noise / max(weak, 1e-12)) > JET_REACH * self.edge_length

    def at(self, points: np.ndarray) -> SurfacePoints:
        """The smooth surface above points near it: enough to read the field there."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        face, foot, _ = self.closest(points)
        return self.lift(face, foot, points)

    def project(self, points: np.ndarray) -> SurfacePoints:
        """Normal projection onto the smooth surface (or its continuation beyond the edge), by Newton steps along it."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        query = points
        lifted = self.at(query)
        for _ in range(PROJECTION_ITERATIONS):
            gap = points - lifted.xyz
            query = lifted.xyz + gap - np.einsum("ij,ij->i", gap, lifted.normal)[:, None] * lifted.normal
            lifted = self.at(query)
        return lifted

    def outside(self, points: np.ndarray) -> np.ndarray:
        """True where a point lies beyond the mesh boundary: its closest point is on the boundary, off to the side."""
        face, foot, _ = self.closest(points)
        weights = _barycentric(self.vertices[self.faces[face]], foot)
        zero = weights < 1e-9
        on_boundary = (zero & self.boundary_side[face]).any(axis=1)
        on_boundary |= ((weights > 1 - 1e-9) & self.boundary_vertex[self.faces[face]]).any(axis=1)
        gap = np.asarray(points) - foot
        normal = self.mesh.face_normals[face]
        sideways = np.linalg.norm(gap - np.einsum("ij,ij->i", gap, normal)[:, None] * normal, axis=1)
        return on_boundary & (sideways > 1e-9 * self.edge_length)

    def vertex_curvatures(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Principal curvatures k1 >= k2 and their directions at every vertex, from its jet there."""
        lifted = self.lift(*self._vertex_feet())
        return principal(lifted.normal, lifted.shape)

    def _vertex_feet(self) -> tuple[np.ndarray, np.ndarray]:
        """One face per vertex, and the vertex itself as the foot (its weight 1 there picks its own jet)."""
        face = np.empty(len(self.vertices), dtype=np.int64)
        face[self.faces.ravel()] = np.repeat(np.arange(len(self.faces)), 3)
        return face, self.vertices.copy()


def fit_jets(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, points: int = MAX_JET_POINTS
             ) -> tuple[np.ndarray, ...]:
    """Per vertex a frame (rows e1, e2, n), cubic jet coefficients in scaled local coordinates, the scale, and the
    RMS fit residual (the mesh's noise, in length units).

    Least squares over the nearest `points` of the smallest ring that holds them on a regular mesh (the two-ring
    for the default 24; one ring more where that has under two thirds of them, e.g. at the boundary), coordinates
    divided by the mean neighbour distance so the normal equations are well conditioned.
    """
    count = len(vertices)
    adjacency = sp.coo_matrix((np.ones(faces.size * 2), (np.r_[faces.ravel(), faces[:, [1, 2, 0]].ravel()],
                                                          np.r_[faces[:, [1, 2, 0]].ravel(), faces.ravel()])),
                              shape=(count, count)).tocsr()
    adjacency = (adjacency + sp.identity(count, format="csr")).astype(bool).astype(np.int32)
    ring = adjacency
    for _ in range(max(2, int(np.ceil(np.sqrt(points / 6.0)))) - 1):  # a regular r-ring holds 3 r (r + 1) + 1 vertices
        ring = (ring @ adjacency).astype(bool).astype(np.int32).tocsr()
    small = np.diff(ring.indptr) < points * MIN_JET_POINTS / MAX_JET_POINTS
    pick = sp.csr_matrix((np.ones(small.sum()), (np.flatnonzero(small), np.arange(small.sum()))), shape=(count, small.sum()))
    rings = (sp.diags((~small).astype(float)) @ ring + pick @ (ring[small] @ adjacency)).astype(bool).tocsr()
    rings.sort_indices()
    sizes = np.diff(rings.indptr)
    width = int(sizes.max())
    index = np.zeros((count, width), dtype=np.int64)
    mask = np.arange(width)[None, :] < sizes[:, None]
    index[mask] = rings.indices
    squared = np.where(mask, np.einsum("vki,vki->vk", vertices[index] - vertices[:, None], vertices[index] - vertices[:, None]), np.inf)
    nearest = np.argsort(squared, axis=1)[:, :points]
    index = np.take_along_axis(index, nearest, axis=1)
    mask = np.take_along_axis(mask, nearest, axis=1)
    sizes = mask.sum(axis=1)
    frames = _frames(normals)
    offsets = vertices[index] - vertices[:, None, :]
    local = np.einsum("vkj,vij->vki", offsets, frames)
    scale = np.sqrt((np.einsum("vki,vki->vk", local[..., :2], local[..., :2]) * mask).sum(axis=1) / np.maximum(sizes - 1, 1))
    scale = np.where(scale > 0, scale, 1.0)
    x, y, z = (local[..., i] / scale[:, None] for i in range(3))
    design = _monomials(x, y) * mask[..., None]
    normal_matrix = np.einsum("vki,vkj->vij", design, design) + 1e-9 * np.eye(JET_TERMS)
    rhs = np.einsum("vki,vk->vi", design, z * mask)
    jets = np.linalg.solve(normal_matrix, rhs[..., None])[..., 0]
    thin = np.flatnonzero(sizes < JET_TERMS)
    if thin.size:
        raise FablineError(f"vertex {thin[0]} at ({xyz_text(vertices[thin[0]])}) has only {sizes[thin[0]] - 1} neighbours "
                           "within three rings: too few to fit the surface there (a loose triangle?)")
    misfit = (np.einsum("vki,vi->vk", design, jets) - z) * mask
    residual = np.sqrt((misfit ** 2).sum(axis=1) / np.maximum(sizes - JET_TERMS, 1)) * scale
    return frames, jets, scale, residual


def jet_at(origin: np.ndarray, frame: np.ndarray, jet: np.ndarray, scale: np.ndarray, points: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A vertex jet evaluated over points: the surface point above each, its unit normal, its second fundamental form (3 x 3)."""
    local = np.einsum("vj,vij->vi", points - origin, frame) / scale[:, None]
    x, y = local[:, 0], local[:, 1]
    c = jet.T
    h = c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * x * y + c[5] * y * y + c[6] * x**3 + c[7] * x * x * y + c[8] * x * y * y + c[9] * y**3
    hx = c[1] + 2 * c[3] * x + c[4] * y + 3 * c[6] * x * x + 2 * c[7] * x * y + c[8] * y * y
    hy = c[2] + c[4] * x + 2 * c[5] * y + c[7] * x * x + 2 * c[8] * x * y + 3 * c[9] * y * y
    hxx = (2 * c[3] + 6 * c[6] * x + 2 * c[7] * y) / scale
    hxy = (c[4] + 2 * c[7] * x + 2 * c[8] * y) / scale
    hyy = (2 * c[5] + 2 * c[8] * x + 6 * c[9] * y) / scale
    point = origin + scale[:, None] * np.einsum("vi,vij->vj", np.stack([x, y, h], axis=-1), frame)
    width = np.sqrt(1 + hx * hx + hy * hy)
    normal = np.einsum("vi,vij->vj", np.stack([-hx, -hy, np.ones_like(hx)], axis=-1) / width[:, None], frame)
    # second fundamental form II = Hess / width on the tangent vectors J a, J = [(1, 0, hx), (0, 1, hy)]
    jac = np.zeros((len(x), 3, 2))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0
    jac[:, 2, 0], jac[:, 2, 1] = hx, hy
    second = np.stack([hxx, hxy, hxy, hyy], axis=-1).reshape(-1, 2, 2) / width[:, None, None]
    local_form = ambient_form(jac, second)
    return point, normal, np.swapaxes(frame, 1, 2) @ local_form @ frame


def ambient_form(jac: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The second fundamental form II (n, 2, 2) of a parametrisation with partials `jac` (n, 3, 2) as a 3 x 3 form.

    J I^-1 II I^-1 J^T with I = J^T J: on a tangent vector J a it gives a^T II a, so forms of different
    parametrisations (vertex jets, NURBS) can be blended and read in any tangent frame.
    """
    first = np.einsum("vki,vkj->vij", jac, jac)
    pseudo = jac @ np.linalg.inv(first)
    return pseudo @ second @ np.swapaxes(pseudo, 1, 2)


def principal(normal: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Principal curvatures k1 >= k2 and unit directions d1, d2 from a tangent second fundamental form."""
    t1, t2 = tangent_basis(normal)
    big_l, big_m, big_n = _form(shape, t1, t2)
    theta = 0.5 * np.arctan2(2 * big_m, big_l - big_n)
    mean, radius = 0.5 * (big_l + big_n), np.hypot(0.5 * (big_l - big_n), big_m)
    d1 = np.cos(theta)[:, None] * t1 + np.sin(theta)[:, None] * t2
    return mean + radius, mean - radius, d1, np.cross(normal, d1)


def tangent_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents t1, t2 = n x t1 at each normal."""
    helper = np.where(np.abs(normal[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normal, t1)


def _form(shape: np.ndarray, t1: np.ndarray, t2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (np.einsum("vi,vij,vj->v", t1, shape, t1), np.einsum("vi,vij,vj->v", t1, shape, t2),
            np.einsum("vi,vij,vj->v", t2, shape, t2))


def _frames(normals: np.ndarray) -> np.ndarray:
    t1, t2 = tangent_basis(normals)
    return np.stack([t1, t2, normals], axis=1)


def _monomials(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    one = np.ones_like(x)
    return np.stack([one, x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3], axis=-1)


def _barycentric(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights of points in (their plane of) triangles, clipped to the triangle and summing to one."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00, d01, d11 = (np.einsum("ij,ij->i", p, q) for p, q in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    denom = d00 * d11 - d01 * d01
    w1 = (d11 * d20 - d01 * d21) / denom
    w2 = (d00 * d21 - d01 * d20) / denom
    weights = np.clip(np.stack([1 - w1 - w2, w1, w2], axis=-1), 0.0, None)
    return weights / weights.sum(axis=1, keepdims=True)


def _boundary_sides(faces: np.ndarray) -> np.ndarray:
    """(F, 3) True where the edge opposite a face's corner belongs to no other face."""
    opposite = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1).reshape(-1, 2)
    key = np.sort(opposite, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return (counts[inverse.ravel()] == 1).reshape(-1, 3)


def xyz_text(point: np.ndarray) -> str:
    """A point for messages: x, y, z to four significant digits."""
    return ", ".join(f"{v:.4g}" for v in point)
