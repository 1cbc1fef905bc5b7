"""Data integrity (issue 16, items 3, 5, 6, 7): sheet ids that collide as file names, nestings that export must
not trust, `nest --check` gaps, and network models that `import` wrote although `inspect` and `unroll` refuse them."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fabline.nest.layout import CommonCut, Placement, Sheet, save_nesting
from fabline.unroll.parts import Part, PartSet, save_parts

from export_helpers import every_kind_nesting, every_kind_partset


def _files(folder):
    return sorted(p.name for p in folder.rglob("*")) if folder.exists() else []


def _job(folder, nesting=None, partset=None):
    save_parts(partset or every_kind_partset(), folder / "parts.json")
    save_nesting(nesting or every_kind_nesting(), folder / "nesting.json")
    return folder / "nesting.json"


@pytest.mark.parametrize("first, second", [("S001", "S001"), ("s001", "S001")])
def test_sheet_ids_that_map_to_one_file_name_are_refused_by_check_and_export(first, second, cli, tmp_path):
    nesting = every_kind_nesting()
    nesting.sheets[0].id = first
    nesting.sheets.append(Sheet(second, 4000.0, 2000.0, []))
    path = _job(tmp_path, nesting)
    before = _files(tmp_path)
    for command in (["nest", "--check", path], ["export", path, "--gcode", tmp_path / "g", "--dxf", tmp_path / "d"]):
        code, _, err = cli(*command)
        assert code == 2 and err.count("\n") == 1 and f"sheet {second}: collides with" in err, err
    assert _files(tmp_path) == before


@pytest.mark.parametrize("first, second", [("S_001", "S/001"), ("a b", "a_b")])
def test_sheet_ids_that_sanitise_alike_export_to_files_of_their_own(first, second, cli, tmp_path):
    """Issue 25: an id that is not a file name as it is gets a hash of itself, so it never takes another's file."""
    nesting = every_kind_nesting()
    nesting.sheets[0].id = first
    nesting.sheets.append(Sheet(second, 4000.0, 2000.0, []))
    code, _, err = cli("export", _job(tmp_path, nesting), "--gcode", tmp_path / "g")
    assert code == 0, err
    programs = sorted(p.name for p in (tmp_path / "g").glob("*.gcode"))
    assert len(programs) == 2 and all("/" not in name and " " not in name for name in programs), programs


def _overlap(nesting, partset):
    nesting.sheets[0].placements[1] = Placement("B", 40, 40)


def _twice(nesting, partset):
    nesting.sheets[0].placements.append(Placement("W", 3500, 1500))


def _off_sheet(nesting, partset):
    nesting.sheets[0].placements[3] = Placement("W", 3990, 1000)


def _bow_tie(nesting, partset):
    partset.parts.append(Part("X", "washer", np.array([[0, 0], [50, 50], [50, 0], [0, 50], [0, 0]], float)))
    nesting.sheets[0].placements.append(Placement("X", 3500, 1500))


def _zero_area(nesting, partset):
    partset.parts.append(Part("Z", "washer", np.array([[0, 0], [0, 0], [0, 0], [0, 0]], float)))
    nesting.sheets[0].placements.append(Placement("Z", 3500, 1500))


BROKEN = {"overlap": (_overlap, "parts A and B overlap"), "placed twice": (_twice, "part W: placed 2 times"),
          "off the sheet": (_off_sheet, "part W lies outside the usable area"),
          "bow-tie outline": (_bow_tie, "part X: outline crosses itself"),
          "zero-area outline": (_zero_area, "part Z: outline encloses no area")}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_export_refuses_a_nesting_the_validator_rejects_and_writes_nothing(case, cli, tmp_path):
    nesting, partset = every_kind_nesting(), every_kind_partset()
    breaking, message = BROKEN[case]
    breaking(nesting, partset)
    path = _job(tmp_path, nesting, partset)
    code, _, err = cli("export", path, "--gcode", tmp_path / "g", "--dxf", tmp_path / "d")
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "g").exists() and not (tmp_path / "d").exists()
    code, out, err = cli("nest", "--check", path)
    assert code == 1 and message in err and "FAILED" in out


def _common_cut_elsewhere(nesting, partset):
    nesting.sheets[0].common_cuts.append(CommonCut(("A", "NOPE"), (0.0, 0.0), (10.0, 0.0)))


def _negative(field):
    def edit(nesting, partset):
        setattr(nesting, field, -0.5)
    return edit


CHECK = {"negative kerf": (_negative("kerf"), "kerf is -0.5 mm: must not be negative"),
         "negative gap": (_negative("gap"), "gap is -0.5 mm: must not be negative"),
         "common cut of a part not on the sheet": (_common_cut_elsewhere, "common cut names part NOPE, which is not on this sheet"),
         "degenerate outline": (_zero_area, "outline encloses no area")}


@pytest.mark.parametrize("case", sorted(CHECK))
def test_nest_check_refuses(case, cli, tmp_path):
    nesting, partset = every_kind_nesting(), every_kind_partset()
    breaking, message = CHECK[case]
    breaking(nesting, partset)
    code, out, err = cli("nest", "--check", _job(tmp_path, nesting, partset))
    assert code == 1 and message in err and "FAILED" in out, out + err


def test_an_empty_sheet_list_is_a_one_line_error(cli, tmp_path):
    path = _job(tmp_path)
    data = json.loads(path.read_text())
    path.write_text(json.dumps({**data, "sheets": []}))
    for command in (["nest", "--check", path], ["export", path, "--gcode", tmp_path / "g"]):
        code, _, err = cli(*command)
        assert code == 2 and err.count("\n") == 1 and "'sheets' is empty" in err, err


@pytest.fixture(scope="module")
def small_model(tmp_path_factory):
    from fabline.model import save_network
    from fabline.model.designs import catenoid_network

    path = tmp_path_factory.mktemp("model") / "c.json"
    save_network(catenoid_network(waist=1.0, height=1.5, count=8), path)
    return json.loads(path.read_text())


def _node_off(data):
    lamella = data["lamellas"][0]
    node = next(n for n in data["nodes"] if n["id"] == lamella["nodes"][1])
    node["xyz"] = [x + 2.0 * n for x, n in zip(node["xyz"], node["normal"])]  # 2 m along its normal


def _reversed(data):
    data["lamellas"][0]["nodes"].reverse()


def _two_point(data):
    lamella = data["lamellas"][0]
    lamella["curve"], lamella["normals"] = lamella["curve"][::len(lamella["curve"]) - 1], lamella["normals"][::len(lamella["normals"]) - 1]


def _no_nodes(data):
    data["lamellas"][0]["nodes"] = []


def _figure_8(data):
    """One planar figure 8 (x = sin t, y = sin 2t / 2 crosses itself at t = 0 and pi) between two edge ends."""
    t = np.linspace(-0.6, np.pi + 0.6, 300)
    curve = np.stack([np.sin(t), np.sin(2 * t) / 2, 0 * t], axis=1)
    data["nodes"] = [{"id": "a", "xyz": curve[0].tolist(), "normal": [0, 0, 1], "kind": "edge-end"},
                     {"id": "b", "xyz": curve[-1].tolist(), "normal": [0, 0, 1], "kind": "edge-end"}]
    data["lamellas"] = [{"id": "L", "family": "A", "nodes": ["a", "b"], "curve": curve.tolist(),
                         "normals": [[0, 0, 1]] * len(curve)}]


MODELS = {"node 2 m off its lamella": (_node_off, "lies 2000.00 mm off its centreline"),
          "reversed node order": (_reversed, "are not in order along the curve"),
          "two-point lamella": (_two_point, "off its centreline"),
          "lamella with no nodes": (_no_nodes, "lists no nodes"),
          "figure-8 lamella": (_figure_8, "lamella L: curve overlaps itself")}


@pytest.mark.parametrize("case", sorted(MODELS))
def test_import_inspect_and_unroll_refuse_the_same_models(case, small_model, cli, tmp_path):
    data = copy.deepcopy(small_model)
    breaking, message = MODELS[case]
    breaking(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    for command in (["import", path, "-o", tmp_path / "out.json"], ["inspect", path],
                    ["unroll", path, "-o", tmp_path / "parts.json"]):
        code, out, err = cli(*command)
        assert code == 2 and err.count("\n") == 1 and message in err, (command, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json"]
