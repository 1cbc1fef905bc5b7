"""The erection's residual stress by the thesis's strain-load approach: the frame is built in the erected shape, stress
free there, and each beam carries an initial strain (twist, curvature about y and z) equal to minus its design
curvature, the flat straight strip it was cut as. The initial strain acts as equivalent nodal loads (its fixed-end
moments, reversed) and each beam's force is what the solution gives plus the fixed-end force: a strip held in its
erected shape carries E I k_g, E I k_n and G J tau_g exactly, and wherever the joints let it spring back a little,
less (the initial strain method of linear frame analysis, applied on the corotational frame)."""

from __future__ import annotations

import numpy as np

from fabline.analysis.frame import Frame


def strain_moments(frame: Frame) -> np.ndarray:
    """Each beam's locked-in moment vector in its local axes (E, 3): (G J tau, E I_y kappa_y, E I_z kappa_z), N mm."""
    return frame.strains * frame.section.rigidities[None, :]


def strain_loads(frame: Frame) -> np.ndarray:
    """The equivalent nodal loads (N, 6) of every beam's initial strain: a beam locked to its design curvature pushes its
    first node by +m and its second by -m (m its locked-in moment vector, in global axes); no forces, since the
    moment is uniform along the beam. Self-equilibrated: they sum to zero."""
    moments = np.einsum("eij,ei->ej", frame.axes(), strain_moments(frame))
    loads = np.zeros((len(frame.xyz), 6))
    np.add.at(loads[:, 3:], frame.beams[:, 0], moments)
    np.add.at(loads[:, 3:], frame.beams[:, 1], -moments)
    return loads


def fixed_end_forces(frame: Frame) -> np.ndarray:
    """Each beam's locked-in forces in OpenSees's basic order (N, Mz_i, Mz_j, My_i, My_j, T): uniform bending has end
    moments -M and +M in that system, uniform twist the torque G J tau."""
    m = strain_moments(frame)
    zero = np.zeros(len(m))
    return np.column_stack([zero, -m[:, 2], m[:, 2], -m[:, 1], m[:, 1], m[:, 0]])
