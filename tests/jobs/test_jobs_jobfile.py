"""Job files: the example parses, and every bad input is one line naming the key path, exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from fabline.errors import FablineError
from fabline.fileio import TOML_DEPTH, parse_toml
from fabline.jobs.jobfile import DEFAULT_STAGES, load_job_file
from jobfiles import GOOD, write

REPO = Path(__file__).resolve().parents[2]

def test_example_job_parses_with_defaults_filled_in():
    spec = load_job_file(REPO / "jobs" / "pavilion.toml")
    assert spec.name == "pavilion"
    assert spec.model == {"design": "enneper", "options": {"size": (9.0, 12.0), "spacing": 0.35, "k_max": 1.05}}
    assert spec.machine["ports"] == [f"sim://grbl-{k}" for k in range(1, 7)]
    assert spec.stages == ("unroll", "assembly", "nest", "export", "stream", "survey", "report")
    assert spec.survey == {"result": None, "simulate": True, "photos": 12, "resolution": "3600x2400", "coverage": 0.7,
                           "sag_mm": 40.0, "seed": 1, "tolerance_mm": 20.0, "reference": "all", "scale_bars": 2,
                           "plan": False}
    assert spec.output_folder == (REPO / "out" / "pavilion").resolve()


def test_defaults_and_relative_paths(tmp_path):
    spec = load_job_file(write(tmp_path, GOOD))
    assert spec.machine["ports"] == ["sim://grbl"]
    assert spec.stages == DEFAULT_STAGES
    assert spec.lamella == {"material": "stainless", "profile": "100x1.5", "materials_file": None}
    assert spec.output_folder == (tmp_path / "out").resolve()
    assert spec.output("gcode/a.gcode") == (tmp_path / "out" / "gcode" / "a.gcode").resolve()


def test_required_keys(tmp_path):
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, GOOD.replace('name = "small"', "")))
    assert str(err.value) == "job.toml: name: missing (required)"
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, GOOD.replace('folder = "out"', 'report = "r.html"')))
    assert str(err.value) == "job.toml: output.folder: missing (required)"


@pytest.mark.parametrize("extra, message", [
    ("colour = 3", "job.toml: colour: unknown key"),
    ("[machine]\nspeed = 3", "job.toml: machine.speed: unknown key"),
    ("[machine]\nport = 7", "job.toml: machine.port: expected a string, got integer 7"),
    ("[machine]\nports = [\"sim://a\", 3]", "job.toml: machine.ports[1]: expected a string, got integer 3"),
    ("[machine]\nports = []", "job.toml: machine.ports: give at least one port"),
    ("[machine]\nports = [\"sim://a\", \"sim://a\"]", "job.toml: machine.ports: a port is listed twice"),
    ("[machine]\nport = \"sim://a\"\nports = [\"sim://b\"]", "job.toml: machine: give machine.port or machine.ports"),
    ("[machine]\ntime_scale = \"fast\"", "job.toml: machine.time_scale: expected a number, got string 'fast'"),
    ("[machine]\ntime_scale = -1.0", "job.toml: machine.time_scale: time_scale must be above 0"),
    ("[machine]\nprofile = \"laser9000\"", "job.toml: machine.profile: unknown machine 'laser9000'"),
    ("[machine]\nprofile = \"missing.toml\"", "job.toml: machine.profile: file not found"),
    ("[stock]\nsheet = \"4000by2000\"", "job.toml: stock.sheet:"),
    ("[stock]\nfile = \"stock.json\"", "job.toml: stock.file: file not found"),
    ("[stock]\ncount = true", "job.toml: stock.count: expected an integer, got boolean True"),
    ("[lamella]\nprofile = \"1.5x100\"", "job.toml: lamella.profile:"),
    ("[lamella]\nmaterial = \"unobtainium\"", "job.toml: lamella.material: unknown material 'unobtainium'"),
    ("[nest]\ngap = -1", "job.toml: nest.gap: must be a finite number, not negative"),
    ("[nest]\nkerf = nan", "job.toml: nest.kerf: must be a finite number, not negative"),
    ("[nest]\nrotations = 3", "job.toml: nest.rotations: must be one of 1, 2, 4, 8, 12, 24, 36, 72, got 3"),
    ("[machine]\nports = [\"sim://a\", \"foo://bar\"]", "job.toml: machine.ports: port foo://bar: unknown scheme foo://"),
    ("[survey]\nresult = \"survey.json\"", "job.toml: survey.result: file not found"),
    ("[survey]\nsimulate = \"yes\"", "job.toml: survey.simulate: expected true or false, got string 'yes'"),
    ("[survey]\nsimulate = true\nlens = 35", "job.toml: survey.lens: unknown key (allowed: result, simulate, photos"),
    ("[survey]\nsimulate = true\nphotos = 6.5", "job.toml: survey.photos: expected an integer, got number 6.5"),
    ("[survey]\nsimulate = true\nphotos = 1", "job.toml: survey.photos: must be at least 2, got 1"),
    ("[survey]\nsimulate = true\nresolution = 3000", "job.toml: survey.resolution: expected a string, got integer 3000"),
    ("[survey]\nsimulate = true\nresolution = \"3000 by 2000\"",
     "job.toml: survey.resolution: '3000 by 2000': expected WIDTHxHEIGHT in pixels"),
    ("[survey]\nsimulate = true\nresolution = \"48x48\"", "job.toml: survey.resolution: '48x48': must be at least 64x64"),
    ("[survey]\nsimulate = true\ncoverage = 3", "job.toml: survey.coverage: must be in (0, 2], got 3.0"),
    ("[survey]\nsimulate = true\nsag_mm = -5", "job.toml: survey.sag_mm: must not be negative, got -5.0"),
    ("[survey]\nsimulate = true\nsag_mm = \"a lot\"", "job.toml: survey.sag_mm: expected a number in mm or with a unit: 3mm, 0.2 mm, 25 cm, 4m, 1in; got 'a lot'"),
    ("[survey]\nsimulate = true\nseed = -1", "job.toml: survey.seed: must not be negative, got -1"),
    ("[survey]\nsimulate = true\ntolerance_mm = 0", "job.toml: survey.tolerance_mm: must be positive, got 0.0"),
    ("[survey]\nsimulate = true\nreference = \"corners\"",
     "job.toml: survey.reference: 'corners' must be 'all' or 'supports'"),
    ("[survey]\nsimulate = true\nscale_bars = 3", "job.toml: survey.scale_bars: must be 0, 1 or 2, got 3"),
    ("[survey]\nphotos = 8", "job.toml: survey.photos: only with survey.simulate = true"),
    ("survey = 3", "job.toml: survey: expected a table, got integer"),
    ("stages = [\"survey\", \"report\"]", "job.toml: stages: 'survey' needs survey.simulate = true"),
    ("stages = [\"unroll\", \"polish\"]", "job.toml: stages[1]: unknown stage 'polish'"),
    ("stages = \"unroll\"", "job.toml: stages: expected a list, got string 'unroll'"),
    ("stages = [\"unroll\", \"export\"]", "job.toml: stages: 'export' needs 'nest' in the same job"),
    ("machine = 3", "job.toml: machine: expected a table, got integer"),
])
def test_bad_keys_name_the_key_path(tmp_path, extra, message):
    top, _, table = extra.partition("\n")
    text = (extra + "\n" + GOOD) if not top.startswith("[") else (GOOD + "\n" + extra + "\n")
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, text))
    assert str(err.value).startswith(message), str(err.value)
    assert "\n" not in str(err.value)


def test_survey_settings_and_stages(tmp_path):
    """`survey.simulate` adds the survey stage to the default stages (after stream, before report), defaults filled in."""
    spec = load_job_file(write(tmp_path, GOOD + "\n[survey]\nsimulate = true\nphotos = 8\n"))
    assert spec.stages == ("unroll", "nest", "export", "stream", "survey", "report")
    assert spec.survey == {"result": None, "simulate": True, "photos": 8, "resolution": "3600x2400", "coverage": 0.7,
                           "sag_mm": 25.0, "seed": 1, "tolerance_mm": 20.0, "reference": "all", "scale_bars": 0,
                           "plan": False}
    spec = load_job_file(write(tmp_path, 'stages = ["report", "survey"]\n' + GOOD + "\n[survey]\nsimulate = true\n"))
    assert spec.stages == ("survey", "report")
    assert load_job_file(write(tmp_path, GOOD)).survey == {"result": None, "simulate": False}


def test_survey_simulate_needs_the_stage_and_excludes_a_result(tmp_path):
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, 'stages = ["report"]\n' + GOOD + "\n[survey]\nsimulate = true\n"))
    assert str(err.value) == "job.toml: survey.simulate: true but 'survey' is not in stages"
    (tmp_path / "survey.json").write_text('{"schema": "fabline.survey/1"}', encoding="utf-8")
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, GOOD + '\n[survey]\nsimulate = true\nresult = "survey.json"\n'))
    assert str(err.value) == ("job.toml: survey: give survey.result (an existing survey) or survey.simulate = true, "
                              "not both")
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, GOOD + '\n[survey]\nresult = "survey.json"\n'))
    assert str(err.value) == (f"job.toml: survey.result: {tmp_path / 'survey.json'}: not a complete fabline.survey/1 "
                              "record (missing 'tolerance_mm')")


@pytest.mark.parametrize("model, message", [
    ('[model]\ndesign = "torus"', "job.toml: model.design: unknown design 'torus'"),
    ('[model]\nfile = "nope.network.json"', "job.toml: model.file: file not found"),
    ('[model]\ndesign = "enneper"\nfile = "x.json"', "job.toml: model: give exactly one of"),
    ('[model]\ndesign = "enneper"\n[model.options]\nsizes = [1.0, 2.0]', "job.toml: model.options.sizes: unknown option"),
    ('[model]\ndesign = "enneper"\n[model.options]\nspacing = "wide"', "job.toml: model.options.spacing: expected a number"),
    ('[model]\ndesign = "enneper"\n[model.options]\nsize = [1.0, "x"]', "job.toml: model.options.size[1]: expected a number"),
])
def test_bad_model(tmp_path, model, message):
    text = 'name = "m"\n[output]\nfolder = "out"\n' + model + "\n"
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, text))
    assert str(err.value).startswith(message), str(err.value)


@pytest.mark.parametrize("report", ["../escape.html", "/tmp/abs.html", "sub/../../up.html"])
def test_outputs_outside_the_output_folder_are_refused(tmp_path, report):
    text = GOOD.replace('folder = "out"', f'folder = "out"\nreport = "{report}"')
    with pytest.raises(FablineError, match="outside the output folder"):
        load_job_file(write(tmp_path, text))


def test_symlink_escaping_the_output_folder_is_refused(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "out" / "link").symlink_to(tmp_path / "elsewhere")
    text = GOOD.replace('folder = "out"', 'folder = "out"\nreport = "link/report.html"')
    with pytest.raises(FablineError, match="outside the output folder"):
        load_job_file(write(tmp_path, text))


def test_bad_name_and_malformed_toml(tmp_path):
    with pytest.raises(FablineError, match="job.toml: name: '../x' must be letters"):
        load_job_file(write(tmp_path, GOOD.replace('name = "small"', 'name = "../x"')))
    with pytest.raises(FablineError, match="job.toml: malformed TOML"):
        load_job_file(write(tmp_path, GOOD + "\n[[[\n"))
    with pytest.raises(FablineError, match="nothere.toml: file not found"):
        load_job_file(tmp_path / "nothere.toml")


def test_toml_nested_past_the_bound_is_refused_in_one_line_naming_the_file(tmp_path):
    """Issue 25: 5000 nested arrays (or inline tables) in a job file ended in tomllib's RecursionError."""
    arrays = TOML_DEPTH - 1  # the document is a level: 31 arrays in it make 32
    assert parse_toml("a = " + "[" * arrays + "]" * arrays, "t.toml")
    with pytest.raises(FablineError, match=f"^t.toml: nested deeper than {TOML_DEPTH} levels"):
        parse_toml("a = " + "[" * (arrays + 1) + "]" * (arrays + 1), "t.toml")
    for text in ("a = " + "[" * 5000 + "]" * 5000, "a = " + "{a=" * 5000 + "1" + "}" * 5000,
                 "[" + ".".join(["a"] * 40) + "]"):
        with pytest.raises(FablineError, match=f"job.toml: nested deeper than {TOML_DEPTH} levels"):
            load_job_file(write(tmp_path, GOOD + "\n" + text))


def test_cli_bad_design_options_exit_2_and_write_nothing(tmp_path, cli):
    path = write(tmp_path, GOOD.replace("size = [2.0, 2.5]", "size = [40.0, 60.0]"))
    code, out, err = cli("run", path)
    assert code == 2 and err.startswith("fabline run: error: job.toml: model: design enneper:")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("extra, message", [
    ("[machine]\nport = 7", "job.toml: machine.port: expected a string, got integer 7"),
    ("[survey]\nsimulate = true\nphotos = \"twelve\"", "job.toml: survey.photos: expected an integer, got string 'twelve'"),
])
def test_cli_bad_job_file_exits_2_with_one_line_and_writes_nothing(tmp_path, cli, extra, message):
    path = write(tmp_path, GOOD + "\n" + extra + "\n")
    code, out, err = cli("run", path)
    assert code == 2
    assert err == f"fabline run: error: {message}\n"
    assert not (tmp_path / "out").exists()


def test_simulated_machines_are_set_up_like_the_machine_profile(tmp_path):
    from fabline.jobs.pipeline import machine_ports
    from fabline.link.protocol_sim import simulator_from_options

    text = GOOD + '[machine]\ntime_scale = 50.0\nports = ["sim://a", "sim://b?time_scale=5&settings=110:900", "/dev/ttyUSB0"]\n'
    simulated, own, serial = machine_ports(load_job_file(write(tmp_path, text)))
    controller = simulator_from_options(simulated.split("?", 1)[1])
    try:
        assert controller.time_scale == 50 and {n: controller.settings[n] for n in (110, 120, 32)} == {
            110: 12000, 120: 800, 32: 1}
    finally:
        controller.close()
    controller = simulator_from_options(own.split("?", 1)[1])
    try:  # a port's own options win over the machine's
        assert controller.time_scale == 5 and controller.settings[110] == 900 and controller.settings[32] == 1
    finally:
        controller.close()
    assert serial == "/dev/ttyUSB0"  # a real machine is never reconfigured
