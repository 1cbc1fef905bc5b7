"""Irregular triangle meshes of the closed-form minimal surfaces, for tests and benchmarks.

Points scattered at random (with a minimum spacing) over a parameter domain are Delaunay-triangulated
in the parameters and mapped to the surface, so the triangulation follows no curvature line or
asymptotic line, as a designer's mesh would not. Optional noise moves vertices along the normal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh
from scipy.spatial import Delaunay, cKDTree

from fabline.model.designs import AsymptoticSurface, catenoid_surface, enneper_network, enneper_surface, helicoid_surface


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


def rail_grid(surface: AsymptoticSurface, seed: tuple[float, float], spacing: float,
              inside: Callable[[np.ndarray, np.ndarray], np.ndarray], rail_along_a: bool = True,
              reach: float = 10.0, samples: int = 200_001, held: bool = True) -> np.ndarray:
    """Closed-form nodes of the rail layout: (a_k, b_j) at arc lengths k * spacing along the rail through the seed and
    j * spacing along the middle curve of the other family, kept where inside; positions (N, 3).

    The rail is the a-line through the seed (or the b-line with `rail_along_a` False); arc lengths by
    trapezoidal integration of the partials' length on `samples` points over +-`reach` in the parameter.
    `held`: as the design drops curves that carry fewer than two crossings, the grid lines with fewer than two
    nodes go, and with them their nodes, until every line left has two.
    """
    a0, b0 = seed

    def stations(fixed: float, start: float, along_a: bool) -> np.ndarray:
        t = np.linspace(start - reach, start + reach, samples)
        fixed_values = np.full_like(t, fixed)
        a, b = (t, fixed_values) if along_a else (fixed_values, t)
        ok = inside(a, b)
        centre = int(np.argmin(np.abs(t - start)))
        lo, hi = centre, centre
        while lo > 0 and ok[lo - 1]:
            lo -= 1
        while hi < samples - 1 and ok[hi + 1]:
            hi += 1
        xa, xb = surface.partials(a, b)
        speed = np.linalg.norm(xa if along_a else xb, axis=1)
        s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
        s -= np.interp(start, t, s)
        ks = np.arange(np.ceil(s[lo] / spacing), np.floor(s[hi] / spacing) + 1)
        return np.interp(ks * spacing, s, t)

    if rail_along_a:
        a_values, b_values = stations(b0, a0, True), stations(a0, b0, False)
    else:
        b_values, a_values = stations(a0, b0, False), stations(b0, a0, True)
    a, b = np.meshgrid(a_values, b_values, indexing="ij")
    keep = inside(a, b)
    while held:
        short = np.r_[keep.sum(axis=1) < 2][:, None] | np.r_[keep.sum(axis=0) < 2][None, :]
        if not (keep & short).any():
            break
        keep &= ~short
    return surface.point(a[keep], b[keep])


@dataclass
class SampleCase:
    """A closed-form surface patch to mesh and trace on: its domain in asymptotic coordinates and a seed there."""

    surface: AsymptoticSurface
    outline: np.ndarray
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray]
    seed: tuple[float, float]

    def mesh(self, triangles: int, seed: int = 0, noise: float = 0.0) -> trimesh.Trimesh:
        return irregular_mesh(self.surface, self.outline, self.inside, triangles, seed, noise)

    def seed_point(self) -> np.ndarray:
        return self.surface.point(np.array(self.seed[0]), np.array(self.seed[1]))


def closed_form_cases() -> dict[str, SampleCase]:
    """The pavilion's Enneper patch (the built-in design's domain), a catenoid patch (waist 1 m) and a helicoid (pitch 6 m)."""
    network = enneper_network()
    dom = network.meta["domain"]
    half_theta, half_z = 1.2, 1.5  # catenoid patch |theta| <= 1.2, |z| <= 1.5 in a = theta + z, b = theta - z
    diamond = np.array([[half_theta + half_z, half_theta - half_z], [half_theta - half_z, half_theta + half_z],
                        [-half_theta - half_z, -half_theta + half_z], [-half_theta + half_z, -half_theta - half_z]])
    return {
        "enneper": SampleCase(enneper_surface(network.meta["scale_m_per_unit"]), ellipse(dom["u"], dom["v"]),
                              lambda a, b: (a / dom["u"]) ** 2 + (b / dom["v"]) ** 2 <= 1 + 1e-9, (0.0, 0.0)),
        "catenoid": SampleCase(catenoid_surface(1.0), diamond,
                               lambda a, b: (np.abs(a + b) / 2 <= half_theta + 1e-9) & (np.abs(a - b) / 2 <= half_z + 1e-9),
                               (0.3, -0.2)),
        "helicoid": SampleCase(helicoid_surface(6.0), rectangle(-3, 3, 0, np.pi),
                               lambda a, b: (np.abs(a) <= 3 + 1e-9) & (b >= -1e-9) & (b <= np.pi + 1e-9), (0.4, 1.3)),
    }
