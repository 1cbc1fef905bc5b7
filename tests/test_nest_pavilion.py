"""The pavilion-sized cut list: every part placed, validated, at most one sheet above the best lower bound."""

from __future__ import annotations

import math

import pytest
from shapely.geometry import Polygon, box

from fabline.nest import NestOptions, StockItem, nest, place, validate_nesting
from fabline.nest.synthetic import pavilion_like_parts
from fabline.unroll import flatten_contour


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
