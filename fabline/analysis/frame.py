"""The frame model as plain arrays: nodes, beam elements with their section axes and initial strains, rigid links
(a pair's strips at a joint), scissor hinges (the bolt: every DOF tied but the rotation about the normal), tension-only
cables and supports. OpenSees never appears here: `fabline.analysis.solve` turns a Frame into its model.

Units: mm, N, N/mm2. A beam's local x runs from its first node to its second, its local z is the surface normal
(the strip's height: the strong axis, bending about the sideways local y), local y = z x x = the sideways u.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fabline.mechanics.materials import Material, Profile

FIXED = (1, 1, 1, 1, 1, 1)
PINNED = (1, 1, 1, 0, 0, 0)
SUPPORT_KINDS = {"fixed": FIXED, "pinned": PINNED}


@dataclass(frozen=True)
class Section:
    """A rectangular strip h (along the normal) x t (sideways) in a material: its area, the inertia about the sideways
    axis (strong, t h^3/12) and about the normal (weak, h t^3/12), and the thin strip's St Venant constant h t^3/3
    (thesis 6.4's tau = G t tau_g is T t / J with this J)."""

    E: float
    G: float
    h: float
    t: float
    density: float = 0.0  # kg/m3

    @classmethod
    def of(cls, material: Material, profile: Profile) -> "Section":
        return cls(material.E, material.G, profile.h, profile.t, material.density)

    @property
    def A(self) -> float:
        return self.h * self.t

    @property
    def I_strong(self) -> float:
        return self.t * self.h ** 3 / 12.0

    @property
    def I_weak(self) -> float:
        return self.h * self.t ** 3 / 12.0

    @property
    def J(self) -> float:
        return self.h * self.t ** 3 / 3.0

    @property
    def rigidities(self) -> np.ndarray:
        """Local (GJ, E I_y, E I_z): torsion, strong-axis and weak-axis bending, N mm2."""
        return np.array([self.G * self.J, self.E * self.I_strong, self.E * self.I_weak])


@dataclass
class Frame:
    """A 3D frame: N nodes (xyz, names), E beams (node pairs, local z, initial strains (twist, curvature about y,
    curvature about z) in 1/mm that the erection imposed, and a tag naming strip and interval), links, hinges, cables,
    supports."""

    xyz: np.ndarray
    names: list[str]
    beams: np.ndarray
    beam_z: np.ndarray
    section: Section
    strains: np.ndarray | None = None
    beam_tags: list[tuple[str, int]] = field(default_factory=list)
    links: list[tuple[int, int]] = field(default_factory=list)                 # (master, slave): rigid beam link
    hinges: list[tuple[int, int, np.ndarray]] = field(default_factory=list)    # (a, b, axis): rotation about axis free
    cables: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))
    cable_area: float = 0.0
    cable_E: float = 0.0
    cable_prestrain: float = 0.0
    supports: dict[int, tuple[int, ...]] = field(default_factory=dict)

    def __post_init__(self):
        if self.strains is None:
            self.strains = np.zeros((len(self.beams), 3))

    @property
    def lengths(self) -> np.ndarray:
        return np.linalg.norm(self.xyz[self.beams[:, 1]] - self.xyz[self.beams[:, 0]], axis=1)

    def axes(self) -> np.ndarray:
        """Each beam's local axes as rows x, y, z (E, 3, 3), z the given normal made square to x."""
        x = self.xyz[self.beams[:, 1]] - self.xyz[self.beams[:, 0]]
        x /= np.linalg.norm(x, axis=1)[:, None]
        z = self.beam_z - np.einsum("ij,ij->i", self.beam_z, x)[:, None] * x
        z /= np.linalg.norm(z, axis=1)[:, None]
        return np.stack([x, np.cross(z, x), z], axis=1)

    def rigid_motions(self) -> int:
        """How many rigid-body motions (of 6: 3 slides, 3 turns) the supports leave free: the rank the support flags'
        constraints on u = a + theta x (x - centre) fall short of. Two pinned supports leave the turn about the line
        through them."""
        centre = self.xyz.mean(axis=0)
        scale = max(float(np.abs(self.xyz - centre).max()), 1e-9)
        rows = []
        for node, flags in self.supports.items():
            x, y, z = (self.xyz[node] - centre) / scale
            held = np.array([[1, 0, 0, 0, z, -y], [0, 1, 0, -z, 0, x], [0, 0, 1, y, -x, 0],
                             [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]], dtype=float)
            rows.append(held[np.asarray(flags, dtype=bool)])
        if not rows:
            return 6
        return 6 - int(np.linalg.matrix_rank(np.vstack(rows), tol=1e-9))

    def mass_per_node(self) -> np.ndarray:
        """Each node's share (kg) of its beams' steel: half of every beam at each end (self-weight, lumped)."""
        kg = self.section.A * self.lengths * self.section.density * 1e-9
        share = np.zeros(len(self.xyz))
        np.add.at(share, self.beams[:, 0], kg / 2.0)
        np.add.at(share, self.beams[:, 1], kg / 2.0)
        return share


def chain(points: np.ndarray, normals: np.ndarray, section: Section, name: str = "S") -> Frame:
    """One strip as a chain of beams through `points` (M, 3), its height along `normals` (M, 3): the builder of the
    closed-form tests and the unit of the gridshell model."""
    points = np.asarray(points, dtype=float)
    beams = np.column_stack([np.arange(len(points) - 1), np.arange(1, len(points))])
    mid_normals = (np.asarray(normals, dtype=float)[1:] + np.asarray(normals, dtype=float)[:-1]) / 2.0
    return Frame(points, [f"{name}:{k}" for k in range(len(points))], beams, mid_normals, section,
                 beam_tags=[(name, k) for k in range(len(beams))])
