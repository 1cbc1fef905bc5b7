"""The nesting validator against hand-placed rectangles with known distances, and on broken real nestings."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fabline.nest import (CommonCut, Nesting, NestOptions, Placement, Sheet, StockItem, nest, nesting_to_dict,
                          validate_nesting)
from fabline.nest.synthetic import pavilion_like_parts
from fabline.unroll import Part, PartSet

GAP, KERF, MARGIN = 3.0, 0.2, 10.0


def rectangle(pid: str, w: float, h: float, grain: bool = False) -> Part:
    return Part(pid, "clamp", np.array([[0, 0], [w, 0], [w, h], [0, h], [0, 0]], dtype=float), grain=grain)


def two_rectangles(x_second: float, y_second: float = 10.0, rotation: float = 0.0, grain: bool = False):
    parts = PartSet([rectangle("A", 100, 50), rectangle("B", 100, 50, grain)])
    sheet = Sheet("S1", 1000, 500, [Placement("A", 10, 10), Placement("B", x_second, y_second, rotation)])
    return Nesting([sheet], "parts.json", KERF, GAP, MARGIN), parts


def test_parts_exactly_gap_plus_kerf_apart_pass():
    nesting, parts = two_rectangles(10 + 100 + GAP + KERF)
    assert validate_nesting(nesting, parts) == []


def test_parts_closer_than_gap_plus_kerf_fail():
    nesting, parts = two_rectangles(10 + 100 + GAP)      # kerf missing: 3.0 mm apart, 3.2 needed
    problems = validate_nesting(nesting, parts)
    assert len(problems) == 1 and "A and B are 3.000 mm apart" in problems[0]


def test_overlap_is_caught():
    nesting, parts = two_rectangles(60, 30)
    problems = validate_nesting(nesting, parts)
    assert problems == ["sheet S1: parts A and B overlap"]


def test_rotation_is_about_the_part_origin_then_translation():
    # B rotated 90 deg about its origin spans x in [-50, 0], y in [0, 100]; translated by (x, y).
    nesting, parts = two_rectangles(10 + 100 + GAP + KERF + 50, 10, rotation=90)
    assert validate_nesting(nesting, parts) == []
    nesting, parts = two_rectangles(10 + 100 + GAP + KERF + 49, 10, rotation=90)
    assert "apart" in validate_nesting(nesting, parts)[0]


def test_outside_the_usable_area_is_caught():
    nesting, parts = two_rectangles(1000 - MARGIN - 100)        # touches the margin: fine
    assert validate_nesting(nesting, parts) == []
    nesting, parts = two_rectangles(1000 - MARGIN - 99)         # 1 mm into the margin
    problems = validate_nesting(nesting, parts)
    assert problems == ["sheet S1: part B lies outside the usable area (margin 10 mm) by 1.00 mm"]


def test_missing_duplicate_and_unknown_parts_are_caught():
    nesting, parts = two_rectangles(200)
    nesting.sheets[0].placements.pop()
    assert validate_nesting(nesting, parts) == ["part B: not placed on any sheet"]
    nesting, parts = two_rectangles(200)
    nesting.sheets.append(Sheet("S2", 1000, 500, [Placement("B", 10, 10), Placement("Z", 300, 10)]))
    problems = validate_nesting(nesting, parts)
    assert "part B: placed 2 times" in problems and "part Z: placed but not in the parts file" in problems


def test_grain_bound_part_may_only_turn_half_way():
    nesting, parts = two_rectangles(10 + 100 + GAP + KERF + 50, rotation=90, grain=True)
    assert validate_nesting(nesting, parts) == ["sheet S1: part B is grain-bound but rotated 90 deg"]
    nesting, parts = two_rectangles(10 + 100 + GAP + KERF + 100, 60, rotation=180, grain=True)
    assert validate_nesting(nesting, parts) == []


def test_common_cut_lets_two_parts_share_one_kerf():
    nesting, parts = two_rectangles(10 + 100 + KERF)
    assert "apart" in validate_nesting(nesting, parts)[0]
    nesting.sheets[0].common_cuts.append(CommonCut(("A", "B"), (110.1, 10), (110.1, 60)))
    assert validate_nesting(nesting, parts) == []


@pytest.fixture(scope="module")
def real_nesting():
    parts = pavilion_like_parts(strip_metres=60, curved=2, washers=120, clamps=40, joints=1, seed=7)
    result = nest(parts, [StockItem("4x2", 4000, 2000)], NestOptions(time_limit=2))
    return result.nesting, parts


def test_a_real_nesting_passes(real_nesting):
    nesting, parts = real_nesting
    assert validate_nesting(nesting, parts) == []
    assert sum(len(s.placements) for s in nesting.sheets) == len(parts.parts)


@pytest.mark.parametrize("damage, expected", [
    ("overlap", "overlap"), ("out of sheet", "outside the usable area"),
    ("missing", "not placed on any sheet"), ("duplicate", "placed 2 times"), ("too close", "apart"),
])
def test_broken_real_nestings_are_caught(real_nesting, damage, expected):
    nesting, parts = copy.deepcopy(real_nesting[0]), real_nesting[1]
    placements = nesting.sheets[0].placements
    washers = [p for p in placements if p.part.startswith("W")]
    if damage == "overlap":
        washers[1].x, washers[1].y = washers[0].x + 20, washers[0].y
    elif damage == "out of sheet":
        placements[0].x -= 50
    elif damage == "missing":
        placements.pop(3)
    elif damage == "duplicate":
        nesting.sheets[-1].placements.append(copy.copy(placements[0]))
    else:
        # Move one washer to 1 mm from another's outline: closer than gap + kerf but not overlapping.
        a, b = washers[0], washers[1]
        b.x, b.y, b.rotation = a.x + 70 + 1.0, a.y, a.rotation
    problems = validate_nesting(nesting, parts)
    assert any(expected in p for p in problems), problems


def _mistype(data: dict, field: str) -> None:
    sheet = data["sheets"][0]
    if field == "sheets":
        data["sheets"] = 5
    elif field == "sheet":
        data["sheets"][0] = "S1"
    elif field == "placements":
        sheet["placements"] = {"part": "A"}
    elif field == "placement":
        sheet["placements"][0] = 7
    elif field == "x":
        sheet["placements"][0]["x"] = "abc"
    elif field == "rotation":
        sheet["placements"][1]["rotation"] = None
    elif field == "width":
        del sheet["width"]
    elif field == "kerf":
        data["kerf"] = [0.2]
    elif field == "common cut":
        sheet["common_cuts"] = [{"parts": ["A", "B"], "start": [0, 0], "end": 5}]


@pytest.mark.parametrize("field, expected", [
    ("sheets", "'sheets' must be a list"), ("sheet", "sheets[0]: expected an object"),
    ("placements", "sheet S1: 'placements' must be a list"), ("placement", "placements[0]: expected an object"),
    ("x", "placements[0]: 'x' must be a finite number"), ("rotation", "placements[1]: 'rotation' must be a finite"),
    ("width", "sheet S1: missing 'width'"), ("kerf", "'kerf' must be a finite number"),
    ("common cut", "common_cuts[0]: 'end' must be [x, y]"),
])
def test_mistyped_nesting_field_is_named_on_one_line(cli, tmp_path, field, expected):
    data = nesting_to_dict(two_rectangles(200)[0])
    _mistype(data, field)
    path = tmp_path / "nesting.json"
    path.write_text(json.dumps(data))
    code, stdout, stderr = cli("nest", "--check", path)
    assert code == 2 and stdout == "" and stderr.count("\n") == 1, stderr
    assert str(path) in stderr and expected in stderr, stderr
    assert [p.name for p in tmp_path.iterdir()] == ["nesting.json"]
