"""The fabline.network/1 format: round trip, the design command, and every bad input named on one line."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fabline.model import load_network, network_to_dict, save_network
from fabline.model.designs import catenoid_network


@pytest.fixture(scope="module")
def small():
    return network_to_dict(catenoid_network(waist=1.0, height=1.5, count=6))


def test_json_round_trip_keeps_everything_within_a_micrometre(tmp_path, catenoid):
    path = tmp_path / "c.network.json"
    save_network(catenoid, path)
    again = load_network(path)
    assert again.units == "m" and list(again.nodes) == list(catenoid.nodes)
    for nid, node in catenoid.nodes.items():
        assert np.abs(again.nodes[nid].xyz - node.xyz).max() * 1000 < 1e-6
        assert again.nodes[nid].kind == node.kind
    for a, b in zip(again.lamellas, catenoid.lamellas):
        assert (a.id, a.family, a.nodes) == (b.id, b.family, b.nodes)
        assert np.abs(a.curve - b.curve).max() * 1000 < 1e-6


def test_design_command_writes_a_valid_model(cli, tmp_path):
    out = tmp_path / "e.network.json"
    code, stdout, _ = cli("design", "enneper", "--size", "6x8", "--spacing", "0.5", "-o", out)
    assert code == 0 and "nodes" in stdout
    network = load_network(out)
    assert network.units == "m" and len(network.nodes) > 50
    code, stdout, _ = cli("inspect", out)
    assert code == 0 and "crossing angles 90.00..90.00" in stdout


def test_inspect_json_table(cli, tmp_path, small):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(small))
    code, stdout, _ = cli("inspect", path, "--json")
    rows = json.loads(stdout)["lamellas"]
    assert code == 0 and len(rows) == len(small["lamellas"])
    assert all(abs(r["min_angle"] - 90) < 0.1 for r in rows)


def _break(data, how):
    data = copy.deepcopy(data)
    lam, node = data["lamellas"][1], data["nodes"][2]
    if how == "missing normals":
        del lam["normals"]
    elif how == "nan":
        node["xyz"][1] = float("nan")
    elif how == "infinite":
        lam["curve"][3][0] = float("inf")
    elif how == "zero length":
        lam["curve"] = [lam["curve"][0]] * len(lam["curve"])
    elif how == "self-overlapping":
        lam["curve"] = lam["curve"] + lam["curve"][::-1][1:]
        lam["normals"] = lam["normals"] + lam["normals"][::-1][1:]
    elif how == "looping":  # one and a quarter turns of a circle: the second pass runs over the first
        t = 2 * np.pi * np.arange(100) / 80
        lam["curve"] = np.stack([np.cos(t), np.sin(t), 0 * t], axis=1).tolist()
        lam["normals"] = [[0.0, 0.0, 1.0]] * 100
        lam["nodes"] = []
    elif how == "duplicate node id":
        data["nodes"][3]["id"] = node["id"]
    elif how == "duplicate lamella id":
        data["lamellas"][2]["id"] = lam["id"]
    elif how == "node on no lamella":
        data["nodes"].append(dict(node, id="LOOSE"))
    elif how == "node off its curve":
        node["xyz"][2] += 0.5  # metres: half a metre off the lamellas through it
    elif how == "unknown units":
        data["units"] = "furlong"
    elif how == "missing units":
        del data["units"]
    elif how == "unknown node":
        lam["nodes"][1] = "NOPE"
    elif how == "bad family":
        lam["family"] = "C"
    elif how == "meta not an object":
        data["meta"] = [1]
    return data


CASES = {
    "missing normals": "lamella A-001: missing 'normals'",
    "nan": "contains NaN",
    "infinite": "curve point 3 contains NaN or infinite",
    "zero length": "zero length",
    "self-overlapping": "doubles back",
    "looping": "curve overlaps itself",
    "duplicate node id": "duplicate node id",
    "duplicate lamella id": "duplicate lamella id",
    "node on no lamella": "node LOOSE lies on no lamella",
    "node off its curve": "off its centreline",
    "unknown units": "unknown units 'furlong'",
    "missing units": "missing 'units'",
    "unknown node": "refers to node NOPE",
    "bad family": "unknown family 'C'",
    "meta not an object": "'meta' must be an object",
}


@pytest.mark.parametrize("how", sorted(CASES))
def test_bad_model_is_named_on_one_line_with_exit_2(cli, tmp_path, small, how):
    path = tmp_path / "bad.network.json"
    path.write_text(json.dumps(_break(small, how)))
    code, stdout, stderr = cli("inspect", path)
    assert code == 2 and stdout == ""
    assert stderr.count("\n") == 1 and str(path) in stderr and CASES[how] in stderr, stderr


def test_malformed_json_names_the_line(cli, tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{\n "schema": "fabline.network/1",\n "units": "m",\n "nodes": [,]\n}\n')
    code, _, stderr = cli("inspect", path)
    assert code == 2 and f"{path}:4:" in stderr and "malformed JSON" in stderr


def test_failed_design_writes_nothing(cli, tmp_path):
    out = tmp_path / "never.json"
    code, _, stderr = cli("design", "enneper", "--size", "40x60", "-o", out)
    assert code == 2 and "overlaps itself" in stderr
    assert not out.exists() and not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, expected", [
    (("enneper", "--spacing", "100"), "spacing 100 m leaves 1 node along a grid line"),
    (("enneper", "--spacing", "0.0001"), "spacing 0.0001 m makes a 120001 x 89999 grid"),
    (("helicoid", "--spacing", "1e-5"), "spacing 1e-05 m makes a"),
    (("catenoid", "--count", "100000"), "count 100000 (height 3 m, waist 1 m) makes a"),
    (("enneper", "--spacing", "nan"), "argument --spacing: expected a number in m or with a unit"),
])
def test_design_grid_too_coarse_or_too_large_is_one_line(cli, tmp_path, args, expected):
    out = tmp_path / "never.json"
    code, stdout, stderr = cli("design", *args, "-o", out)
    assert code == 2 and stdout == "" and stderr.count("\n") == 1 and expected in stderr, stderr
    assert not list(tmp_path.iterdir())
