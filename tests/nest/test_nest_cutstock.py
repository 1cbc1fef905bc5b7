"""Strip rows by cutting stock: against instances with known optima and an independent assignment MIP."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import Bounds, LinearConstraint, milp

from fabline.nest.cutstock import first_fit_decreasing, pack_rows


def rows_are_feasible(rows, sizes, capacity):
    flat = sorted(i for row in rows for i in row)
    return flat == list(range(len(sizes))) and all(sizes[row].sum() <= capacity + 1e-9 for row in rows)


def test_first_fit_decreasing_by_hand():
    sizes = np.array([4.0, 4.0, 3.0, 3.0, 3.0, 3.0])
    rows = first_fit_decreasing(sizes, 10.0)
    assert [sorted(sizes[r].tolist()) for r in rows] == [[4.0, 4.0], [3.0, 3.0, 3.0], [3.0]]


def test_column_generation_beats_ffd_where_ffd_is_known_to_fail():
    # 2n fours and 4n threes in rows of 10: FFD pairs the fours (n rows) and stacks threes by three,
    # 2n + ceil(n/3) rows in all; the optimum is 2n rows of (4, 3, 3), also the LP and area bound.
    n = 30
    sizes = np.array([4.0] * (2 * n) + [3.0] * (4 * n))
    assert len(first_fit_decreasing(sizes, 10.0)) == n + -(-4 * n // 3)
    packing = pack_rows(sizes, 10.0, time_limit=5)
    assert rows_are_feasible(packing.rows, sizes, 10.0)
    assert len(packing.rows) == packing.lower_bound == 2 * n
    assert packing.lp_value == pytest.approx(2 * n)


def test_lp_bound_closed_form_when_area_is_loose():
    # Items of 0.4 C + 1: only two fit a row, so the LP bound is n / 2 while the area bound is ~0.4 n.
    capacity, n = 1000.0, 41
    sizes = np.full(n, 401.0)
    packing = pack_rows(sizes, capacity, time_limit=5)
    assert packing.lower_bound == 21 and len(packing.rows) == 21
    assert rows_are_feasible(packing.rows, sizes, capacity)


def test_perfectly_fillable_rows_are_found():
    # Rows cut at random whole millimetres into three pieces (the knapsack works on a 1 mm grid).
    rng = np.random.default_rng(4)
    capacity, rows = 3983.0, 12
    sizes = []
    for _ in range(rows):
        cuts = np.sort(rng.choice(np.arange(500, 3484), size=2, replace=False))
        sizes += [cuts[0], cuts[1] - cuts[0], capacity - cuts[1]]
    sizes = rng.permutation(np.array(sizes, dtype=float))
    packing = pack_rows(sizes, capacity, time_limit=30)
    assert rows_are_feasible(packing.rows, sizes, capacity)
    assert len(packing.rows) == rows == packing.lower_bound


def assignment_optimum(sizes, capacity):
    """Independent exact answer: the textbook bin-assignment MIP (x[i, b] item in bin, y[b] bin used)."""
    n = len(sizes)
    bins = len(first_fit_decreasing(sizes, capacity))
    nx = n * bins
    cost = np.concatenate([np.zeros(nx), np.ones(bins)])
    each_once = np.zeros((n, nx + bins))
    for i in range(n):
        each_once[i, i * bins:(i + 1) * bins] = 1
    capacity_rows = np.zeros((bins, nx + bins))
    for b in range(bins):
        capacity_rows[b, b:nx:bins] = sizes
        capacity_rows[b, nx + b] = -capacity
    result = milp(cost, integrality=np.ones(nx + bins), bounds=Bounds(0, 1),
                  constraints=[LinearConstraint(each_once, 1, 1), LinearConstraint(capacity_rows, -np.inf, 0)])
    return round(result.fun)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_matches_an_independent_exact_solver(seed):
    rng = np.random.default_rng(seed)
    sizes = rng.uniform(200, 2600, size=14).round(1)
    packing = pack_rows(sizes, 4000.0, time_limit=5)
    assert rows_are_feasible(packing.rows, sizes, 4000.0)
    optimum = assignment_optimum(sizes, 4000.0)
    assert packing.lower_bound <= optimum == len(packing.rows)


def test_item_longer_than_a_row_is_refused():
    with pytest.raises(ValueError):
        pack_rows(np.array([10.0, 11.0]), 10.5)
