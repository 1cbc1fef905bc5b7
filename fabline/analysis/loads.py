"""Load cases on the erected frame and their combinations with partial factors: self-weight from the material density,
snow on the plan area and wind normal to the shell (uniform, and on one half only), and a person's point load, each
lumped on the joints by tributary area (a plan triangulation of the joints, shared by mixed Voronoi areas).

Area loads in kN/m2 (1 kN/m2 = 1e-3 N/mm2); forces in N on the frame's nodes (N, 6). z is up (the supports lie low).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from fabline.analysis.frame import Frame

GRAVITY = 9.81              # m/s2: a kg weighs 9.81 N
KN_PER_M2 = 1e-3            # N/mm2
LONG_EDGE = 2.5             # a plan triangle with an edge longer than this many median edges spans a gap, not the shell


@dataclass(frozen=True)
class LoadSettings:
    """The load cases' figures (`fabline analyse` options): snow and wind (kN/m2), the person (N), partial factors."""

    snow: float = 0.75
    wind: float = 0.5
    person: float = 1000.0
    gamma_g: float = 1.35
    gamma_q: float = 1.5


def tributary(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's plan area (mm2) and area vector (mm2, up-facing surface normal times area), from a Delaunay
    triangulation of the joints in plan without the triangles that bridge a gap (an edge over 2.5 x the median), each
    triangle shared by its mixed Voronoi areas (Meyer et al. 2003: the circumcentric cells, or a half to an obtuse
    corner and quarters to the others), so that a square grid's node gets its whole cell whichever diagonal it got."""
    triangles = Delaunay(xyz[:, :2]).simplices
    corners = xyz[triangles]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    keep = edges.max(axis=1) <= LONG_EDGE * np.median(edges)
    triangles, corners = triangles[keep], corners[keep]
    vectors = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) / 2.0
    vectors *= np.sign(vectors[:, 2])[:, None]
    shares = _voronoi_shares(corners[:, :, :2])
    plan, area = np.zeros(len(xyz)), np.zeros((len(xyz), 3))
    for k in range(3):
        np.add.at(plan, triangles[:, k], shares[:, k] * vectors[:, 2])
        np.add.at(area, triangles[:, k], shares[:, k, None] * vectors)
    return plan, area


def _voronoi_shares(corners: np.ndarray) -> np.ndarray:
    """Each corner's fraction (T, 3) of its triangle's area: its circumcentric Voronoi part, (|ab|^2 cot C + |ac|^2
    cot B) / 8 over the area, where no angle is obtuse; else a half to the obtuse corner and a quarter to each other."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    u, v = b - a, c - a
    double = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])

    def cot(p, q, r):  # at p, between q and r
        u, v = q - p, r - p
        return np.einsum("ij,ij->i", u, v) / double

    def sq(p, q):
        return np.einsum("ij,ij->i", p - q, p - q)

    cots = np.column_stack([cot(a, b, c), cot(b, c, a), cot(c, a, b)])
    voronoi = np.column_stack([sq(a, b) * cots[:, 2] + sq(a, c) * cots[:, 1], sq(b, c) * cots[:, 0] + sq(b, a) * cots[:, 2],
                               sq(c, a) * cots[:, 1] + sq(c, b) * cots[:, 0]]) / 8.0 / (double / 2.0)[:, None]
    obtuse = cots < 0.0
    mixed = np.where(obtuse, 0.5, 0.25)
    return np.where(obtuse.any(axis=1)[:, None], mixed, voronoi)


def basic_cases(frame: Frame, joints: np.ndarray, settings: LoadSettings) -> dict[str, np.ndarray]:
    """Unfactored load cases (N, 6): self-weight G, snow S (all, and the half x < median, one-sided), wind W pressing
    on the shell along its downward normal (all, one-sided). `joints` are the frame nodes the area loads act on."""
    n = len(frame.xyz)
    plan, area = tributary(frame.xyz[joints])
    weight = np.zeros((n, 6))
    weight[:, 2] = -frame.mass_per_node() * GRAVITY
    half = frame.xyz[joints, 0] < np.median(frame.xyz[joints, 0])
    cases = {"G": weight}
    for name, forces in (("S", np.column_stack([0 * plan, 0 * plan, -settings.snow * KN_PER_M2 * plan])),
                         ("W", -settings.wind * KN_PER_M2 * area)):
        for suffix, on in (("", np.ones(len(joints), dtype=bool)), (" one-sided", half)):
            loads = np.zeros((n, 6))
            loads[joints[on], :3] = forces[on]
            cases[name + suffix] = loads
    return cases


def person(frame: Frame, node: int, settings: LoadSettings) -> np.ndarray:
    """A person standing on a joint: `settings.person` N downward."""
    loads = np.zeros((len(frame.xyz), 6))
    loads[node, 2] = -settings.person
    return loads


def combinations(cases: dict[str, np.ndarray], settings: LoadSettings) -> dict[str, np.ndarray]:
    """The design combinations: 1.35 G alone and with 1.5 times each variable case (the residual stress of the
    erection is on top of every one, unfactored: it is locked in, not a load)."""
    g = settings.gamma_g * cases["G"]
    combined = {f"{settings.gamma_g:g} G": g}
    for name, loads in cases.items():
        if name != "G":
            combined[f"{settings.gamma_g:g} G + {settings.gamma_q:g} {name}"] = g + settings.gamma_q * loads
    return combined
