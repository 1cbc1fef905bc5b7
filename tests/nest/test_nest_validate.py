"""The nesting validator against hand-placed rectangles with known distances, and on broken real nestings."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.nest import CommonCut, Nesting, NestOptions, Placement, Sheet, nest, nesting_to_dict, validate_nesting
from fabline.nest.synthetic import pavilion_like_parts
from fabline.shop import StockItem
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
    assert problems == ["sheet S1: parts A and B overlap by 1500 mm²"]  # [60, 110] x [30, 60]


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
    assert "part B: placed 2 times (on sheets S1, S2)" in problems
    assert "part Z: placed (on sheet S2) but not in the parts file" in problems


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


CHECK_CASES = {
    "overlap": (lambda n: _move(n, "B", 60, 30), "sheet S1: parts A and B overlap by 1500 mm²"),
    "too close": (lambda n: _move(n, "B", 10 + 100 + GAP, 10),
                  "sheet S1: parts A and B are 3.000 mm apart, need 3.2 mm (gap + kerf)"),
    "placed twice": (lambda n: n.sheets[0].placements.append(Placement("A", 500, 200)), "part A: placed 2 times "
                     "(on sheet S1 2 times)"),
    "missing": (lambda n: n.sheets[0].placements.pop(), "part B: not placed on any sheet"),
    "unknown id": (lambda n: n.sheets[0].placements.append(Placement("Z", 500, 200)),
                   "part Z: placed (on sheet S1) but not in the parts file"),
    "negative kerf": (lambda n: setattr(n, "kerf", -0.2), "kerf is -0.2 mm: must not be negative"),
    "negative gap": (lambda n: setattr(n, "gap", -3), "gap is -3 mm: must not be negative"),
    "grain rotated 45": (lambda n: setattr(n.sheets[0].placements[1], "rotation", 45.0),
                         "sheet S1: part B is grain-bound but rotated 45 deg"),
    "outside the margin": (lambda n: _move(n, "B", 1000 - MARGIN - 99, 10),
                           "sheet S1: part B lies outside the usable area (margin 10 mm) by 1.00 mm"),
    "outside the sheet": (lambda n: _move(n, "B", 10, -60),
                          "sheet S1: part B lies outside the usable area (margin 10 mm) by 70.00 mm"),
    "common cut off the sheet": (lambda n: n.sheets[0].common_cuts.append(CommonCut(("A", "Q"), (0, 0), (1, 0))),
                                 "sheet S1: common cut names part Q, which is not on this sheet"),
}


def _move(nesting, pid, x, y):
    placement = next(p for p in nesting.sheets[0].placements if p.part == pid)
    placement.x, placement.y = x, y


def _check_files(tmp_path, damages):
    from fabline.nest import save_nesting
    from fabline.unroll import save_parts

    nesting, parts = two_rectangles(400, grain=True)
    for damage in damages:
        CHECK_CASES[damage][0](nesting)
    save_parts(parts, tmp_path / "parts.json")
    save_nesting(nesting, tmp_path / "nesting.json")
    return tmp_path / "nesting.json"


@pytest.mark.parametrize("damage", sorted(CHECK_CASES))
def test_nest_check_names_each_kind_of_problem_on_a_line_of_its_own(damage, cli, tmp_path):
    path = _check_files(tmp_path, [damage])
    code, out, err = cli("nest", "--check", path)
    assert code == 1 and err == f"fabline nest: {path}: {CHECK_CASES[damage][1]}\n", err
    assert "FAILED" in out and "1 problems" in out


def test_nest_check_lists_every_problem_not_just_the_first(cli, tmp_path):
    damages = ["overlap", "unknown id", "negative kerf", "placed twice"]
    path = _check_files(tmp_path, damages)
    code, out, err = cli("nest", "--check", path)
    assert code == 1 and sorted(err.splitlines()) == sorted(f"fabline nest: {path}: {CHECK_CASES[d][1]}"
                                                            for d in damages), err
    assert f"{len(damages)} problems" in out


def test_nest_check_refuses_a_nul_byte_in_parts_file(cli, tmp_path):
    path = _check_files(tmp_path, [])
    data = json.loads(path.read_text())
    data["parts_file"] = "parts\0.json"
    path.write_text(json.dumps(data))
    code, out, err = cli("nest", "--check", path)
    assert code == 2 and out == "" and err.count("\n") == 1 and "holds a NUL byte" in err and "parts" in err, err


def test_parts_in_a_rings_hole_fit_by_material_not_by_outline():
    """A ring filling its sheet with a square in its hole: the outlines cover more than the sheet, the material
    does not, so the fit check lets the pair check decide (it finds nothing)."""
    from fabline.nest import Nesting, Placement, Sheet
    from fabline.nest.validate import check_fit
    from fabline.unroll import Part, PartSet

    square = lambda x0, y0, x1, y1: np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]], dtype=float)
    ring = Part("ring", "washer", square(0, 0, 100, 100), holes=[square(10, 10, 90, 90)])
    inner = Part("inner", "washer", square(0, 0, 60, 60))
    sheet = Sheet("S1", 100.0, 100.0, [Placement("ring", 0.0, 0.0, 0.0), Placement("inner", 20.0, 20.0, 0.0)])
    check_fit(Nesting([sheet], "p.json"), PartSet([ring, inner]), "n.json")  # 10000 + 3600 mm² of outline, 7200 of material
    with pytest.raises(FablineError, match="sheet S1"):
        check_fit(Nesting([sheet], "p.json"), PartSet([inner, Part("ring", "washer", square(0, 0, 100, 100))]), "n.json")
