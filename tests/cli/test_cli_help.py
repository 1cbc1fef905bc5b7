"""The command line as a new user meets it (issue 20): every `--help` shows defaults and units, lengths take units
as vpype reads them, one name per concept (old names still work, hidden), and a misspelled option gets the
sub-command's usage and the option meant."""

from __future__ import annotations

import argparse
import re

import pytest

from conftest import without_usage
from fabline.cli import STAGE_COMMANDS, build_parser, main
from fabline.cli.units import length_m, length_mm
from fabline.jobs.jobfile import job_from_dict
from fabline.units import parse_length, parse_size
from jobfiles import GOOD

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """`fabline`, `fabline runner`, `fabline runner pause`, ...: every parser by its prog."""
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
COMMANDS = [(prog, parser) for prog, parser in PARSERS.items()
            if not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)]
"""(`fabline nest`, its parser) for every command and sub-command that takes options."""
LENGTH_NAMES = re.compile(r"size|spacing|kerf|gap|margin|length|width|height|offset|radius|overlap|clearance|"
                          r"tolerance|sag|screw-hole|waist|pitch|lead-in|square|marker")
NOT_LENGTHS = {
    ("fabline design asymptotic", "--spacing"): "model units (the surface file's)",
    ("fabline design minimal", "--mesh-size"): "model units (the boundary file's)",
    ("fabline survey simulate", "--resolution"): "pixels",
    ("fabline nest", "--sheet-size"): "a WIDTHxHEIGHT size in mm",
    ("fabline nest", "--remnant-min"): "a WIDTHxHEIGHT size in mm",
    ("fabline design enneper", "--size"): "a footprint size in m",
}
TIMES = re.compile(r"time|timeout|latency|scan")


def _help_of(parser: argparse.ArgumentParser) -> str:
    return " ".join(parser.format_help().split())  # the wrapping undone


@pytest.mark.parametrize("prog, parser", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_help_shows_every_default_and_every_length_option_names_its_unit(prog, parser):
    for action in parser._actions:
        if not action.option_strings or action.help == argparse.SUPPRESS:
            continue
        name, default = action.option_strings[-1], action.default
        entry = " ".join(parser._get_formatter()._format_action(action).split())  # this option's entry in --help
        if default is not None and default is not False and default != [] and action.nargs != 0:
            shown = "x".join(f"{v:g}" for v in default) if isinstance(default, tuple) else str(default)
            assert f"(default: {shown}" in entry, f"{prog} {name}: the default {shown} is not shown: {entry}"
        unit = getattr(action.type, "unit", None)
        if unit is not None:
            assert re.search(rf"\b{unit}\b", entry), f"{prog} {name}: a length option that names no unit: {entry}"
        elif LENGTH_NAMES.search(name) and (prog, name) not in NOT_LENGTHS:
            assert action.type in (length_mm, length_m), f"{prog} {name}: a length option that takes no units"
        if TIMES.search(name) and "scale" not in name:
            assert "second" in entry, f"{prog} {name}: a time option that names no unit: {entry}"


def test_descriptions_keep_their_line_breaks():
    parser = dict(COMMANDS)["fabline gcode-check"]
    parser.description = "first line\nsecond line"
    assert "first line\nsecond line" in parser.format_help()


@pytest.mark.parametrize("text, unit, value", [
    ("3", "mm", 3.0), ("3mm", "mm", 3.0), ("0.2 mm", "mm", 0.2), ("4m", "mm", 4000.0), ("25 cm", "mm", 250.0),
    ("1in", "mm", 25.4), ("-2.5 mm", "mm", -2.5), (".5", "mm", 0.5), ("1e3 mm", "m", 1.0), ("350mm", "m", 0.35),
    ("0.35", "m", 0.35), ("2 ft", "mm", 609.6), ("72pt", "mm", 25.4)])
def test_a_length_is_read_in_its_unit(text, unit, value):
    assert parse_length(text, unit) == pytest.approx(value, rel=1e-12)


@pytest.mark.parametrize("text", ["", "mm", "3 furlongs", "3 m m", "nan", "inf", "1e400", "3,5", "x3"])
def test_a_malformed_length_says_the_accepted_forms(text):
    with pytest.raises(ValueError, match="expected a number in mm or with a unit: 3mm, 0.2 mm|longer than"):
        parse_length(text)


@pytest.mark.parametrize("text, value", [("4000x2000", (4000, 2000)), ("4m x 2m", (4000, 2000)),
                                         ("4000x2000mm", (4000, 2000)), ("4 x 2 m", (4000, 2000)),
                                         ("400cm X 2000", (4000, 2000)), ("1in x 1 in", (25.4, 25.4))])
def test_a_sheet_size_takes_units(text, value):
    assert parse_size(text, "mm") == pytest.approx(value)


def test_length_options_take_units_and_mean_what_plain_numbers_mean():
    parser = build_parser(("nest", "unroll", "model"))
    plain = parser.parse_args(["nest", "p.json", "--sheet-size", "4000x2000", "--kerf", "0.2", "--gap", "3",
                               "--sheet-margin", "10"])
    united = parser.parse_args(["nest", "p.json", "--sheet-size", "4m x 2m", "--kerf", "0.2 mm", "--gap", "0.3cm",
                                "--sheet-margin", "1 cm"])
    for key in ("sheet_size", "kerf", "gap", "sheet_margin"):
        assert getattr(united, key) == pytest.approx(getattr(plain, key)), key
    unroll = parser.parse_args(["unroll", "n.json", "-o", "p.json", "--overlap", "15cm", "--sheet-length", "4m"])
    assert (unroll.overlap, unroll.sheet_length) == (150.0, 4000.0)
    enneper = parser.parse_args(["design", "enneper", "--size", "9000x12000mm", "--spacing", "350mm", "-o", "e.json"])
    assert enneper.size == pytest.approx((9.0, 12.0)) and enneper.spacing == pytest.approx(0.35)


def test_a_bad_length_is_one_line_naming_the_option_and_the_forms_then_the_usage(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["nest", "p.json", "-o", "n.json", "--kerf", "3furlongs"])
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert without_usage(err) == ("fabline nest: error: argument --kerf: unknown unit 'furlongs' (use mm, cm, m, in, "
                                  "ft, pt or px); expected a number in mm or with a unit: 3mm, 0.2 mm, 25 cm, 4m, 1in; "
                                  "got '3furlongs'\n")
    assert err.endswith(dict(COMMANDS)["fabline nest"].format_usage())


def test_a_job_file_takes_lengths_with_units_and_plain_numbers_as_before(tmp_path):
    path = tmp_path / "job.toml"
    plain = job_from_dict(tomllib.loads(GOOD + '[nest]\ngap = 3\nmargin = 10\n[export]\nlead_in = 2\n'
                                        '[unroll]\noverlap = 150\n[stock]\nsheet = "4000x2000"\n'), path)
    united = job_from_dict(tomllib.loads(GOOD + '[nest]\ngap = "3 mm"\nsheet_margin = "1cm"\n[export]\nlead_in = '
                                         '"0.2 cm"\n[unroll]\noverlap = "15 cm"\n[stock]\nsheet = "4m x 2m"\n'), path)
    assert (united.nest["gap"], united.nest["sheet_margin"], united.export["lead_in"], united.unroll["overlap"]) == \
        pytest.approx((plain.nest["gap"], plain.nest["sheet_margin"], plain.export["lead_in"], plain.unroll["overlap"]))


@pytest.mark.parametrize("argv, line", [
    (["nest", "p.json", "--sheet-sise", "4000x2000"], "fabline nest: error: unknown option --sheet-sise; "
                                                      "did you mean --sheet-size?"),
    (["design", "enneper", "-o", "e.json", "--spaceing=0.3"], "fabline design enneper: error: unknown option "
                                                              "--spaceing; did you mean --spacing?"),
    (["runner", "cancel", "3", "--yse"], "fabline runner cancel: error: unknown option --yse; did you mean --yes?"),
    (["export", "n.json", "--frobnicate"], "fabline export: error: unknown option --frobnicate "
                                          "(see fabline export --help)"),
    (["nets", "p.json"], "fabline: error: argument COMMAND: invalid choice: 'nets'; did you mean nest?"),
    (["runner", "stauts"], "fabline runner: error: argument ACTION: invalid choice: 'stauts'; did you mean status?"),
    (["frobnicate"], "fabline: error: argument COMMAND: invalid choice: 'frobnicate' (see fabline --help)"),
])
def test_a_misspelled_option_gets_the_option_meant_and_the_sub_commands_usage(argv, line, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    prog = line.split(": error:")[0]
    assert stop.value.code == 2
    assert err == f"{line}\n{PARSERS[prog].format_usage()}"


@pytest.mark.parametrize("prog, argv, dest, value", [
    ("fabline nest", ["nest", "p.json", "--sheet", "3000x1500"], "sheet_size", (3000.0, 1500.0)),
    ("fabline nest", ["nest", "p.json", "--margin", "5"], "sheet_margin", 5.0),
    ("fabline runner serve", ["runner", "serve", "--port", "8123"], "web_port", 8123),
    ("fabline survey simulate", ["survey", "simulate", "--model", "m.json", "-o", "s", "--size", "800x600"],
     "resolution", "800x600"),
])
def test_an_old_option_name_still_works_but_is_not_shown(prog, argv, dest, value):
    assert getattr(build_parser().parse_args(argv), dest) == value
    old = argv[-2]
    assert not re.search(rf"{old}\b(?!-)", _help_of(dict(COMMANDS)[prog])), f"{prog} --help shows {old}"


def test_a_job_files_survey_lengths_take_units_too(tmp_path):
    survey = '[survey]\nsimulate = true\nsag_mm = "2.5 cm"\ntolerance_mm = "0.02 m"\n'
    spec = job_from_dict(tomllib.loads(GOOD + survey), tmp_path / "job.toml")
    assert (spec.survey["sag_mm"], spec.survey["tolerance_mm"]) == pytest.approx((25.0, 20.0))
