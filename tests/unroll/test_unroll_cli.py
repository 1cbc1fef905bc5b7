"""`fabline unroll` end to end: parts.json and SVG previews, and every bad input of the issue named with its numbers."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from fabline.model import save_network
from fabline.unroll import load_parts
from networks import network_of, polar_grid


def square_grid(spacing: float, count: int, angle_deg: float = 90.0):
    """Straight lamellas in the plane z = 0: family A along x, family B at `angle_deg` to it; nodes at the crossings."""
    direction = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg)), 0.0])
    along = np.array([1.0, 0.0, 0.0])
    curves = []
    steps = np.linspace(0.0, 1.0, 10 * (count - 1) + 1)
    for j in range(count):
        base = j * spacing * direction
        points = base + np.outer(steps * spacing * (count - 1), along)
        curves.append((f"A-{j:03d}", "A", points, np.tile([0.0, 0.0, 1.0], (len(steps), 1)), list(range(0, len(steps), 10))))
    for i in range(count):
        base = i * spacing * along
        points = base + np.outer(steps * spacing * (count - 1), direction)
        curves.append((f"B-{i:03d}", "B", points, np.tile([0.0, 0.0, 1.0], (len(steps), 1)), list(range(0, len(steps), 10))))
    return network_of(curves, "grid")


@pytest.fixture
def polar_model(tmp_path):
    path = tmp_path / "polar.network.json"
    save_network(polar_grid(3000.0 + 350.0 * np.arange(4), 0.1 * np.arange(8)), path)
    return path


def test_unroll_writes_parts_and_previews(cli, tmp_path, polar_model):
    out, svg = tmp_path / "parts.json", tmp_path / "preview"
    code, stdout, stderr = cli("unroll", polar_model, "-o", out, "--profile", "100x1.5", "--material", "steel-s235",
                               "--svg", svg)
    assert code == 0, stderr
    assert "A-000" in stdout and "B-007" in stdout and "max utilisation" in stdout
    partset = load_parts(out)
    strips = [p for p in partset.parts if p.kind == "strip"]
    assert len(strips) == 2 * (4 + 8)
    assert {p.kind for p in partset.parts} == {"strip", "washer", "clamp"}
    drawings = sorted(svg.glob("*.svg"))
    assert len(drawings) == len(strips)
    root = ET.parse(drawings[0]).getroot()
    layers = {g.get("id"): g for g in root.iter("{http://www.w3.org/2000/svg}g")}
    part = next(p for p in strips if p.id == drawings[0].stem)
    assert len(layers["cut"]) == 1 + len(part.holes)
    assert len(layers["marks"]) == len(part.marks) and len(layers["text"]) == len(part.text)
    code, stdout, _ = cli("unroll", polar_model, "-o", out, "--pair-spacing", "0", "--no-hardware", "--json")
    report = json.loads(stdout)
    assert report["summary"]["strips"] == 12 and report["summary"]["parts_by_kind"] == {"strip": 12}


def run_bad(cli, tmp_path, network, *extra):
    model, out = tmp_path / "bad.network.json", tmp_path / "parts.json"
    save_network(network, model)
    code, stdout, stderr = cli("unroll", model, "-o", out, *extra)
    return code, stderr, out


def test_nodes_too_close_for_a_slot_pair(cli, tmp_path):
    code, err, out = run_bad(cli, tmp_path, square_grid(20.0, 12))
    assert code == 2 and not out.exists()
    assert "lamella A-000, strip A-000-L: slots at nodes" in err and "5.00 mm apart" in err and "at least 6.00 mm" in err


def test_a_lamella_shorter_than_one_seam_overlap_is_one_strip_without_a_seam(cli, tmp_path):
    # 100 mm between its two nodes, shorter than the 150 mm overlap (once refused: a traced design's short lamellas
    # stopped the unroll): the strip runs 12.5 mm (half the pair spacing) past the crossing strips and 50 mm (h/2) on
    code, err, out = run_bad(cli, tmp_path, square_grid(100.0, 2))
    assert code == 0, err
    strip = next(part for part in json.loads(out.read_text())["parts"] if part["id"] == "A-000-L")
    assert strip["meta"]["segments"] == 1 and strip["meta"]["joins"] == {"start": None, "end": None}
    assert strip["meta"]["length_mm"] == pytest.approx(100.0 + 2 * (12.5 + 50.0))
    assert [node["s"] for node in strip["nodes"]] == pytest.approx([62.5, 162.5])


def test_crossing_angle_under_the_joint_limit(cli, tmp_path):
    code, err, out = run_bad(cli, tmp_path, square_grid(350.0, 3, angle_deg=20.0))
    assert code == 2 and not out.exists()
    assert "cross at 20.0 degrees, under the 30 degrees" in err and "lamellas A-" in err


def test_profile_too_thick_for_the_curvature_warns_or_fails(cli, tmp_path):
    network = polar_grid(1200.0 + 350.0 * np.arange(3), 0.25 * np.arange(5))
    code, err, out = run_bad(cli, tmp_path, network, "--profile", "100x4")  # r_min = E t / (2 f_y) = 1787 mm
    assert code == 0 and out.exists()
    assert "warning: lamella A-000, nodes" in err and "bending radius 1200 mm is below the minimum 1787 mm" in err
    out.unlink()
    code, err, out = run_bad(cli, tmp_path, network, "--profile", "100x4", "--strict")
    assert code == 2 and not out.exists() and "bending radius 1200 mm" in err


@pytest.mark.parametrize("args, message", [
    (("--profile", "1.5x100"), "not smaller than height"),
    (("--material", "wood"), "'wood' is not known"),
    (("--pair-spacing", "2"), "--pair-spacing: 2 mm leaves no room"),
    (("--overlap", "0"), "--overlap: must be positive"),
    (("--screw-hole", "500"), "--screw-hole: 500 mm does not fit a seam of the 100 mm strip with a 100 mm overlap"),
])
def test_bad_options(cli, tmp_path, polar_model, args, message):
    out = tmp_path / "parts.json"
    code, _, err = cli("unroll", polar_model, "-o", out, *args)
    assert code == 2 and message in err and not out.exists()


def test_bad_model_file(cli, tmp_path):
    model = tmp_path / "broken.json"
    model.write_text("{\n  nope")
    code, _, err = cli("unroll", model, "-o", tmp_path / "parts.json")
    assert code == 2 and "broken.json:2" in err


def test_unreadable_materials_file_is_one_line(cli, tmp_path, polar_model):
    materials = tmp_path / "materials.toml"
    materials.write_bytes(b"[steel]\nE = \xff\xfe\n")  # not UTF-8
    out = tmp_path / "parts.json"
    code, _, err = cli("unroll", polar_model, "-o", out, "--materials", materials)
    assert code == 2 and err.count("\n") == 1 and f"{materials}: cannot read" in err and not out.exists()
