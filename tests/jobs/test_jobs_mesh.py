"""A job that starts from a designer's mesh (issue 29): `model.mesh` with `design asymptotic`'s options traces the
network the command traces, and the report's design stage shows what it covered, left out and why curves stopped.

Truth: the command's own output for the same options (the job adds nothing to the design), trimesh's area of
the mesh, the stops the command printed; every mistake one line naming the key, exit 2.
"""

from __future__ import annotations

import json

import pytest
import trimesh

from fabline.model import load_network
from jobfiles import write
from meshes import hard_mesh, write_mesh

JOB = """
name = "traced"
stages = ["report"]  # unroll, nest and export on a hard mesh: tests/design/test_design_hard.py
[model]
mesh = "neck.obj"
[model.options]
units = "m"
spacing = "70 mm"
[output]
folder = "out"
"""


@pytest.fixture
def neck(tmp_path):
    vertices, faces, _ = hard_mesh("neck")
    return write_mesh(tmp_path / "neck.obj", vertices, faces)


def test_a_job_from_a_mesh_traces_what_the_command_traces_and_reports_the_design(tmp_path, cli, neck):
    code, out, err = cli("design", "asymptotic", "--surface", neck, "--units", "m", "--spacing", "0.07", "--json",
                         "-o", tmp_path / "command.json")
    assert code == 0, err
    printed = json.loads(out)
    code, out, err = cli("run", write(tmp_path, JOB))
    assert code == 0, err
    traced, command = load_network(tmp_path / "out" / "network.json"), load_network(tmp_path / "command.json")
    assert sorted(traced.nodes) == sorted(command.nodes) and len(traced.lamellas) == len(command.lamellas)
    design = json.loads((tmp_path / "out" / "report.json").read_text())["design"]
    coverage = design["coverage"]
    assert coverage["surface_area"] == pytest.approx(trimesh.load(neck).area)
    assert coverage["fraction"] == pytest.approx(printed["quality"]["coverage"]["fraction"])
    assert {s["reason"]: s["ends"] for s in design["stops"]} == \
        {r: [s["reason"] for s in printed["stops"]].count(r) for r in {s["reason"] for s in printed["stops"]}}
    assert len(design["left_out"]) == len(printed["regions"])
    assert f"covers {coverage['fraction'] * 100:.1f} % of its area" in out
    page = (tmp_path / "out" / "report.html").read_text()
    assert "<h2 id=design>" in page and f"it covers {coverage['fraction'] * 100:.1f} %" in page


@pytest.mark.parametrize("old, new, message", [
    ('spacing = "70 mm"\n', "", "model.options.spacing: missing (required)"),
    ('"70 mm"', '"70 parsecs"', "model.options.spacing: unknown unit 'parsecs'"),
    ('"70 mm"', "-0.07", "model.options.spacing: must be a positive length"),
    ('units = "m"', 'units = "m"\nseed = [0.1, 0.2]', "model.options.seed: expected three finite numbers"),
    ('units = "m"', 'units = "furlong"', "model.options.units: 'furlong' is not a unit"),
    ('units = "m"', 'units = "m"\nsize = [1.0, 2.0]', "model.options.size: unknown key (allowed: spacing, step, seed, "
                                                     "supports, units)"),
    ('mesh = "neck.obj"', 'mesh = "neck.obj"\ndesign = "enneper"', "model: give exactly one of model.design"),
    ('mesh = "neck.obj"', 'mesh = "gone.obj"', "model.mesh: file not found"),
    ("[output]", '[lamella]\nmaterials_file = "neck.obj"\n[output]', "lamella.materials_file: not with model.mesh"),
])
def test_a_mesh_job_mistake_is_one_line_naming_the_key(tmp_path, cli, neck, old, new, message):
    assert old in JOB
    code, _, err = cli("run", write(tmp_path, JOB.replace(old, new)))
    assert code == 2 and err.count("\n") == 1, err
    assert f"job.toml: {message}" in err
    assert not (tmp_path / "out").exists()


def test_a_mesh_job_traces_for_its_unroll_stages_pair_spacing(tmp_path, cli):
    """unroll.pair_spacing 60 mm and slot_width 4 mm reach the design: the traced network unrolls with them (traced
    for the default 25 mm pair, unroll at 60 mm refuses this mesh: tests/design/test_design_hard.py)."""
    vertices, faces, _ = hard_mesh("folded-centre")
    write_mesh(tmp_path / "neck.obj", vertices, faces)
    job = JOB.replace('stages = ["report"]', 'stages = ["unroll"]').replace(
        "[output]", '[unroll]\npair_spacing = "60 mm"\nslot_width = "4 mm"\nhardware = false\n[output]')
    code, out, err = cli("run", write(tmp_path, job))
    assert code == 0, err
    parts = json.loads((tmp_path / "out" / "parts.json").read_text())
    assert parts["report"]["options"]["pair_spacing_mm"] == 60.0 and parts["parts"]
