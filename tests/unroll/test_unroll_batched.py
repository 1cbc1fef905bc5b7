"""The batched forms behind the unroll's speed against independent references: the network-wide spline table
against scipy's per-lamella splines, offset-curve arc lengths against a closed form (concentric circles), and
the vectorised label placement against the one-segment `pieces.label_spot`, ties and crowded strips included."""

from __future__ import annotations

import numpy as np
import pytest

from fabline.geometry import analyse
from fabline.geometry.offsets import OffsetCurve, OffsetCurves, SplineTable, offset_arc_lengths
from fabline.unroll.batch import label_spots
from fabline.unroll.pieces import label_spot
from networks import polar_grid


@pytest.fixture(scope="module")
def pavilion_geometry(enneper):
    return list(analyse(enneper).lamellas.values())


def test_spline_table_equals_each_lamellas_scipy_spline(pavilion_geometry):
    fits = [geo.fit for geo in pavilion_geometry]
    table = SplineTable(fits)
    rng = np.random.default_rng(3)
    which = rng.integers(0, len(fits), 4000)
    low = np.array([fits[f].tau[0] for f in which])
    high = np.array([fits[f].tau[-1] for f in which])
    tau = low - 60.0 + rng.random(len(which)) * (high - low + 120.0)  # past both ends too: extrapolated pieces
    tau[:len(fits)] = [fit.tau[len(fit.tau) // 2] for fit in fits]   # exactly on a knot
    which[:len(fits)] = np.arange(len(fits))
    piece = table.local_piece(which, tau)
    for derivative in (0, 1):
        expected = np.array([fits[f].spline(t, derivative) for f, t in zip(which, tau)])
        assert np.abs(table.evaluate(which, piece, tau, derivative) - expected).max() < 1e-9
    expected_length = np.array([fits[f].arc_length(np.array([t]))[0] for f, t in zip(which, tau)])
    assert np.abs(table.arc_length(which, tau)[0] - expected_length).max() < 1e-9
    inside = (tau > low) & (tau < high)
    s = expected_length[inside]
    expected_tau = np.array([fits[f].parameter_at(np.array([x]))[0] for f, x in zip(which[inside], s)])
    assert np.abs(table.parameter_at(which[inside], s) - expected_tau).max() < 1e-9


def test_offset_arc_lengths_of_concentric_circles():
    radii, angles = 3000.0 + 350.0 * np.arange(3), 0.1 * np.arange(9)
    geos = [geo for geo in analyse(polar_grid(radii, angles)).lamellas.values() if geo.lamella.family == "A"]
    table = SplineTable([geo.fit for geo in geos])
    offsets = [12.5, -12.5, 40.0]
    curves = OffsetCurves.of([geo for geo in geos for _ in offsets], offsets * len(geos),
                             [1.0] * len(offsets) * len(geos))
    fit_of_curve = np.repeat(np.arange(len(geos)), len(offsets))
    rng = np.random.default_rng(5)
    curve = rng.integers(0, len(curves.curves), 500)
    fits = [geos[f].fit for f in fit_of_curve[curve]]
    tau = np.array([fit.tau[-1] * u for fit, u in zip(fits, rng.random(len(curve)))])
    measured = offset_arc_lengths(table, curves, fit_of_curve, curve, tau)
    # u = n x t points inwards on these counter-clockwise circles: the offset curve is the circle r - o
    for k, (c, t) in enumerate(zip(curve, tau)):
        fit, offset = fits[k], offsets[c % len(offsets)]
        start, here = fit.curve(np.array([0.0, t]))
        radius = np.hypot(*start[:2])
        turned = np.arctan2(here[1], here[0]) - np.arctan2(start[1], start[0])
        assert measured[k] == pytest.approx((radius - offset) * turned, abs=2e-3), (c, t)


def test_offset_curves_made_together_equal_each_made_alone(pavilion_geometry):
    """The batch adds up each curve's length pieces in its own order: bit for bit the trapezoid sums of the
    length element sqrt((1 - o k_g)^2 + (o tau_g)^2) ds taken curve by curve, with and without a per-sample stretch."""
    geos = pavilion_geometry[:12]
    offsets = [25.0, -25.0, 0.0] * 4
    stretches = [1.0 + 1e-4 * np.sin(geo.s) if k % 3 == 1 else 1.0 for k, geo in enumerate(geos)]
    together = OffsetCurves.of(geos, offsets, stretches)
    for geo, offset, stretch, curve in zip(geos, offsets, stretches, together.curves):
        ratio = np.hypot(1.0 - offset * geo.k_g, offset * geo.tau_g) * stretch
        s_at = np.concatenate([[0.0], np.cumsum(np.diff(geo.s) * (ratio[1:] + ratio[:-1]) / 2.0)])
        assert np.array_equal(curve.ratio, ratio) and np.array_equal(curve.s_at_samples, s_at)
        assert curve.geometry is geo and curve.offset == offset
    assert np.array_equal(OffsetCurve.of(geos[1], -25.0, stretches[1]).s_at_samples, together.curves[1].s_at_samples)


def random_segments(rng, count):
    """Segment ranges and blocked spans like a strip's: seam overlaps at the ends, node id spans, some repeated
    exactly (equally wide free stretches), some overlapping, some sticking out of the segment, some tiny."""
    a = rng.uniform(0.0, 5000.0, count)
    b = a + rng.choice([40.0, 300.0, 3980.0], count)
    spans = []
    for k in range(count):
        if rng.random() < 0.5:
            spans.append((k, a[k], a[k] + 150.0))
        if rng.random() < 0.5:
            spans.append((k, b[k] - 150.0, b[k]))
        step = rng.choice([50.0, 350.0])          # a regular grid: many free stretches of one width
        for x in np.arange(a[k] - 20.0, b[k] + 20.0, step):
            spans.append((k, x - 1.5, x + rng.choice([30.0, 30.0, 60.0])))
    seg, lo, hi = (np.array(column) for column in zip(*spans))
    order = rng.permutation(len(seg))
    return a, b, seg[order], lo[order], hi[order]


def test_vectorised_label_spots_equal_the_one_segment_placement():
    rng = np.random.default_rng(11)
    a, b, seg, lo, hi = random_segments(rng, 400)
    widths = rng.uniform(5.0, 30.0, len(a))
    anchor, size = label_spots(widths, a, b, seg, lo, hi, 6.0)
    placed = 0
    for k in range(len(a)):
        spot = label_spot(float(widths[k]), a[k], b[k], list(zip(lo[seg == k], hi[seg == k])), 6.0)
        if spot is None:
            assert np.isnan(anchor[k]) and size[k] == 0.0, k
        else:
            placed += 1
            assert (anchor[k], size[k]) == pytest.approx(spot, abs=1e-9), k
    assert 0 < placed < len(a)  # both outcomes exercised
