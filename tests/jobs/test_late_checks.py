"""Checks that came late or not at all (issue 25, probe items 5 and 12): a file read through another input (the
parts file a nesting names, a design's surface mesh) is an input, never an output; every job key is checked when
the job is loaded, before any stage runs; a supports rule that picks no node is refused."""

from __future__ import annotations

import time

import pytest

from meshes import saddle, write_mesh
from jobfiles import GOOD, write


@pytest.fixture(scope="module")
def nested(tmp_path_factory):
    """A catenoid unrolled into `exp/cutlist.csv` (an export output name in the export folder) and nested."""
    from fabline.cli import main

    folder = tmp_path_factory.mktemp("nested")
    network, nesting = folder / "c.network.json", folder / "c.nesting.json"
    parts = folder / "exp" / "cutlist.csv"
    parts.parent.mkdir()
    assert main(["design", "catenoid", "--waist", "1", "--height", "1.5", "--count", "8", "-o", str(network)]) == 0
    assert main(["unroll", str(network), "-o", str(parts), "--no-hardware"]) == 0
    assert main(["nest", str(parts), "-o", str(nesting), "--time-limit", "2"]) == 0
    return {"nesting": nesting, "parts": parts, "folder": folder}


def refused_unchanged(cli, path, *args, words):
    """`fabline ARGS` refused on one line (exit 2) naming `words`, and `path` byte for byte as it was."""
    before = path.read_bytes()
    code, _, err = cli(*args)
    assert code == 2, err
    assert err.count("\n") == 1 and all(w in err for w in words), err
    assert path.read_bytes() == before


@pytest.mark.parametrize("extra", [["-o", "{exp}"], ["--gcode", "{exp}"], ["-o", "{exp}", "--no-preview"]])
def test_export_does_not_overwrite_the_parts_file_its_nesting_names(cli, nested, extra):
    arguments = [a.format(exp=nested["parts"].parent) for a in extra]
    refused_unchanged(cli, nested["parts"], "export", nested["nesting"], *arguments,
                      words=("cutlist.csv", "is also an input"))


def test_export_parts_file_under_a_sheet_dxf_name_is_refused(cli, nested, tmp_path):
    import json

    nesting = json.loads(nested["nesting"].read_text())
    sheet = nesting["sheets"][0]["id"]
    from fabline.naming import file_stem

    parts = tmp_path / f"n_{file_stem(sheet)}.dxf"
    parts.write_bytes(nested["parts"].read_bytes())
    nesting["parts_file"] = parts.name
    (tmp_path / "n.json").write_text(json.dumps(nesting))
    refused_unchanged(cli, parts, "export", tmp_path / "n.json", "--dxf", tmp_path, words=(parts.name, "is also an input"))


@pytest.fixture
def saddle_obj(tmp_path):
    vertices, faces = saddle()
    return write_mesh(tmp_path / "saddle.obj", vertices, faces)


def test_design_asymptotic_does_not_overwrite_its_surface(cli, saddle_obj):
    refused_unchanged(cli, saddle_obj, "design", "asymptotic", "--surface", saddle_obj, "--spacing", "0.2",
                      "-o", saddle_obj, words=("saddle.obj", "is also an input"))


def test_design_asymptotic_supports_that_pick_no_node_are_refused_as_import_refuses_them(cli, saddle_obj, tmp_path):
    out = tmp_path / "net.json"
    code, _, err = cli("design", "asymptotic", "--surface", saddle_obj, "--spacing", "0.2", "--supports", "z<-1000",
                       "-o", out)
    assert code == 2 and err.count("\n") == 1, err
    assert "--supports 'z<-1000': no node of" in err and "saddle.obj" in err, err
    assert not out.exists()
    code, _, err = cli("design", "asymptotic", "--surface", saddle_obj, "--spacing", "0.2", "--supports", "z<0", "-o", out)
    assert code == 0, err  # a rule that picks nodes still makes supports
    assert '"support"' in out.read_text()


LONG = "a" * 300
PROBE_KEYS = {  # the job text changed, the key the one line must name
    "name": (lambda t: t.replace('name = "small"', f'name = "{LONG}"'), "name: 300 characters"),
    "export.lead_in": (lambda t: t + "[export]\nlead_in = 1e8\n", "export.lead_in:"),
    "export.tab_width": (lambda t: t + '[export]\ntab_width = "5 m"\n', "export.tab_width:"),
    "machine.time_scale": (lambda t: t + "[machine]\ntime_scale = 1e308\n", "machine.time_scale:"),
    "machine.port": (lambda t: t + '[machine]\nport = "sim://grbl?machine=/etc/passwd"\n', "machine.port:"),
    "machine.ports": (lambda t: t + '[machine]\nports = ["sim://a", "sim://b?time_scale=1e308"]\n', "machine.ports:"),
    "model.options.size": (lambda t: t.replace("size = [2.0, 2.5]", "size = [1, 2, 3]"),
                           "model.options.size: expected 2 values, got 3"),
}


@pytest.mark.parametrize("key", sorted(PROBE_KEYS))
def test_a_bad_job_key_is_refused_before_any_stage_runs(cli, tmp_path, key):
    change, words = PROBE_KEYS[key]
    path = write(tmp_path, change(GOOD))
    start = time.perf_counter()
    code, out, err = cli("run", path)
    took = time.perf_counter() - start
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith(f"fabline run: error: job.toml: {words}"), err
    assert took < 1.0, took
    assert not (tmp_path / "out").exists()


def test_sim_port_machine_option_takes_a_profile_name():
    from fabline.errors import FablineError
    from fabline.link.ports import check_port

    assert check_port("sim://x?machine=grbl-laser&time_scale=100") == []
    for url, words in (("sim://x?machine=/etc/passwd", "not a machine profile's name"),
                       ("sim://x?time_scale=0", "time_scale must be above 0"),
                       ("sim://x?time_scale=fast", "not a number")):
        with pytest.raises(FablineError, match=words):
            check_port(url)
