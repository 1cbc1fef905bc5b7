"""Irregular triangle meshes of the closed-form minimal surfaces, for tests and benchmarks.

Points scattered at random (with a minimum spacing) over a parameter domain are Delaunay-triangulated
in the parameters and mapped to the surface, so the triangulation follows no curvature line or
asymptotic line, as a designer's mesh would not. Optional noise moves vertices along the normal.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import trimesh
from scipy.spatial import Delaunay, cKDTree

from fabline.model.designs import AsymptoticSurface


def irregular_mesh(surface: AsymptoticSurface, boundary: np.ndarray, inside: Callable[[np.ndarray, np.ndarray], np.ndarray],
                   triangles: int, seed: int = 0, noise: float = 0.0) -> trimesh.Trimesh:
    """About `triangles` irregular triangles over the (a, b) domain bounded by the closed polygon `boundary` (M, 2).

    The vertices' parameters are kept in `mesh.metadata["params"]`, for comparison with the closed form.
    Interior points are a jittered grid (each moved up to 0.45 cells at random), boundary points are
    evenly spaced along the polygon; `noise` is the standard deviation (model units) of a normal offset.
    """
    rng = np.random.default_rng(seed)
    lo, hi = boundary.min(axis=0), boundary.max(axis=0)
    edge = np.linalg.norm(np.diff(np.vstack([boundary, boundary[:1]]), axis=0), axis=1)
    area = 0.5 * abs(np.dot(boundary[:, 0], np.roll(boundary[:, 1], -1)) - np.dot(boundary[:, 1], np.roll(boundary[:, 0], -1)))
    cell = np.sqrt(2.0 * area / triangles)
    ga, gb = np.meshgrid(np.arange(lo[0], hi[0], cell), np.arange(lo[1], hi[1], cell), indexing="ij")
    grid = np.c_[ga.ravel(), gb.ravel()] + rng.uniform(-0.45, 0.45, (ga.size, 2)) * cell
    rim = _resample_closed(boundary, edge, cell)
    keep = inside(grid[:, 0], grid[:, 1]) & (cKDTree(rim).query(grid)[0] > 0.5 * cell)
    params = np.vstack([rim, grid[keep]])
    faces = Delaunay(params).simplices
    centroid = params[faces].mean(axis=1)
    faces = faces[inside(centroid[:, 0], centroid[:, 1])]
    used = np.unique(faces)
    params, faces = params[used], np.searchsorted(used, faces)
    vertices = surface.point(params[:, 0], params[:, 1])
    if noise:
        vertices = vertices + rng.normal(0.0, noise, len(params))[:, None] * surface.normal(params[:, 0], params[:, 1])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.metadata["params"] = params
    return mesh


def _resample_closed(polygon: np.ndarray, edge: np.ndarray, step: float) -> np.ndarray:
    """Points every `step` (about) along a closed polygon."""
    s = np.concatenate([[0.0], np.cumsum(edge)])
    count = max(8, int(np.ceil(s[-1] / step)))
    t = np.linspace(0.0, s[-1], count, endpoint=False)
    closed = np.vstack([polygon, polygon[:1]])
    return np.c_[np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])]


def ellipse(half_a: float, half_b: float, count: int = 400) -> np.ndarray:
    """A closed polygon on the ellipse with these half-axes."""
    t = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    return np.c_[half_a * np.cos(t), half_b * np.sin(t)]


def rectangle(a0: float, a1: float, b0: float, b1: float) -> np.ndarray:
    """A closed polygon on the rectangle [a0, a1] x [b0, b1]."""
    return np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]], dtype=float)
