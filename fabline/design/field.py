"""Asymptotic directions where K < 0, in two globally consistent families, and the regions without them.

In a tangent frame where the second fundamental form is diag(k1, k2), k1 > 0 > k2, the asymptotic
directions are cos(mu) d1 +/- sin(mu) d2 with tan^2 mu = -k1 / k2 (domain.md 1.1). The two are told
apart by the sign of their geodesic torsion II(a, n x a), which is the same for a and -a and does not
depend on which way d1 points: with the surface normals oriented consistently (the mesh's winding),
family A (torsion < 0) and family B (torsion > 0) are labelled the same way everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fabline.design.mesh import principal

FLAT_FRACTION = 0.02  # |k| below this fraction of the surface's largest |k|: a near-flat point


def asymptotic_directions(normal: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit asymptotic directions of families A and B (NaN where K >= 0), and the Gaussian curvature K."""
    k1, k2, d1, d2 = principal(normal, shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = np.arctan(np.sqrt(k1 / -k2))
    hyperbolic = (k1 > 0) & (k2 < 0)
    mu = np.where(hyperbolic, mu, np.nan)
    cos, sin = np.cos(mu)[:, None], np.sin(mu)[:, None]
    # II(a, n x a) = (k2 - k1) sin(mu) cos(mu) < 0 for a = cos d1 + sin d2 (family A), > 0 for the other.
    return cos * d1 + sin * d2, cos * d1 - sin * d2, k1 * k2


def geodesic_torsion(normal: np.ndarray, shape: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """II(a, n x a) for unit tangents a: negative on family A, positive on family B."""
    return np.einsum("vi,vij,vj->v", direction, shape, np.cross(normal, direction))


@dataclass
class Region:
    """A connected region of the mesh where the network cannot follow asymptotic lines."""

    kind: str  # "synclastic" (K > 0 beyond the flat threshold) or "flat" (both |k| small: a singularity)
    centre: np.ndarray
    vertices: int
    extent: float
    area: float = 0.0

    def describe(self, units: str = "") -> str:
        unit = f" {units}" if units else ""
        return (f"{self.kind} region of {self.vertices} vertices around ({', '.join(f'{v:.3f}' for v in self.centre)}){unit}, "
                f"{self.extent:.3f}{unit} across, area {self.area:.3g}{unit}2: no asymptotic network there, left out")


def flat_curvature(k1: np.ndarray, k2: np.ndarray) -> float:
    """The curvature both principal curvatures stay under at a flat point: FLAT_FRACTION of the largest |k|."""
    return FLAT_FRACTION * (float(np.max(np.abs(np.r_[k1, k2]))) or 1.0)


def special_regions(vertices: np.ndarray, faces: np.ndarray, k1: np.ndarray, k2: np.ndarray) -> list[Region]:
    """Connected vertex regions where K >= 0 (synclastic or parabolic) or both curvatures are near zero (flat),
    with their area (a third of each face at a member vertex)."""
    flat = np.maximum(np.abs(k1), np.abs(k2)) < flat_curvature(k1, k2)
    synclastic = ~flat & (k1 * k2 >= 0)
    corner = np.linalg.norm(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]), axis=1) / 6
    vertex_area = np.bincount(faces.ravel(), np.repeat(corner, 3), minlength=len(vertices))
    regions = []
    for kind, mask in (("flat", flat), ("synclastic", synclastic)):
        if not mask.any():
            continue
        keep = mask[faces[:, 0]] & mask[faces[:, 1]] | mask[faces[:, 1]] & mask[faces[:, 2]] | mask[faces[:, 0]] & mask[faces[:, 2]]
        edges = np.r_[faces[keep][:, [0, 1]], faces[keep][:, [1, 2]], faces[keep][:, [2, 0]]]
        edges = edges[mask[edges[:, 0]] & mask[edges[:, 1]]]
        graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
        _, label = connected_components(graph, directed=False)
        for lab in np.unique(label[mask]):
            members = np.flatnonzero(mask & (label == lab))
            points = vertices[members]
            regions.append(Region(kind, points.mean(axis=0), len(members), float(np.linalg.norm(np.ptp(points, axis=0))),
                                  float(vertex_area[members].sum())))
    regions.sort(key=lambda r: -r.vertices)
    return regions
