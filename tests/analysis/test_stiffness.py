"""The buckling eigenproblem's matrices and factor against independent truth: the elastic stiffness against OpenSees's
own assembled matrix of the same frame (its printA), the factor against Euler's column (the two-hinged arch's closed
form is in test_closed_forms), and a column's factor against the sway OpenSees's nonlinear frame shows on the way."""

import numpy as np
import pytest

from fabline.analysis.buckling import buckling
from fabline.analysis.frame import FIXED, PINNED, Frame, Section, chain
from fabline.analysis.solve import Model, opensees
from fabline.analysis.stiffness import elastic, free_dofs

SECTION = Section(E=210000.0, G=81000.0, h=100.0, t=1.5, density=7850.0)


def small_frame() -> Frame:
    """Every kind of member the gridshell frame has: two strips crossing (an x strip with its normal along z, a y strip
    tilted), a scissor hinge where they cross, a washer link to a parallel strip's node, a cable, a fixed and a pinned
    support, and nodes off the axes so that no matrix term hides in a zero."""
    xyz = np.array([[0, 0, 0], [300, 10, 5], [620, 15, 30], [900, 0, 40],          # strip A
                    [300, 10, 5], [310, 330, 40], [305, -300, 20],                # strip B through the crossing
                    [620, 27.5, 30], [900, 12.5, 50]], dtype=float)               # a parallel strip's stretch, linked
    beams = np.array([[0, 1], [1, 2], [2, 3], [6, 4], [4, 5], [7, 8]])
    normals = np.array([[0, 0.1, 1], [0, 0, 1], [0.1, 0, 1], [0.3, 0, 1], [0.2, 0.1, 1], [0.1, 0, 1]], dtype=float)
    frame = Frame(xyz, [f"n{k}" for k in range(len(xyz))], beams, normals, SECTION,
                  links=[(2, 7)], hinges=[(1, 4, np.array([0.05, 0.0, 1.0]))],
                  cables=np.array([[3, 5]]), cable_area=22.6, cable_E=120000.0, cable_prestrain=0.0,
                  supports={0: FIXED, 6: PINNED})
    return frame


def opensees_matrix(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """OpenSees's assembled tangent of the unloaded frame (its FullGeneral system's printA) and, for each of its
    equations, our global DOF."""
    Model(frame)
    ops = opensees()
    ops.constraints("Plain")
    ops.numberer("Plain")
    ops.system("FullGeneral")
    ops.test("NormDispIncr", 1e-10, 10)
    ops.algorithm("Linear")   # the tangent formed once, at the unloaded start (a pretensioned cable then moves it)
    ops.integrator("LoadControl", 0.0)
    ops.analysis("Static")
    assert ops.analyze(1) == 0
    size = ops.systemSize()
    matrix = np.array(ops.printA("-ret")).reshape(size, size)
    dof_of = np.zeros(size, dtype=int)
    for node in range(len(frame.xyz)):
        for local, equation in enumerate(ops.nodeDOFs(node + 1)):
            if equation >= 0:
                dof_of[equation] = 6 * node + local
    return matrix, dof_of


@pytest.mark.parametrize("prestrain, taut", [(0.0, False), (1e-12, True)], ids=["cable at zero strain", "cable pretensioned"])
def test_elastic_stiffness_is_opensees_assembled_matrix(prestrain, taut):
    """Beams (both bending axes, torsion, axial), the washer link, the hinge and the cable: every entry within 1e-9 of
    itself or 0.01 N/mm (the hinges' 1e13 rounds to 1e-3 elsewhere; a strip's weak-axis terms are about 3 N/mm).
    OpenSees takes a cable at zero strain as slack (its tension-only tangent there is 0), pretensioned as taut (1e-12:
    a force of uN, so that the matrix printed after the step is still the unloaded one)."""
    frame = small_frame()
    frame.cable_prestrain = prestrain
    theirs, dof_of = opensees_matrix(frame)
    assert sorted(dof_of) == free_dofs(frame).tolist()
    ours = elastic(frame, cable_taut=np.array([taut])).toarray()[np.ix_(dof_of, dof_of)]
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-2)
    other = elastic(frame, cable_taut=np.array([not taut])).toarray()[np.ix_(dof_of, dof_of)]
    assert np.abs(other - theirs).max() > 1000.0  # the cable's EA/L (5 kN/mm) decides it: the comparison sees it


def column(n: int = 8, length: float = 1000.0):
    x = np.linspace(0.0, length, n + 1)
    frame = chain(np.column_stack([x, 0 * x, 0 * x]), np.tile([0.0, 0.0, 1.0], (n + 1, 1)), SECTION)
    frame.supports = {0: (1, 1, 1, 1, 0, 0), n: (0, 1, 1, 0, 0, 0)}
    return frame


@pytest.mark.parametrize("n", [4, 8])
def test_pinned_column_buckles_at_euler_load_about_its_weak_axis(n):
    """A unit compression: the factor is pi^2 E I_weak / L^2 within 1 % (0.75 % with 4 beams, the consistent
    matrix's error), sideways in the strip's weak direction (local y), the half sine."""
    frame = column(n)
    result = buckling(frame, load_axial=-np.ones(n))
    assert result.factor == pytest.approx(np.pi ** 2 * SECTION.E * SECTION.I_weak / 1000.0 ** 2, rel=0.01)
    sideways = result.mode[:, 1]
    assert np.abs(sideways).max() == pytest.approx(1.0)
    assert np.abs(result.mode[:, 2]).max() < 1e-6  # not about the strong axis
    assert np.allclose(np.abs(sideways), np.sin(np.linspace(0, np.pi, n + 1)), atol=0.02)


def test_a_tension_only_load_never_buckles_a_column():
    result = buckling(column(), load_axial=np.ones(8))
    assert result.factor == np.inf


def test_the_corotational_frame_sways_as_the_factor_says():
    """OpenSees's own nonlinear frame as the second opinion: a column with a small sideways bow under P stands with its
    sway amplified by 1 / (1 - P / P_cr); with the eigenproblem's P_cr, the sway at 0.9 P_cr is 9 times the one at
    0.5 P_cr, within 10 %."""
    frame = column(8)
    frame.xyz[:, 1] = 0.5 * np.sin(np.linspace(0, np.pi, 9))  # an L / 2000 bow
    factor = buckling(frame, -np.ones(8)).factor
    sways = []
    for share in (0.5, 0.9):
        loads = np.zeros((9, 6))
        loads[-1, 0] = -share * factor
        solution = Model(frame).solve(loads, residual=False)
        assert solution.converged
        sways.append(np.abs(solution.displacements[:, 1]).max())
    assert sways[1] / sways[0] == pytest.approx((0.9 / 0.1) / (0.5 / 0.5), rel=0.1)
