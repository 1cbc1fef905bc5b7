"""Stacking long curved parts by their outlines: straight bars at the closed-form pitch, arcs of one radius
nested inside each other, checked by independent shapely distances; a nesting of such bars validated."""

from __future__ import annotations

import math
from itertools import combinations

from shapely import affinity
from shapely.geometry import Polygon, box

from fabline.nest import NestOptions, nest, place, validate_nesting
from fabline.nest.stacking import BISECTION_TOL, BUFFER_MARGIN, StackSheet
from fabline.nest.synthetic import curved_strip
from fabline.shop import StockItem
from fabline.unroll import PartSet, flatten_contour

CLEARANCE = 3.2


def _lay(stack: StackSheet, polygon: Polygon, rotations=(0.0, 180.0)) -> Polygon:
    x, y, rotation = stack.place(polygon, list(rotations))
    laid = affinity.translate(affinity.rotate(polygon, rotation, origin=(0, 0)), x, y)
    stack.add(laid)
    return laid


def test_straight_bars_stack_at_height_plus_clearance_above_the_rows():
    stack = StackSheet(4000.0, 2000.0, 10.0, CLEARANCE, rows_top=500.0)
    laid = [_lay(stack, box(0, 0, 3000, 100)) for _ in range(5)]
    bottoms = [p.bounds[1] for p in laid]
    assert abs(bottoms[0] - (500.0 + CLEARANCE)) < 1e-9        # the first bar right above the rows
    for below, above in zip(bottoms, bottoms[1:]):            # then one bar height plus the clearance apart
        assert 100.0 + CLEARANCE <= above - below <= 100.0 + CLEARANCE + BUFFER_MARGIN + BISECTION_TOL
    # a sheet too full for another bar says so
    full = StackSheet(4000.0, 2000.0, 10.0, CLEARANCE, rows_top=1950.0)
    assert full.place(box(0, 0, 3000, 100), [0.0]) is None


def test_arcs_of_one_radius_nest_inside_each_other_clear_of_each_other():
    radius, length, width = 5000.0, 3600.0, 100.0
    arc = Polygon(flatten_contour(curved_strip("E", radius, length, width).outline)[:, :2])
    stack = StackSheet(4000.0, 2000.0, 10.0, CLEARANCE, rows_top=None)
    laid = [_lay(stack, arc) for _ in range(8)]
    usable = box(10.0, 10.0, 3990.0, 1990.0)
    assert all(usable.contains(p) for p in laid)
    assert all(a.distance(b) >= CLEARANCE for a, b in combinations(laid, 2))
    # Translated copies of an arc band: vertically apart by at least the width plus the clearance (at the middle),
    # at most that over the cosine of the end slope (a band's vertical thickness is largest at its ends).
    sagitta = radius * (1 - math.cos(length / radius / 2))
    bounding = laid[0].bounds[3] - laid[0].bounds[1]
    assert abs(bounding - (sagitta + width * math.cos(length / radius / 2))) < 1.0
    cosine = math.cos(length / radius / 2)
    pitches = [b.bounds[1] - a.bounds[1] for a, b in zip(laid, laid[1:])]
    assert all(width + CLEARANCE - 1e-6 <= p <= (width + CLEARANCE) / cosine + 1.0 for p in pitches)


def test_a_nesting_of_curved_bars_is_valid_and_dense():
    parts = [curved_strip(f"E{k}", 6000.0 + 50.0 * k, 3700.0) for k in range(14)]
    partset = PartSet(parts, profile="100x1.5", material="stainless", source="test")
    result = nest(partset, [StockItem("4x2", 4000, 2000)], NestOptions(kerf=0.2, gap=3.0, margin=10.0))
    assert validate_nesting(result.nesting, partset) == []
    by_id = {p.id: p for p in parts}
    for sheet in result.nesting.sheets:   # independent of the validator: shapely distances of the placed outlines
        outlines = [Polygon(place(flatten_contour(by_id[p.part].outline), p)[:, :2]) for p in sheet.placements]
        assert all(a.distance(b) >= 3.2 - 1e-6 for a, b in combinations(outlines, 2))
    # Arcs of 3700 mm on radii 6000-6650 mm: a sagitta of at most 283 mm plus the 100 mm width, then a pitch of at
    # most (100 + 3.2) / cos(3700 / 6000 / 2) = 108.3 mm: 10 + 383 + 13 x 108.3 = 1801 mm, all 14 on one sheet
    assert len(result.nesting.sheets) == 1 == result.report["lower_bound"]["best"]
