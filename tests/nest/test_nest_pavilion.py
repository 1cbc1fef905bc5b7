"""Pavilion-sized cut lists (synthetic and the unrolled built-in design): every part placed, validated,
at most one sheet above the best lower bound; the lower bounds against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from fabline.model.designs import enneper_network
from fabline.nest import NestOptions, nest, place, validate_nesting
from fabline.nest.nester import lower_bounds
from fabline.nest.shapes import nest_shapes
from fabline.nest.synthetic import pavilion_like_parts
from fabline.shop import StockItem
from fabline.unroll import Part, flatten_contour, unroll_network


@pytest.fixture(scope="module")
def pavilion():
    parts = pavilion_like_parts()
    return parts, nest(parts, [StockItem("4x2", 4000, 2000)], NestOptions(kerf=0.2, gap=3.0, margin=10.0))


def test_every_part_placed_once_and_valid(pavilion):
    parts, result = pavilion
    assert validate_nesting(result.nesting, parts) == []
    placed = sorted(p.part for s in result.nesting.sheets for p in s.placements)
    assert placed == sorted(p.id for p in parts.parts)


def test_at_most_one_sheet_above_the_lower_bound(pavilion):
    parts, result = pavilion
    report = result.report
    # The plain area bound, recomputed here from the outlines and holes.
    net = sum(Polygon(flatten_contour(p.outline)[:, :2], [flatten_contour(h)[:, :2] for h in p.holes]).area
              for p in parts.parts)
    assert report["lower_bound"]["area"] == math.ceil(net / 8e6)
    # Strips: 262 rows of 3983.2 mm at most 19 to a sheet (19 x 103.2 <= 1983.2 mm).
    assert report["strips"]["row_lower_bound"] == report["strips"]["rows"]
    assert report["lower_bound"]["strip_lp"] == math.ceil(report["strips"]["row_lower_bound"] / 19)
    assert report["sheets_used"] <= report["lower_bound"]["best"] + 1
    assert report["sheets_used"] == len(result.nesting.sheets)


def test_leftovers_become_remnants_clear_of_every_part(pavilion):
    parts, result = pavilion
    by_sheet = {s.id: s for s in result.nesting.sheets}
    by_id = {p.id: p for p in parts.parts}
    assert result.nesting.remnants
    for remnant in result.nesting.remnants:
        sheet = by_sheet[remnant["sheet"]]
        assert max(remnant["width"], remnant["height"]) >= 400 and min(remnant["width"], remnant["height"]) >= 200
        assert 0 <= remnant["x"] and remnant["x"] + remnant["width"] <= sheet.width + 1e-6
        assert 0 <= remnant["y"] and remnant["y"] + remnant["height"] <= sheet.height + 1e-6
        area = box(remnant["x"], remnant["y"], remnant["x"] + remnant["width"], remnant["y"] + remnant["height"])
        for placement in sheet.placements:
            outline = Polygon(place(flatten_contour(by_id[placement.part].outline), placement)[:, :2])
            assert outline.distance(area) >= 3.2 - 1e-6, (remnant["id"], placement.part)


def test_clearance_area_bound_closed_form():
    # 53 plates of 390 x 190 mm, clearance 3.2 mm: grown plate (a + c)(b + c) - (4 - pi)(c / 2)^2,
    # grown usable sheet (W - 2m + c)(H - 2m + c); the bound is the ceiling of their ratio.
    a, b, c, count = 390.0, 190.0, 3.2, 53
    plate = np.array([[0, 0], [a, 0], [a, b], [0, b], [0, 0]])
    shapes = nest_shapes([Part(f"P{k}", "clamp", plate) for k in range(count)])
    options = NestOptions(kerf=0.2, gap=3.0, margin=10.0)
    bounds = lower_bounds(shapes, StockItem("s", 1000, 1000), options, {"row_lower_bound": None})
    grown = (a + c) * (b + c) - (4 - math.pi) * (c / 2) ** 2
    ratio = count * grown / ((1000 - 20 + c) ** 2)
    assert bounds["clearance_area"] == math.ceil(ratio) == 5
    assert bounds["area"] == math.ceil(count * a * b / 1e6) == 4
    assert bounds["strip_lp"] == 0


def test_the_unrolled_built_in_design_nests_within_one_sheet_of_the_bound():
    parts = unroll_network(enneper_network())
    result = nest(parts, [StockItem("4x2", 4000, 2000)], NestOptions(kerf=0.2, gap=3.0, margin=10.0))
    assert validate_nesting(result.nesting, parts) == []
    assert len(result.nesting.sheets) <= result.report["lower_bound"]["best"] + 1
