"""Shortcuts of the 20,000-node unroll against the plain forms they replace: a Gauss-Newton step's reused spline
pieces against a fresh search, the queries-last spline speed against np.linalg.norm (bit for bit: the parts must
not change), and the collector hand-off after bulk work against what the gc module reports."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from fabline.geometry import analyse
from fabline.geometry.offsets import SplineTable, _speed
from fabline.unroll.collector import collector_paused


@pytest.fixture(scope="module")
def table(enneper):
    return SplineTable([geo.fit for geo in analyse(enneper).lamellas.values()])


def test_a_reused_location_equals_a_fresh_search(table):
    rng = np.random.default_rng(11)
    fit = rng.integers(0, len(table.pieces), 6000)
    low = table.knots[table.first_knot[fit]]
    high = table.knots[table.first_knot[fit] + table.pieces[fit]]
    tau = low - 50.0 + rng.random(len(fit)) * (high - low + 100.0)   # before, inside and past every fit
    previous = table.locate(fit, tau)
    # move parameters: some stay in their piece, some land exactly on knots, some leave the fit's range
    step = rng.choice([0.0, 1e-9, 0.3, -0.3, 5.0, -80.0], len(fit)) * (high - low) / table.pieces[fit]
    moved = tau + step
    on_knot = rng.random(len(fit)) < 0.1
    knot_row = table.first_knot[fit] + rng.integers(0, table.pieces[fit] + 1)
    moved[on_knot] = table.knots[knot_row[on_knot]]
    reused, fresh = table.locate(fit, moved, previous), table.locate(fit, moved)
    assert np.array_equal(reused.piece, table.local_piece(fit, moved))
    assert np.array_equal(reused.piece, fresh.piece)
    assert np.array_equal(reused.coefficients, fresh.coefficients) and np.array_equal(reused.knot, fresh.knot)
    assert np.any(reused.piece != previous.piece) and np.any(reused.piece == previous.piece)
    assert table.locate(fit, tau, previous) is previous  # nothing moved: nothing recomputed
    offset = rng.uniform(-30.0, 30.0, len(fit))
    for got, want in zip(table.offset_points(fit, moved, offset, reused), table.offset_points(fit, moved, offset)):
        assert np.array_equal(got, want)


def test_the_queries_last_speed_is_numpys_norm_bit_for_bit(table):
    rng = np.random.default_rng(12)
    fit = rng.integers(0, len(table.pieces), 5000)
    low = table.knots[table.first_knot[fit]]
    high = table.knots[table.first_knot[fit] + table.pieces[fit]]
    tau = low - 20.0 + rng.random(len(fit)) * (high - low + 40.0)
    location = table.locate(fit, tau)
    dx = tau - location.knot
    expected = np.linalg.norm(table.evaluate(fit, location.piece, tau, 1)[:, :3], axis=1)
    assert np.array_equal(_speed(location.coefficients, dx), expected)
    steps = np.stack([dx * f for f in (0.1, 0.5, 0.9)])     # (3, N): several offsets per query at once
    together = _speed(location.coefficients, steps)
    assert all(np.array_equal(together[k], _speed(location.coefficients, steps[k])) for k in range(3))


def test_offset_points_by_column_equal_the_row_formula_bit_for_bit(table):
    """Points c + o u and c' from the column layout against the same formula on (N, 6) rows of `evaluate`, and
    arc lengths on a reused location against a fresh search: equal to the last bit, so the parts cannot change."""
    rng = np.random.default_rng(13)
    fit = rng.integers(0, len(table.pieces), 5000)
    low = table.knots[table.first_knot[fit]]
    high = table.knots[table.first_knot[fit] + table.pieces[fit]]
    tau = low - 20.0 + rng.random(len(fit)) * (high - low + 40.0)
    offset = rng.uniform(-30.0, 30.0, len(fit))
    piece = table.local_piece(fit, tau)
    value, d1 = table.evaluate(fit, piece, tau, 0), table.evaluate(fit, piece, tau, 1)[:, :3]
    t = d1 / np.linalg.norm(d1, axis=1)[:, None]
    n = value[:, 3:] - np.einsum("ij,ij->i", value[:, 3:], t)[:, None] * t
    n /= np.linalg.norm(n, axis=1)[:, None]
    points, derivative = table.offset_points(fit, tau, offset)
    assert np.array_equal(points, value[:, :3] + offset[:, None] * np.cross(n, t)) and np.array_equal(derivative, d1)
    moved = tau + rng.uniform(-5.0, 5.0, len(tau))
    reused = table.locate(fit, moved, table.locate(fit, tau))
    for got, want in zip(table.arc_length(fit, moved, reused), table.arc_length(fit, moved)):
        assert np.array_equal(got, want)


class _Cycle:
    """An object in a reference cycle, only the cyclic collector can free."""

    def __init__(self) -> None:
        self.me = self


def test_objects_made_while_paused_go_to_the_oldest_generation_and_cycles_still_get_collected():
    gc.unfreeze()                               # objects another test froze: the hand-off is skipped while any are
    gc.collect()
    with collector_paused():
        assert not gc.isenabled()
        kept = [[k] for k in range(2000)]
        cycle = weakref.ref(_Cycle())
    assert gc.isenabled() and gc.get_freeze_count() == 0
    assert gc.get_count()[0] < 100              # nothing waits in the youngest generation for a pass
    oldest = {id(o) for o in gc.get_objects(generation=2)}
    assert all(id(row) in oldest for row in kept)
    assert cycle() is not None                  # garbage, but only a cyclic pass can tell ...
    gc.collect()
    assert cycle() is None                      # ... and a full collection still does


def test_objects_frozen_by_others_stay_frozen():
    marker = [object()]                         # frozen objects are in no generation that gc.get_objects lists
    gc.freeze()
    try:
        with collector_paused():
            [[k] for k in range(100)]
        assert gc.get_freeze_count() > 0
        assert all(o is not marker for o in gc.get_objects())
    finally:
        gc.unfreeze()
    assert any(o is marker for o in gc.get_objects())
