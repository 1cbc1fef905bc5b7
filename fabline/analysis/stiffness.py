"""The Frame's stiffness as sparse matrices (scipy), for the linear buckling eigenproblem OpenSees does not offer: the
elastic stiffness of the elements `fabline.analysis.solve` builds on OpenSees (elastic beams, washer links as stiff beams,
zero-length scissor hinges, the cables in tension), and the beams' geometric stiffness from their axial forces (the
consistent 3D beam matrix). Checked against OpenSees's own assembled matrix in the tests.

Global DOFs: 6 per node (ux, uy, uz, rx, ry, rz), node k at 6 k; a beam's local DOFs u v w rx ry rz at each end."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sparse

from fabline.analysis.frame import Frame

HINGE_STIFFNESS = (1e8, 1e13)   # N/mm and N mm/rad of a bolt's tied DOFs: 1e3 to 1e5 times a strip's own
LINK_STIFFNESS = 1e3            # a washer link's moduli over the strip's (with the strip's strong-axis inertia)


def beam_elastic(length: np.ndarray, A: float, E, G, J: float, I_y: float, I_z: float) -> np.ndarray:
    """Each beam's local elastic stiffness (E, 12, 12): axial EA/L, torsion GJ/L, bending about local z (v, rz) with
    I_z and about local y (w, ry) with I_y. E and G may be arrays (one per beam)."""
    L = np.asarray(length, dtype=float)
    E = np.broadcast_to(np.asarray(E, dtype=float), L.shape)
    G = np.broadcast_to(np.asarray(G, dtype=float), L.shape)
    k = np.zeros((len(L), 12, 12))
    _pair(k, (0, 6), E * A / L)
    _pair(k, (3, 9), G * J / L)
    _bending(k, (1, 5, 7, 11), E * I_z / L ** 3 * np.stack([np.full_like(L, 12.0), 6 * L, 4 * L ** 2, 2 * L ** 2]), +1)
    _bending(k, (2, 4, 8, 10), E * I_y / L ** 3 * np.stack([np.full_like(L, 12.0), 6 * L, 4 * L ** 2, 2 * L ** 2]), -1)
    return k


def beam_geometric(length: np.ndarray, axial: np.ndarray, A: float, polar: float) -> np.ndarray:
    """Each beam's local geometric stiffness (E, 12, 12) under its axial force N (tension positive): the consistent
    matrix N/(30 L) (36, 3L, 4L^2, -L^2) in both bending planes and N I_p/(A L) on the twist."""
    L = np.asarray(length, dtype=float)
    N = np.asarray(axial, dtype=float)
    k = np.zeros((len(L), 12, 12))
    _pair(k, (3, 9), N * polar / (A * L))
    terms = N / (30.0 * L) * np.stack([np.full_like(L, 36.0), 3 * L, 4 * L ** 2, -L ** 2])
    _bending(k, (1, 5, 7, 11), terms, +1)
    _bending(k, (2, 4, 8, 10), terms, -1)
    return k


def _pair(k: np.ndarray, dofs: tuple[int, int], value: np.ndarray) -> None:
    """A two-DOF spring value * [[1, -1], [-1, 1]] into every beam's matrix."""
    i, j = dofs
    k[:, i, i] += value
    k[:, j, j] += value
    k[:, i, j] -= value
    k[:, j, i] -= value


def _bending(k: np.ndarray, dofs: tuple[int, int, int, int], terms: np.ndarray, sign: int) -> None:
    """One bending plane's 4 x 4 block (displacement, rotation at each end) from its terms (a, b, c, d): stiffness
    [[a, sb, -a, sb], [sb, c, -sb, d], [-a, -sb, a, -sb], [sb, d, -sb, c]], s = +1 for (v, rz), -1 for (w, ry)."""
    a, b, c, d = terms
    b = sign * b
    block = np.stack([np.stack([a, b, -a, b]), np.stack([b, c, -b, d]),
                      np.stack([-a, -b, a, -b]), np.stack([b, d, -b, c])]).transpose(2, 0, 1)
    index = np.array(dofs)
    k[:, index[:, None], index[None, :]] += block


def _to_global(local: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Local 12 x 12 matrices in global axes: T^T k T, T four copies of each element's rows-are-axes rotation."""
    T = np.zeros((len(axes), 12, 12))
    for block in range(4):
        T[:, 3 * block:3 * block + 3, 3 * block:3 * block + 3] = axes
    return np.einsum("eji,ejk,ekl->eil", T, local, T)


def _assemble(n_nodes: int, ends: np.ndarray, matrices: np.ndarray) -> sparse.csr_matrix:
    """Sum two-node element matrices (E, 12, 12) on nodes `ends` (E, 2) into the global sparse matrix."""
    dofs = (6 * ends[:, :, None] + np.arange(6)[None, None, :]).reshape(len(ends), 12)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    return sparse.coo_matrix((matrices.ravel(), (rows, cols)), shape=(6 * n_nodes, 6 * n_nodes)).tocsr()


def _any_axes(direction: np.ndarray) -> np.ndarray:
    """Orthonormal axes (E, 3, 3), rows x (along `direction`), y, z: for members whose bending is the same about any
    axis (the washer links)."""
    x = direction / np.linalg.norm(direction, axis=1)[:, None]
    helper = np.where(np.abs(x[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    z = np.cross(x, helper)
    z /= np.linalg.norm(z, axis=1)[:, None]
    return np.stack([x, np.cross(z, x), z], axis=1)


def elastic(frame: Frame, cable_taut: np.ndarray | None = None) -> sparse.csr_matrix:
    """The frame's elastic stiffness (6 N x 6 N, every DOF, supports not removed): its beams, washer links, hinges and
    the cables marked taut (a slack tension-only cable has none)."""
    n = len(frame.xyz)
    sec = frame.section
    total = _assemble(n, frame.beams, _to_global(
        beam_elastic(frame.lengths, sec.A, sec.E, sec.G, sec.J, sec.I_strong, sec.I_weak), frame.axes()))
    if frame.links:
        ends = np.array(frame.links, dtype=int)
        direction = frame.xyz[ends[:, 1]] - frame.xyz[ends[:, 0]]
        local = beam_elastic(np.linalg.norm(direction, axis=1), sec.A, LINK_STIFFNESS * sec.E, LINK_STIFFNESS * sec.G,
                             sec.I_strong, sec.I_strong, sec.I_strong)
        total = total + _assemble(n, ends, _to_global(local, _any_axes(direction)))
    if frame.hinges:
        ends = np.array([(a, b) for a, b, _ in frame.hinges], dtype=int)
        axis = np.array([h[2] for h in frame.hinges], dtype=float)
        axis /= np.linalg.norm(axis, axis=1)[:, None]
        block = np.zeros((len(ends), 6, 6))
        block[:, :3, :3] = HINGE_STIFFNESS[0] * np.eye(3)
        block[:, 3:, 3:] = HINGE_STIFFNESS[1] * (np.eye(3) - axis[:, :, None] * axis[:, None, :])
        total = total + _assemble(n, ends, np.block([[block, -block], [-block, block]]))
    if len(frame.cables) and cable_taut is not None and cable_taut.any():
        ends = frame.cables[cable_taut]
        direction = frame.xyz[ends[:, 1]] - frame.xyz[ends[:, 0]]
        length = np.linalg.norm(direction, axis=1)
        x = direction / length[:, None]
        block = np.zeros((len(ends), 6, 6))
        block[:, :3, :3] = (frame.cable_E * frame.cable_area / length)[:, None, None] * x[:, :, None] * x[:, None, :]
        total = total + _assemble(n, ends, np.block([[block, -block], [-block, block]]))
    return total


def geometric(frame: Frame, axial: np.ndarray) -> sparse.csr_matrix:
    """The beams' geometric stiffness (6 N x 6 N) under axial forces `axial` (E,), N, tension positive. The washer links
    and cables carry none, as on OpenSees (linear links, small-displacement trusses)."""
    sec = frame.section
    local = beam_geometric(frame.lengths, axial, sec.A, sec.I_strong + sec.I_weak)
    return _assemble(len(frame.xyz), frame.beams, _to_global(local, frame.axes()))


def free_dofs(frame: Frame) -> np.ndarray:
    """The global DOFs the supports leave free, in order."""
    fixed = np.zeros(6 * len(frame.xyz), dtype=bool)
    for node, flags in frame.supports.items():
        fixed[6 * node:6 * node + 6] = np.asarray(flags, dtype=bool)
    return np.flatnonzero(~fixed)
