"""The frame on OpenSees against closed forms: a cantilever strip's tip deflection about both axes, a twisted strip's
torque, a strip locked to a design curvature and twist, a two-hinged circular arch's buckling load, equilibrium."""

import numpy as np
import pytest

from fabline.analysis.buckling import buckling
from fabline.analysis.frame import FIXED, Section, chain
from fabline.analysis.solve import Model

SECTION = Section(E=210000.0, G=81000.0, h=100.0, t=1.5, density=7850.0)
L = 1000.0


def straight(n: int = 20):
    x = np.linspace(0.0, L, n + 1)
    return chain(np.column_stack([x, 0 * x, 0 * x]), np.tile([0.0, 0.0, 1.0], (n + 1, 1)), SECTION)


def tip_loads(frame, dof: int, value: float) -> np.ndarray:
    loads = np.zeros((len(frame.xyz), 6))
    loads[-1, dof] = value
    return loads


@pytest.mark.parametrize("dof, inertia, force", [(1, SECTION.I_weak, 0.002), (2, SECTION.I_strong, 1.0)],
                         ids=["weak axis (sideways)", "strong axis (along the normal)"])
def test_cantilever_tip_deflection_is_PL3_over_3EI(dof, inertia, force):
    """Small loads (a tip deflection of L/10000), so the corotational frame's answer is the linear one."""
    frame = straight()
    frame.supports = {0: FIXED}
    solution = Model(frame).solve(tip_loads(frame, dof, force))
    expected = force * L ** 3 / (3.0 * SECTION.E * inertia)
    assert solution.converged
    assert solution.displacements[-1, dof] == pytest.approx(expected, rel=0.01)
    assert solution.displacements[-1, dof] == pytest.approx(expected, rel=1e-4)  # in fact exact, up to the geometry


def test_twisted_strip_carries_the_torque_G_J_tau():
    """A strip clamped at one end, turned at the other about its axis by tau L: the torque is G J tau with the thin
    strip's J = h t^3 / 3, the reaction at the clamp equal and opposite."""
    frame = straight()
    frame.supports = {0: FIXED}
    torque = 1000.0
    solution = Model(frame).solve(tip_loads(frame, 3, torque))
    tau = solution.displacements[-1, 3] / L
    assert SECTION.G * SECTION.J == pytest.approx(SECTION.G * 100.0 * 1.5 ** 3 / 3.0)
    assert torque == pytest.approx(SECTION.G * SECTION.J * tau, rel=0.01)
    assert solution.reactions[0][3] == pytest.approx(-torque, rel=1e-9)


@pytest.mark.parametrize("strain, moment", [((0.001, 0.0, 0.0), 5), ((0.0, 0.0, 0.002), 1), ((0.0, 0.0, 0.0), None)],
                         ids=["twist", "weak-axis curvature", "none"])
def test_a_strip_held_in_its_erected_shape_carries_its_design_curvature(strain, moment):
    """Both ends clamped: the initial strain cannot relax, so every beam carries G J tau and E I_z k_g (the geometric
    check's stresses: tau = G t tau, sigma = E t k_g / 2) and nothing moves."""
    frame = straight()
    frame.supports = {0: FIXED, len(frame.xyz) - 1: FIXED}
    frame.strains[:] = strain
    solution = Model(frame).solve(np.zeros((len(frame.xyz), 6)))
    assert np.abs(solution.displacements).max() < 1e-9
    forces = solution.beam_forces
    assert np.allclose(forces[:, 5], SECTION.G * SECTION.J * strain[0], rtol=1e-6, atol=1e-9)
    assert np.allclose(forces[:, 2], SECTION.E * SECTION.I_weak * strain[2], rtol=1e-6, atol=1e-9)
    tau = np.abs(forces[:, 5]) * SECTION.t / SECTION.J
    sigma = np.abs(forces[:, 2]) / (SECTION.h * SECTION.t ** 2 / 6.0)
    assert np.allclose(tau, SECTION.G * SECTION.t * strain[0], rtol=1e-6, atol=1e-9)
    assert np.allclose(sigma, SECTION.E * SECTION.t * strain[2] / 2.0, rtol=1e-6, atol=1e-9)


def test_a_free_strip_springs_back_straight():
    """Clamped at one end only, a strip locked to a curvature k about its weak axis relaxes to its natural shape: the
    moment vanishes and the tip moves sideways by -k L^2 / 2 (small k: 0.5 mm)."""
    frame = straight()
    frame.supports = {0: FIXED}
    k = 1e-6
    frame.strains[:, 2] = k
    solution = Model(frame).solve(np.zeros((len(frame.xyz), 6)))
    assert solution.displacements[-1, 1] == pytest.approx(-k * L ** 2 / 2.0, rel=1e-3)
    assert np.abs(solution.beam_forces[:, 1:3]).max() < 1e-6 * SECTION.E * SECTION.I_weak * k + 1e-6


def arch(alpha: float, n: int = 60, radius: float = 1000.0):
    """A two-hinged circular arch in the x-z plane (hinges about y), its in-plane bending the strip's weak axis, and
    a unit radial line load (N/mm) lumped on its nodes."""
    theta = np.linspace(-alpha, alpha, n + 1)
    points = np.column_stack([radius * np.sin(theta), np.zeros(n + 1), radius * np.cos(theta)])
    frame = chain(points, np.tile([0.0, 1.0, 0.0], (n + 1, 1)), SECTION)
    frame.supports = {0: (1, 1, 1, 1, 0, 1), n: (1, 1, 1, 1, 0, 1)}
    loads = np.zeros((n + 1, 6))
    step = radius * 2.0 * alpha / n
    loads[:, 0], loads[:, 2] = -np.sin(theta) * step, -np.cos(theta) * step
    loads[[0, n]] /= 2.0
    return frame, loads


def test_two_hinged_arch_buckles_at_EI_over_R3_times_pi2_over_alpha2_minus_1():
    """q_cr = E I / R^3 (pi^2 / alpha^2 - 1) for a half-opening alpha of 20 degrees, within 2 %: the linear buckling
    eigenproblem on the axial forces of OpenSees's linear solve of the unit load (the hoop force q R, checked too).
    The closed form is for a pressure that stays normal to the deformed arch, the eigenproblem's loads keep their
    direction: about 1/(pi^2/alpha^2 - 1) apart, 1.3 % at 20 degrees (9 % at 60, where the test would fail)."""
    alpha, radius = np.radians(20.0), 1000.0
    frame, loads = arch(alpha, radius=radius)
    axial = Model(frame, linear=True).solve(loads, residual=False).beam_forces[:, 0]
    assert axial == pytest.approx(np.full(len(axial), -radius), rel=0.01)
    result = buckling(frame, axial)
    expected = SECTION.E * SECTION.I_weak / radius ** 3 * (np.pi ** 2 / alpha ** 2 - 1.0)
    assert result.factor == pytest.approx(expected, rel=0.02)
    mode = result.mode
    sway = mode[:, 0]
    assert abs(sway[len(sway) // 2]) > 0.5 * np.abs(sway).max()  # the antisymmetric mode: the crown sways sideways
    assert np.abs(mode[:, 2][len(sway) // 2]) < 0.05 * np.abs(mode[:, 2]).max()


def test_reactions_balance_the_applied_load():
    """An arch under its radial load: the reactions' sum equals minus the loads' sum to 1e-6 (of the load)."""
    frame, loads = arch(np.radians(40.0))
    solution = Model(frame).solve(loads * 0.01)
    total = sum(solution.reactions.values())[:3] + loads[:, :3].sum(axis=0) * 0.01
    assert np.abs(total).max() <= 1e-6 * np.abs(loads[:, :3] * 0.01).sum()
