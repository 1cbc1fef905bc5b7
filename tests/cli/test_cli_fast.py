"""The command line as a new user meets it (issue 24): help without importing the stages, every length option
takes units, a value implausible in the model's units is refused naming what was meant, negative numbers and
points parse, and output into a closed pipe ends quietly."""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fabline.cli import STAGE_COMMANDS, build_parser, main
from fabline.cli import choices
from fabline.model_units import Length

ROOT = Path(__file__).resolve().parents[2]
SURFACE = ROOT / "examples" / "surface.obj"
"""A saddle in m (3.2 m across, no units declared)."""


def _parsers() -> dict[str, argparse.ArgumentParser]:
    found = {}

    def walk(parser: argparse.ArgumentParser) -> None:
        found[parser.prog] = parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)

    walk(build_parser(tuple(STAGE_COMMANDS)))
    return found


PARSERS = _parsers()
OPTIONS = [(prog, action) for prog, parser in PARSERS.items() for action in parser._actions
           if action.option_strings and action.help != argparse.SUPPRESS and action.nargs != 0
           and not isinstance(action, (argparse._HelpAction, argparse._VersionAction))]
"""(`fabline nest`, its --kerf action) for every option that takes a value."""


def _fabline(*args, stdout=subprocess.PIPE, env=None, cwd=None) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "fabline", *map(str, args)], stdout=stdout, stderr=subprocess.PIPE,
                          env={k: v for k, v in environment.items() if v is not None}, cwd=cwd, timeout=300)


# --- help without the stages ------------------------------------------------------------------------------------

LIGHT = {"fabline", "fabline.errors", "fabline.fileio", "fabline.units", "fabline.model_units", "fabline.lazy"}
"""The modules below the command line that building its parser may import: none of a stage's."""
HEAVY = ("numpy", "scipy", "shapely", "trimesh", "ezdxf", "cv2", "serial", "rhino3dm", "uvicorn")


def test_no_help_imports_a_stage_or_its_libraries():
    script = f"""
import contextlib, io, sys
from fabline.cli import STAGE_COMMANDS, main
for commands in STAGE_COMMANDS.values():
    for command in ("",) + commands:
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                main([command, "--help"] if command else ["--help"])
            except SystemExit:
                pass
from cli.test_cli_fast import PARSERS
for parser in PARSERS.values():
    parser.format_help()
print(" ".join(sorted(m for m in sys.modules if m.split(".")[0] in ("fabline",) + {HEAVY!r})))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{ROOT / 'tests'}"})
    assert done.returncode == 0, done.stderr
    loaded = set(done.stdout.split())
    stages = sorted(m for m in loaded if m not in LIGHT and not m.startswith("fabline.cli") and m != "test_cli_fast")
    assert stages == [], f"--help imported {stages}"


def test_the_helps_names_and_defaults_are_the_stages_own():
    from fabline.link.streamer import MODES
    from fabline.machine.build import STOCK_BUILD
    from fabline.model.designs import BOUNDARIES
    from fabline.model.importers import FORMATS
    from fabline.model.network import UNIT_TO_MM
    from fabline.unroll import SINGULARITY_MODES

    assert choices.MODEL_UNITS == tuple(sorted(UNIT_TO_MM))
    assert choices.IMPORT_FORMATS == tuple(FORMATS)
    assert choices.BOUNDARIES == BOUNDARIES
    assert choices.SINGULARITY_MODES == SINGULARITY_MODES
    assert choices.STREAM_MODES == MODES
    assert choices.STOCK_BUILD_OPTIONS == STOCK_BUILD.options


def test_each_command_runs_its_stage_and_help_still_shows_every_command(cli):
    code, out, _ = cli("--help")
    assert code == 0
    for commands in STAGE_COMMANDS.values():
        for command in commands:
            assert re.search(rf"^\s+{re.escape(command)}\s", out, re.M), f"{command} missing from fabline --help"
    code, out, err = cli("limits", "--profile", "100x1.5")  # its handler imports the structural check itself
    assert code == 0, err
    assert "minimum bending radius (weak axis)  670.2 mm" in out  # E t / (2 f_y) = 210000 * 1.5 / 470


# --- every length option takes units ----------------------------------------------------------------------------

LENGTH_WORDS = re.compile(r"length|spacing|distance|radius|width|height|edge|offset|overlap|clearance|margin|"
                          r"border|diameter|depth|step|thickness|sag|tolerance|kerf|gap|pitch|waist|size|square|"
                          r"marker|lead-in|screw-hole")
NOT_LENGTHS = {
    ("fabline design asymptotic", "--seed"): "a point (three coordinates in model units)",
    ("fabline survey simulate", "--resolution"): "an image size in pixels",
    ("fabline survey simulate", "--focal"): "a focal length in pixels",
    ("fabline survey measure", "--scale-min-cell"): "a cell width in pixels",
    ("fabline grbl-sim", "--planner-blocks"): "a planner size in blocks",
    ("fabline nest", "--rotations"): "a count of rotation steps",
    ("fabline survey calibrate", "--board"): "a count of squares",
    ("fabline survey measure", "--k-sigma"): "a number of standard deviations",
    ("fabline nest", "--stock"): "a file (of sheet sizes)",
    ("fabline survey measure", "--tags"): "a file (of tag sizes)",
    ("fabline survey plan", "--tags"): "a file (of tag sizes)",
    ("fabline survey plan", "--photo"): "a photo file (its size and EXIF focal length)",
    ("fabline survey plan", "--resolution"): "an image size in pixels",
}
LENGTH_OPTIONS = [(prog, action) for prog, action in OPTIONS
                  if LENGTH_WORDS.search(f"{action.option_strings[-1]} {action.help}")
                  and (prog, action.option_strings[-1]) not in NOT_LENGTHS]
"""Every option whose name or help says it is a length (or a size of lengths)."""
IN_UNIT = {"mm": ("350", "35cm"), "m": ("0.35", "35cm"), "model units": ("350", "350mm")}
"""A plain number in the option's unit and the same length written with a unit (for model units: read in mm)."""


def test_the_length_options_are_found_and_the_exceptions_exist():
    names = {(prog, action.option_strings[-1]) for prog, action in OPTIONS}
    assert set(NOT_LENGTHS) <= names, set(NOT_LENGTHS) - names
    found = {(prog, action.option_strings[-1]) for prog, action in LENGTH_OPTIONS}
    assert {("fabline design asymptotic", "--spacing"), ("fabline design asymptotic", "--step"),
            ("fabline design minimal", "--mesh-size"), ("fabline nest", "--gap"), ("fabline survey tags",
            "--mount-offset"), ("fabline unroll", "--profile"), ("fabline survey measure", "--scale-bar")} <= found
    assert len(found) >= 40


@pytest.mark.parametrize("prog, action", LENGTH_OPTIONS, ids=[f"{p} {a.option_strings[-1]}" for p, a in LENGTH_OPTIONS])
def test_every_length_option_takes_a_unit(prog, action):
    name = action.option_strings[-1]
    if action.nargs == 3:  # --scale-bar TAG_A TAG_B DIST_MM: the distance is read with its unit by the command
        from fabline.cli.survey import _scale_bar

        assert _scale_bar(["1", "2", "1.2m"]) == _scale_bar(["1", "2", "1200"]) == (1, 2, 1200.0)
        return
    unit = getattr(action.type, "unit", None)
    assert unit in IN_UNIT, f"{prog} {name}: a length option whose values take no unit (type {action.type})"
    plain, united = IN_UNIT[unit]
    if action.metavar in ("WxH", "XxY", "HxT"):  # a size: two lengths
        plain, united = f"{plain}x{plain}", f"{united} x {united}"
    parsed, expected = action.type(united), action.type(plain)
    if isinstance(parsed, Length):
        parsed, expected = parsed.in_units("mm"), expected.in_units("mm")
    assert parsed == pytest.approx(expected, rel=1e-12) if not isinstance(parsed, str) else parsed == expected


@pytest.mark.parametrize("argv, dest, value", [
    (["design", "asymptotic", "--surface", "s.obj", "--spacing", "17mm", "-o", "n.json"], "spacing", (17.0, "mm")),
    (["design", "asymptotic", "--surface", "s.obj", "--spacing", "0.35m", "-o", "n.json"], "spacing", (0.35, "m")),
    (["design", "asymptotic", "--surface", "s.obj", "--spacing", "0.35", "-o", "n.json"], "spacing", (0.35, None)),
    (["design", "asymptotic", "--surface", "s.obj", "--spacing", "0.35", "--step", "2 cm", "-o", "n.json"], "step",
     (2.0, "cm")),
    (["design", "minimal", "--boundary", "b.json", "--mesh-size", "100mm", "-o", "s.obj"], "mesh_size", (100.0, "mm")),
    (["unroll", "n.json", "-o", "p.json", "--profile", "10cm x 1.5mm"], "profile", "100x1.5"),
    (["limits", "--profile", "0.1m x 0.0015m"], "profile", "100x1.5"),
])
def test_model_lengths_and_profiles_parse_with_their_units(argv, dest, value):
    parsed = getattr(build_parser().parse_args(argv), dest)
    if isinstance(parsed, Length):
        parsed = (pytest.approx(parsed.value, rel=1e-15), parsed.unit)
    assert parsed == value


def test_a_spacing_with_a_unit_traces_the_network_its_plain_number_does(cli, tmp_path):
    code, _, err = cli("design", "asymptotic", "--surface", SURFACE, "--spacing", "0.35", "-o", tmp_path / "plain.json")
    assert code == 0, err
    code, _, err = cli("design", "asymptotic", "--surface", SURFACE, "--spacing", "350mm", "-o", tmp_path / "mm.json")
    assert code == 0, err
    plain, united = (json.loads((tmp_path / name).read_text()) for name in ("plain.json", "mm.json"))
    assert united["nodes"] == plain["nodes"] and united["lamellas"] == plain["lamellas"]


@pytest.mark.parametrize("argv, line", [
    (["--units", "mm", "--spacing", "0.35"], "fabline design: error: --spacing 0.35: a node spacing in millimetres must "
                                             "be 10 to 10000; 0.35 looks like metres: give 350"),
    (["--spacing", "350"], "fabline design: error: --spacing 350: a node spacing in metres must be 0.01 to 10; 350 "
                           "looks like millimetres: give 0.35"),
    (["--spacing", "2mm"], "fabline design: error: --spacing 2mm: a node spacing must be 10 mm to 10 m, got 0.002 m"),
    (["--spacing", "0.35", "--units", "mm", "--step", "0.01"],
     "fabline design: error: --spacing 0.35: a node spacing in millimetres must be 10 to 10000; 0.35 looks like "
     "metres: give 350"),
    (["--spacing", "0.35", "--step", "50"], "fabline design: error: --step 50: a tracing step in metres must be 0.0001 "
                                            "to 10; 50 looks like millimetres: give 0.05"),
    (["--spacing", "-0.35"], "fabline design asymptotic: error: argument --spacing: must be a positive length, got "
                             "'-0.35'"),
])
def test_a_spacing_implausible_in_the_models_units_is_refused_saying_what_was_meant(argv, line, cli, tmp_path):
    code, out, err = cli("design", "asymptotic", "--surface", SURFACE, *argv, "-o", tmp_path / "n.json")
    assert (code, err) == (2, line + "\n")
    assert not (tmp_path / "n.json").exists()


def test_a_mesh_size_implausible_in_the_boundarys_units_is_refused(cli, tmp_path):
    edges = tmp_path / "edges.json"
    edges.write_text(json.dumps({"units": "mm", "curves": [[[0, 0, 0], [2000, 0, 600], [2000, 2000, 0],
                                                             [0, 2000, 600], [0, 0, 0]]]}))
    code, _, err = cli("design", "minimal", "--boundary", edges, "--mesh-size", "0.1", "-o", tmp_path / "s.obj")
    assert (code, err) == (2, "fabline design: error: --mesh-size 0.1: a triangle size in millimetres must be 1 to "
                              "10000; 0.1 looks like metres: give 100\n")
    code, out, err = cli("design", "minimal", "--boundary", edges, "--mesh-size", "0.25m", "-o", tmp_path / "s.obj")
    assert code == 0, err
    assert "(units mm)" in out


def test_the_tag_size_check_is_the_same_check():
    from fabline.errors import FablineError
    from fabline.model_units import check_plausible
    from fabline.survey.tagmap import TAG_SIZE_RANGE_MM, check_tag_size_mm

    with pytest.raises(FablineError) as refused:
        check_tag_size_mm(0.065)
    with pytest.raises(FablineError) as same:
        check_plausible(0.065, "mm", TAG_SIZE_RANGE_MM, "--tag-size", "a tag's black-square edge")
    assert str(refused.value) == str(same.value) == ("--tag-size 0.065: a tag's black-square edge in millimetres must "
                                                     "be 5 to 2000; 0.065 looks like metres: give 65")


# --- negative numbers and points --------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [
    ["design", "asymptotic", "--surface", "s.obj", "--spacing", "0.35", "--seed", "-0.22,0.04,0.006", "-o", "n.json"],
    ["design", "asymptotic", "--surface", "s.obj", "--spacing", "0.35", "--seed=-0.22,0.04,0.006", "-o", "n.json"],
])
def test_a_negative_seed_parses(argv):
    assert build_parser().parse_args(argv).seed == (-0.22, 0.04, 0.006)


NUMBER_TYPES = ("float", "int", "_point")


@pytest.mark.parametrize("prog, action", [(p, a) for p, a in OPTIONS if getattr(a.type, "__name__", "") in NUMBER_TYPES],
                         ids=[f"{p} {a.option_strings[-1]}" for p, a in OPTIONS
                              if getattr(a.type, "__name__", "") in NUMBER_TYPES])
@pytest.mark.parametrize("value", ["-1e-3", "-2", "-.5", "-1,2,3", "-25mm"])
def test_a_negative_value_is_read_as_the_options_value_not_as_an_option(prog, action, value, monkeypatch):
    """Every number or point option: a value with a leading '-' reaches the option's own check (which may refuse
    it, naming the value), never "expected one argument"."""
    parser = PARSERS[prog]
    said = []

    def error(self, message):
        said.append(message)
        raise SystemExit(2)

    monkeypatch.setattr(type(parser), "error", error)
    try:
        parser.parse_known_args([action.option_strings[-1], value])
    except SystemExit:
        pass
    assert not any("expected one argument" in message for message in said), said
    assert not any("unknown option" in message for message in said), said


def test_a_negative_twist_reaches_the_commands_own_check(cli):
    code, _, err = cli("limits", "--twist", "-1e-3")
    assert (code, err) == (2, "fabline limits: error: --twist: must be positive, got -0.001\n")


# --- a closed pipe ----------------------------------------------------------------------------------------------

def _into_closed_pipe(*args, env=None, cwd=None) -> subprocess.CompletedProcess:
    """Run `fabline ARGS` with its standard output a pipe whose reader is gone (`| head` that has exited)."""
    reader, writer = os.pipe()
    os.close(reader)
    try:
        return _fabline(*args, stdout=writer, env=env, cwd=cwd)
    finally:
        os.close(writer)


@pytest.fixture(scope="module")
def queue(tmp_path_factory):
    from fabline.jobs.queue import JobQueue

    path = tmp_path_factory.mktemp("queue") / "runner.sqlite"
    program = path.with_name("sheet-1.gcode")
    program.write_text("G21\nG90\nG0 X1 Y1\nG1 X5 Y5 F1000\nM2\n")
    JobQueue(path).submit("first", programs=[("sheet-1", str(program), "")])
    return path


@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "unbuffered"])
@pytest.mark.parametrize("args", [["runner", "status", "--db", "{queue}"], ["limits"], ["--help"], ["nest", "--help"],
                                  ["runner", "status", "--json", "--db", "{queue}"]],
                         ids=["runner status", "limits", "--help", "nest --help", "runner status --json"])
def test_output_into_a_closed_pipe_ends_quietly(args, buffered, queue):
    done = _into_closed_pipe(*(a.format(queue=queue) for a in args),
                             env={"PYTHONUNBUFFERED": None if buffered else "1"})
    assert done.stderr.decode() == ""
    # 128 + SIGPIPE as a shell reports it, --help too, whether or not this Python's argparse swallows a failed write
    assert done.returncode == 141


def test_a_job_whose_output_reader_went_away_runs_to_its_end(tmp_path, catenoid):
    from fabline.model import save_network

    save_network(catenoid, tmp_path / "net.json")
    (tmp_path / "job.toml").write_text('name = "pipe"\nstages = ["unroll"]\n[model]\nfile = "net.json"\n'
                                       '[output]\nfolder = "out"\n')
    done = _into_closed_pipe("run", "job.toml", cwd=tmp_path)
    assert (done.returncode, done.stderr.decode()) == (0, "")
    assert (tmp_path / "out" / "parts.json").is_file()

