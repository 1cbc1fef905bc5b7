"""Linear buckling as one eigenproblem: the smallest load factor at which the stiffness of a prestressed frame,
K_E + K_G(base) + factor K_G(load), turns singular, with its mode. Solved as the largest eigenvalue 1/factor of
the pencil (-K_G(load), K0) (scipy's ARPACK, symmetric, on one sparse LU of K0 = K_E + K_G(base)), where a search of nonlinear solves
took minutes on the pavilion. The axial forces come from a solved case (OpenSees)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as sla

from fabline.analysis.frame import Frame
from fabline.analysis.stiffness import elastic, free_dofs, geometric
from fabline.errors import FablineError

MODES = 4            # eigenvalues asked of ARPACK: the pairs of strips buckle in pairs of nearly equal modes
NO_BUCKLING = 1e-9   # 1/factor below this share of the largest diagonal ratio K_G/K0: round-off, no buckling


@dataclass
class Buckling:
    """The buckling factor (inf: no positive one, the load only stiffens the frame) and its mode (N, 6), scaled to a
    largest translation of 1."""

    factor: float
    mode: np.ndarray

    def peak(self) -> int:
        """The node index where the mode moves most."""
        return int(np.argmax(np.linalg.norm(self.mode[:, :3], axis=1)))


def buckling(frame: Frame, load_axial: np.ndarray, base_axial: np.ndarray | None = None,
             cable_taut: np.ndarray | None = None) -> Buckling:
    """The factor on the beams' axial forces `load_axial` (E,) at which the frame, prestressed by `base_axial` (none:
    unstressed) and with the cables `cable_taut` bracing it, buckles. The base state must itself be stable."""
    free = free_dofs(frame)
    k0 = elastic(frame, cable_taut)
    if base_axial is not None:
        k0 = k0 + geometric(frame, base_axial)
    k0 = k0[free][:, free].tocsc()
    kg = geometric(frame, load_axial)[free][:, free].tocsr()
    try:
        lu = sla.splu(k0)
    except RuntimeError:
        raise FablineError("analysis: the frame's stiffness is singular: a mechanism (check the supports and "
                           "joints)") from None
    inverse = sla.LinearOperator(k0.shape, matvec=lu.solve, dtype=float)
    try:
        values, vectors = sla.eigsh(-kg, k=min(MODES, len(free) - 1), M=k0, Minv=inverse, which="LA")
    except sla.ArpackNoConvergence as partial:
        values, vectors = partial.eigenvalues, partial.eigenvectors
    mode = np.zeros(6 * len(frame.xyz))
    scale = np.abs(kg.diagonal() / k0.diagonal()).max()
    if not len(values) or not values.max() > NO_BUCKLING * scale:
        return Buckling(np.inf, mode.reshape(-1, 6))
    best = int(np.argmax(values))
    mode[free] = vectors[:, best]
    mode = mode.reshape(-1, 6)
    return Buckling(1.0 / float(values.real[best]), mode / np.linalg.norm(mode[:, :3], axis=1).max())
