"""Load cases on the erected frame and their combinations with partial factors: self-weight from the material density,
snow on the plan area and wind normal to the shell (uniform, and on one half only), and a person's point load, each
lumped on the joints by tributary area (a plan triangulation of the joints, each triangle's area a third to each corner).

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
    """The job's [analysis] loads: snow and wind (kN/m2), the person (N), partial factors of permanent and variable loads."""

    snow: float = 0.75
    wind: float = 0.5
    person: float = 1000.0
    gamma_g: float = 1.35
    gamma_q: float = 1.5


def tributary(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's plan area (mm2) and area vector (mm2, up-facing surface normal times area), from a Delaunay
    triangulation of the joints in plan without the triangles that bridge a gap (an edge over 2.5 x the median)."""
    triangles = Delaunay(xyz[:, :2]).simplices
    corners = xyz[triangles]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    keep = edges.max(axis=1) <= LONG_EDGE * np.median(edges)
    triangles, corners = triangles[keep], corners[keep]
    vectors = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) / 2.0
    vectors *= np.sign(vectors[:, 2])[:, None]
    plan, area = np.zeros(len(xyz)), np.zeros((len(xyz), 3))
    for k in range(3):
        np.add.at(plan, triangles[:, k], vectors[:, 2] / 3.0)
        np.add.at(area, triangles[:, k], vectors / 3.0)
    return plan, area


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
