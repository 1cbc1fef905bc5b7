"""Load lumping by tributary area and the combinations, against hand figures on a flat square grid."""

import numpy as np
import pytest

from fabline.analysis.frame import Frame, Section
from fabline.analysis.loads import GRAVITY, LoadSettings, basic_cases, combinations, tributary


def grid(n: int = 5, spacing: float = 500.0, tilt: float = 0.0):
    x, y = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    xyz = np.column_stack([x.ravel(), y.ravel(), tilt * x.ravel()])
    return xyz, spacing * (n - 1)


def test_plan_areas_of_a_square_grid_are_its_cells():
    xyz, side = grid()
    plan, area = tributary(xyz)
    assert plan.sum() == pytest.approx(side ** 2)
    inner = (xyz[:, 0] > 0) & (xyz[:, 0] < side) & (xyz[:, 1] > 0) & (xyz[:, 1] < side)
    assert plan[inner] == pytest.approx(np.full(inner.sum(), 500.0 ** 2))
    assert np.allclose(area[:, :2], 0.0) and np.allclose(area[:, 2], plan)


def test_a_tilted_grid_has_the_same_plan_and_a_larger_true_area():
    xyz, side = grid(tilt=0.75)  # slope 3:4, true area 5/4 of the plan
    plan, area = tributary(xyz)
    assert plan.sum() == pytest.approx(side ** 2)
    assert np.linalg.norm(area.sum(axis=0)) == pytest.approx(1.25 * side ** 2)


def test_cases_and_combinations_carry_their_totals():
    xyz, side = grid()
    beams = np.array([(k, k + 1) for k in range(len(xyz) - 1) if (k + 1) % 5])
    section = Section(210000.0, 81000.0, 100.0, 1.5, density=7850.0)
    frame = Frame(xyz, [str(k) for k in range(len(xyz))], beams, np.tile([0.0, 0.0, 1.0], (len(beams), 1)), section)
    settings = LoadSettings(snow=1.0, wind=0.5, person=1000.0)
    cases = basic_cases(frame, np.arange(len(xyz)), settings)
    steel = 20 * 500.0 * 150.0 * 7850.0 * 1e-9   # 20 beams of 500 mm, 150 mm2
    assert -cases["G"][:, 2].sum() == pytest.approx(steel * GRAVITY)
    assert -cases["S"][:, 2].sum() == pytest.approx(1e-3 * side ** 2)          # 1 kN/m2 = 1e-3 N/mm2
    assert -cases["W"][:, 2].sum() == pytest.approx(0.5e-3 * side ** 2)
    assert cases["S one-sided"][:, 2].sum() / cases["S"][:, 2].sum() == pytest.approx(1500.0 / 4000.0)  # x < 1000 mm
    combined = combinations(cases, settings)
    assert list(combined)[0] == "1.35 G"
    assert np.allclose(combined["1.35 G + 1.5 S"], 1.35 * cases["G"] + 1.5 * cases["S"])
