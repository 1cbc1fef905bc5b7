"""A NURBS surface from a .3dm file, evaluated exactly: position, partial derivatives, second fundamental form.

rhino3dm gives the control net (homogeneous points), knots and degrees but no derivatives, so the
surface is rebuilt as a tensor-product B-spline of its homogeneous coordinates (scipy's NdBSpline) and
the rational derivatives follow by the quotient rule. Closest points are Newton iterations in (u, v)
from the nearest of a sample grid; the spline polynomials continue past the domain, so the tracer's
last step can land beyond the edge and be trimmed back to it. A sample grid stands in as a mesh for
the regions report, the default seed and the surface's size.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.interpolate import NdBSpline
from scipy.spatial import cKDTree

from fabline.design.mesh import SurfacePoints, ambient_form, principal
from fabline.errors import FablineError

SAMPLES = 121  # sample grid per direction: Newton seeds, regions, size
NEWTON_STEPS = 8


class NurbsPatch:
    """One NURBS surface with the interface the tracer and the layout use (`at`, `project`, `outside`, `closest`)."""

    def __init__(self, surface, source: str):
        nurbs = surface.ToNurbsSurface() if hasattr(surface, "ToNurbsSurface") else surface
        points = nurbs.Points
        control = np.array([[_homogeneous(points.GetControlPoint(i, j)) for j in range(points.CountV)]
                            for i in range(points.CountU)], dtype=float)
        knots = [np.r_[k[0], k, k[-1]] for k in (np.array(nurbs.KnotsU.ToList()), np.array(nurbs.KnotsV.ToList()))]
        degrees = (nurbs.Degree(0), nurbs.Degree(1))
        if not np.isfinite(control).all() or np.any(control[..., 3] <= 0):
            raise FablineError(f"{source}: the NURBS surface has non-finite control points or weights <= 0")
        self.spline = NdBSpline(tuple(knots), control, degrees, extrapolate=True)
        self.domain = np.array([[nurbs.Domain(0).T0, nurbs.Domain(0).T1], [nurbs.Domain(1).T0, nurbs.Domain(1).T1]])
        u, v = (np.linspace(lo, hi, SAMPLES) for lo, hi in self.domain)
        grid = np.stack(np.meshgrid(u, v, indexing="ij"), axis=-1).reshape(-1, 2)
        self.sample_uv = grid
        self.vertices = self._point(grid)
        index = np.arange(SAMPLES * SAMPLES).reshape(SAMPLES, SAMPLES)
        a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
        self.faces = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
        self.mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        self.edge_length = float(self.mesh.edges_unique_length.mean())
        self.tree = cKDTree(self.vertices)
        self.scale = float(np.linalg.norm(np.ptp(self.vertices, axis=0)))

    def _derivatives(self, uv: np.ndarray) -> tuple[np.ndarray, ...]:
        """Point, S_u, S_v, S_uu, S_uv, S_vv at parameters uv (n, 2), by the quotient rule on homogeneous splines."""
        h = {nu: self.spline(uv, nu=nu) for nu in ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))}
        w = {nu: value[:, 3:] for nu, value in h.items()}
        a = {nu: value[:, :3] for nu, value in h.items()}
        s = a[0, 0] / w[0, 0]
        su = (a[1, 0] - w[1, 0] * s) / w[0, 0]
        sv = (a[0, 1] - w[0, 1] * s) / w[0, 0]
        suu = (a[2, 0] - 2 * w[1, 0] * su - w[2, 0] * s) / w[0, 0]
        suv = (a[1, 1] - w[1, 0] * sv - w[0, 1] * su - w[1, 1] * s) / w[0, 0]
        svv = (a[0, 2] - 2 * w[0, 1] * sv - w[0, 2] * s) / w[0, 0]
        return s, su, sv, suu, suv, svv

    def _point(self, uv: np.ndarray) -> np.ndarray:
        value = self.spline(uv)
        return value[:, :3] / value[:, 3:]

    def evaluate(self, uv: np.ndarray) -> SurfacePoints:
        """Exact position, unit normal (S_u x S_v) and second fundamental form at parameters uv."""
        s, su, sv, suu, suv, svv = self._derivatives(uv)
        normal = np.cross(su, sv)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        second = np.stack([np.einsum("ij,ij->i", d, normal) for d in (suu, suv, suv, svv)], axis=-1).reshape(-1, 2, 2)
        return SurfacePoints(s, normal, ambient_form(np.stack([su, sv], axis=-1), second), np.zeros(len(uv), int), uv)

    def parameters(self, points: np.ndarray) -> np.ndarray:
        """(u, v) of each point's foot on the surface (or its continuation), by Newton steps from the nearest sample."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        uv = self.sample_uv[self.tree.query(points)[1]].copy()
        span = self.domain[:, 1] - self.domain[:, 0]
        for _ in range(NEWTON_STEPS):
            s, su, sv, suu, suv, svv = self._derivatives(uv)
            r = s - points
            gradient = np.stack([np.einsum("ij,ij->i", su, r), np.einsum("ij,ij->i", sv, r)], axis=1)
            hessian = np.stack([np.einsum("ij,ij->i", su, su) + np.einsum("ij,ij->i", suu, r),
                                np.einsum("ij,ij->i", su, sv) + np.einsum("ij,ij->i", suv, r),
                                np.einsum("ij,ij->i", su, sv) + np.einsum("ij,ij->i", suv, r),
                                np.einsum("ij,ij->i", sv, sv) + np.einsum("ij,ij->i", svv, r)], axis=-1).reshape(-1, 2, 2)
            step = np.linalg.solve(hessian, gradient[..., None])[..., 0]
            uv = uv - np.clip(step, -0.25 * span, 0.25 * span)
        return uv

    def at(self, points: np.ndarray) -> SurfacePoints:
        return self.evaluate(self.parameters(points))

    def project(self, points: np.ndarray) -> SurfacePoints:
        return self.at(points)

    def outside(self, points: np.ndarray) -> np.ndarray:
        """True where a point's foot lies beyond the parameter domain."""
        uv = self.parameters(points)
        slack = 1e-12 * (self.domain[:, 1] - self.domain[:, 0])
        return np.any((uv < self.domain[:, 0] - slack) | (uv > self.domain[:, 1] + slack), axis=1)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Face (none: zeros), closest point within the domain, and squared distance."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        uv = np.clip(self.parameters(points), self.domain[:, 0], self.domain[:, 1])
        foot = self._point(uv)
        return np.zeros(len(points), int), foot, np.einsum("ij,ij->i", foot - points, foot - points)

    def vertex_curvatures(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Principal curvatures and directions at the sample grid."""
        lifted = self.evaluate(self.sample_uv)
        return principal(lifted.normal, lifted.shape)


def _homogeneous(point) -> tuple[float, float, float, float]:
    return point.X, point.Y, point.Z, point.W


def read_nurbs(path: str) -> tuple[NurbsPatch | None, str | None]:
    """The one NURBS surface (a surface object or a one-face brep's surface) of a .3dm file and its units, if it
    holds exactly one and no mesh; else (None, units): the caller meshes the file instead."""
    from fabline.model.importers.rhino import _declared_units, _read_model, _rhino3dm

    rhino3dm = _rhino3dm()
    model = _read_model(rhino3dm, path)
    units = _declared_units(rhino3dm, model, path)
    surfaces, others = [], 0
    for item in model.Objects:
        geometry = item.Geometry
        if isinstance(geometry, rhino3dm.Surface):
            surfaces.append(geometry)
        elif isinstance(geometry, rhino3dm.Brep) and len(geometry.Faces) == 1:
            surfaces.append(geometry.Faces[0].UnderlyingSurface())
        elif isinstance(geometry, (rhino3dm.Mesh, rhino3dm.Brep)):
            others += 1
    if len(surfaces) != 1 or others:
        return None, units
    return NurbsPatch(surfaces[0], path), units
