"""`fabline nest` end to end: nesting.json, SVG per sheet, stock write-back, --check, and every bad input."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from fabline.nest import load_nesting, parts_path, validate_nesting
from fabline.nest.synthetic import pavilion_like_parts
from fabline.shop import load_stock
from fabline.unroll import Part, PartSet, load_parts, save_parts


@pytest.fixture(scope="module")
def small_parts(tmp_path_factory):
    folder = tmp_path_factory.mktemp("parts")
    path = folder / "parts.json"
    save_parts(pavilion_like_parts(strip_metres=40, curved=2, washers=60, clamps=20, joints=1, seed=3), path)
    return path


@pytest.fixture(scope="module")
def nested(small_parts, tmp_path_factory):
    """One nesting run through the CLI on a 2 x 1 m sheet, with SVGs."""
    from fabline.cli import main

    out = tmp_path_factory.mktemp("out")
    code = main(["nest", str(small_parts), "-o", str(out / "nesting.json"), "--sheet", "4000x2000", "--kerf", "0.2",
                 "--gap", "3", "--svg", str(out / "sheets"), "--time-limit", "2"])
    assert code == 0
    return out


def test_nest_writes_a_valid_nesting_and_svgs(nested, small_parts):
    nesting = load_nesting(nested / "nesting.json")
    raw = json.loads((nested / "nesting.json").read_text())
    assert raw["schema"] == "fabline.nesting/1"
    for sheet in raw["sheets"]:
        assert {"id", "width", "height", "placements"} <= set(sheet)
        assert all({"part", "x", "y", "rotation"} <= set(p) for p in sheet["placements"])
    parts = load_parts(parts_path(nested / "nesting.json", nesting))
    assert validate_nesting(nesting, parts) == []
    assert sorted(p.part for s in nesting.sheets for p in s.placements) == sorted(p.id for p in parts.parts)
    summary = nesting.summary
    assert summary["sheets_used"] == len(nesting.sheets) >= summary["lower_bound"]["best"]
    svgs = sorted((nested / "sheets").glob("*.svg"))
    assert [p.stem for p in svgs] == [s.id for s in nesting.sheets]
    root = ET.parse(svgs[0]).getroot()
    labels = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    by_id = {p.id: p for p in parts.parts}
    assert sorted(labels) == sorted(by_id[pl.part].label or pl.part for pl in nesting.sheets[0].placements)


def test_check_passes_a_good_nesting_and_fails_a_broken_one(nested, cli, tmp_path):
    code, out, _ = cli("nest", "--check", nested / "nesting.json")
    assert code == 0 and "ok" in out
    data = json.loads((nested / "nesting.json").read_text())
    data["sheets"][0]["placements"].append(dict(data["sheets"][0]["placements"][0]))
    data["parts_file"] = str((nested / "nesting.json").parent / data["parts_file"])
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(data))
    code, out, err = cli("nest", "--check", broken)
    assert code == 1 and "placed 2 times" in err and "FAILED" in out


def test_stock_remnants_first_and_write_back(small_parts, cli, tmp_path):
    stock = tmp_path / "stock.json"
    stock.write_text(json.dumps({"schema": "fabline.stock/1",
                                 "sheets": [{"id": "4x2", "width": 4000, "height": 2000, "count": 10}],
                                 "remnants": [{"id": "R-old", "width": 1500, "height": 800}]}))
    code, out, err = cli("nest", small_parts, "-o", tmp_path / "n.json", "--stock", stock, "--remnants-first",
                         "--stock-out", tmp_path / "after.json", "--time-limit", "2")
    assert code == 0, err
    nesting = load_nesting(tmp_path / "n.json")
    assert nesting.sheets[0].stock == "R-old" and nesting.sheets[0].width == 1500
    after = load_stock(tmp_path / "after.json")
    used = sum(1 for s in nesting.sheets if s.stock == "4x2")
    assert [s.count for s in after if s.id == "4x2"] == [10 - used]
    assert "R-old" not in {s.id for s in after}
    new = [s for s in after if s.remnant]
    assert len(new) == len(nesting.remnants)
    for remnant, item in zip(nesting.remnants, new):
        assert item.id == f"n-{remnant['id']}" and min(item.width, item.height) >= 200


def _write_parts(path, parts):
    save_parts(PartSet(parts), path)
    return path


def _square(pid, side):
    return Part(pid, "clamp", np.array([[0, 0], [side, 0], [side, side], [0, side], [0, 0]], dtype=float))


@pytest.mark.parametrize("case, message", [
    ("too large", "part BIG (5000 x 5000 mm) is larger than every sheet"),
    ("self-intersecting", "part BOW: outline is self-intersecting"),
    ("empty", "no parts"),
    ("negative stock", "sheet neg: width and height must be positive"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(case, message, cli, tmp_path):
    parts = tmp_path / "parts.json"
    extra = []
    if case == "too large":
        _write_parts(parts, [_square("OK", 100), _square("BIG", 5000)])
    elif case == "self-intersecting":
        bow = Part("BOW", "clamp", np.array([[0, 0], [100, 100], [100, 0], [0, 100], [0, 0]], dtype=float))
        _write_parts(parts, [_square("OK", 100), bow])
    elif case == "empty":
        parts.write_text(json.dumps({"schema": "fabline.parts/1", "units": "mm", "parts": []}))
    else:
        _write_parts(parts, [_square("OK", 100)])
        stock = tmp_path / "stock.json"
        stock.write_text(json.dumps({"schema": "fabline.stock/1",
                                     "sheets": [{"id": "neg", "width": -4000, "height": 2000}]}))
        extra = ["--stock", stock]
    out = tmp_path / "out"
    code, stdout, err = cli("nest", parts, "-o", out / "nesting.json", "--svg", out / "svg", *extra)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("fabline nest: error:") and message in err, err
    assert not out.exists()


def test_sheet_size_and_options_are_checked(cli, small_parts, tmp_path):
    code, _, err = cli("nest", small_parts, "-o", tmp_path / "n.json", "--sheet", "4000by2000")
    assert code == 2 and "--sheet" in err
    code, _, err = cli("nest", small_parts, "-o", tmp_path / "n.json", "--gap", "-1")
    assert code == 2 and "--gap" in err
    code, _, err = cli("nest", small_parts)
    assert code == 2 and "-o" in err
    assert not (tmp_path / "n.json").exists()


@pytest.mark.parametrize("fill_holes", [False, True])
def test_small_parts_go_into_large_holes_only_when_allowed(fill_holes, cli, tmp_path):
    parts = pavilion_like_parts(strip_metres=0, curved=0, washers=6, clamps=4, joints=2, seed=5)
    save_parts(parts, tmp_path / "parts.json")
    args = ["--fill-holes"] if fill_holes else []
    code, _, err = cli("nest", tmp_path / "parts.json", "-o", tmp_path / "n.json", "--sheet", "1000x600", *args)
    assert code == 0, err
    nesting = load_nesting(tmp_path / "n.json")
    placements = {p.part: p for s in nesting.sheets for p in s.placements}
    joints = [p for pid, p in placements.items() if pid.startswith("J")]
    small = [p for pid, p in placements.items() if pid[0] in "WC"]
    # The joint's round hole has radius 70 mm about the joint's origin.
    inside = [s.part for j in joints for s in small if np.hypot(s.x - j.x, s.y - j.y) < 70]
    assert (len(inside) == len(joints)) if fill_holes else not inside
    assert validate_nesting(nesting, parts) == []


def test_sheet_svgs_are_one_to_one_with_cut_and_engrave_in_their_layer_colours(nested, small_parts):
    """A 4000 x 2000 mm sheet is a 4000 mm x 2000 mm SVG in mm user units; every placed part is a group with its
    id; its paths are in the documented layer colours and the reference lines in the tool-layer colour."""
    from fabline.shop.layers import LAYERS

    nesting = load_nesting(nested / "nesting.json")
    parts = {p.id: p for p in load_parts(small_parts).parts}
    svg = "{http://www.w3.org/2000/svg}"
    for sheet in nesting.sheets:
        root = ET.parse(nested / "sheets" / f"{sheet.id}.svg").getroot()
        assert (root.get("width"), root.get("height")) == (f"{sheet.width:g}mm", f"{sheet.height:g}mm")
        assert root.get("viewBox") == f"0 0 {sheet.width:g} {sheet.height:g}"
        groups = {g.get("id"): g for g in root.iter(f"{svg}g")}
        assert sorted(groups) == sorted(p.part for p in sheet.placements)
        for part_id, group in groups.items():
            paths = {p.get("class"): p for p in group.iter(f"{svg}path")}
            assert paths["CUT-OUTER"].get("stroke") == LAYERS["CUT-OUTER"].rgb == "#FF0000"
            assert all(p.get("stroke") == LAYERS[name].rgb and p.get("fill") == "none" for name, p in paths.items())
            assert ("ENGRAVE-TEXT" in paths) == bool(parts[part_id].text)
        assert {r.get("stroke") for r in root.iter(f"{svg}rect")} == {LAYERS["SHEET"].rgb}
