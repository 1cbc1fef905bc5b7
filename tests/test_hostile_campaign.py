"""The hostile campaign (issue 25): options and files that ask for more than any job needs (a size, a count, a
memory or a duration) or that break a parser from the inside (format strings, deep nesting, numbers at the ends
of the range). Every case runs as a user runs it, in its own process under a 6 GiB address-space cap and a 60 s
clock, and must end in one line on stderr that says what is at fault, exit 2 and no traceback, with the world's
files unchanged. The count of cases per kind is printed at the end of the run (conftest.py)."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest

from test_bad_input_campaign import _digest, world_folder

MEMORY_CAP = 6 * 2**30
TIME_CAP_S = 60


@dataclass(frozen=True)
class Case:
    """One hostile case: its kind (the summary's row), its name, the command line it runs (from the world's folder
    and a scratch folder) and a fragment the one line of refusal must contain (what it names at fault)."""

    kind: str
    name: str
    command: Callable[[Path, Path], list[str]]
    says: str


# --- profiles, job files and TOML (issue 25, item 10) ----------------------------------------------------------

def _profile(world: Path, tmp: Path, key: str, value: str) -> Path:
    """The world's machine profile with one line `key = value` replaced, written into tmp."""
    lines = (world / "machine.toml").read_text().splitlines()
    text = "\n".join(f"{key} = {value}" if line.startswith(f"{key} =") else line for line in lines)
    (tmp / "bad.toml").write_text(text + "\n")
    return tmp / "bad.toml"


def _job(world: Path, tmp: Path, machine: str = "", extra: str = "", stages: str = '["unroll"]') -> Path:
    """A job file in tmp on the world's net, with `machine` lines in its [machine] table and `extra` at the end."""
    (tmp / "job.toml").write_text(f'name = "hostile"\nstages = {stages}\n[model]\nfile = "{world / "net.json"}"\n'
                                  f'[output]\nfolder = "out"\n[machine]\n{machine}\n{extra}\n')
    return tmp / "job.toml"


def _export_with(profile: Callable[[Path, Path], Path]) -> Callable[[Path, Path], list[str]]:
    return lambda w, t: ["export", w / "nesting.json", "--machine", profile(w, t), "--gcode", t / "out.gcode"]


def _deep(tmp: Path, name: str, value: str, prefix: str = "") -> Path:
    (tmp / name).write_text(f"{prefix}a = {value}\n")
    return tmp / name


def _nesting(world: Path, tmp: Path, parts_file: str) -> Path:
    data = json.loads((world / "nesting.json").read_text())
    data["parts_file"] = parts_file
    (tmp / "nesting.json").write_text(json.dumps(data))
    return tmp / "nesting.json"


_LISTS = "[" * 5000 + "]" * 5000
_TABLES = "{a=" * 5000 + "1" + "}" * 5000
_JUST_TOO_DEEP = "[" * 33 + "]" * 33
PROFILE_CASES: list[Case] = [
    Case("profile format", "program_start {power} (rendered without power)",
         _export_with(lambda w, t: _profile(w, t, "program_start", '["G4 P{power}"]')), "unknown placeholder {power}"),
    Case("profile format", "tool_off {depth}",
         _export_with(lambda w, t: _profile(w, t, "tool_off", '["M5 S{depth}"]')), "tool_off"),
    Case("profile format", "unclosed brace",
         _export_with(lambda w, t: _profile(w, t, "program_start", '["G1 {x"]')), "program_start"),
    Case("profile format", "single closing brace",
         _export_with(lambda w, t: _profile(w, t, "program_end", '["}"]')), "program_end"),
    Case("profile format", "format spec on power",
         _export_with(lambda w, t: _profile(w, t, "tool_on", '["M4 S{power:d}"]')), "no format"),
    Case("profile format", "attribute of power",
         _export_with(lambda w, t: _profile(w, t, "tool_on", '["M4 S{power.real}"]')), "{power.real}"),
    Case("profile format", "job file's machine.profile",
         lambda w, t: ["run", _job(w, t, 'profile = "%s"' % _profile(w, t, "program_start", '["G4 P{power}"]'))],
         "machine.profile"),
    Case("deep TOML", "job file, 5000 nested arrays", lambda w, t: ["run", _job(w, t, extra="[x]\na = " + _LISTS)],
         "nested deeper than 32 levels"),
    Case("deep TOML", "job file, 5000 nested inline tables",
         lambda w, t: ["run", _job(w, t, extra="[x]\na = " + _TABLES)], "job.toml: nested deeper than 32"),
    Case("deep TOML", "job file, 33 nested arrays", lambda w, t: ["run", _job(w, t, extra="[x]\na = " + _JUST_TOO_DEEP)],
         "nested deeper than 32"),
    Case("deep TOML", "machine profile, 5000 nested arrays",
         _export_with(lambda w, t: _deep(t, "deep.toml", _LISTS)), "deep.toml: nested deeper than 32"),
    Case("deep TOML", "materials file, 5000 nested inline tables",
         lambda w, t: ["unroll", w / "net.json", "-o", t / "u.json", "--materials",
                       _deep(t, "deep.toml", _TABLES, "[m]\n")], "deep.toml: nested deeper than 32"),
    *(Case("time scale", f"stream sim:// time_scale={v}",
           lambda w, t, v=v: ["stream", w / "program.gcode", "--port", f"sim://grbl?time_scale={v}"], "at most 1e+06")
      for v in ("inf", "nan", "1e308", "-1", "0")),
    *(Case("time scale", f"job machine.port time_scale={v}",
           lambda w, t, v=v: ["run", _job(w, t, f'port = "sim://grbl?time_scale={v}"')], "machine.port")
      for v in ("inf", "nan", "1e308", "-1")),
    *(Case("time scale", f"job machine.time_scale = {v}",
           lambda w, t, v=v: ["run", _job(w, t, f"time_scale = {v}")], "machine.time_scale")
      for v in ("inf", "nan", "1e308", "-1")),
    Case("nesting parts_file", "NUL byte",
         lambda w, t: ["export", _nesting(w, t, "parts\0.json"), "--gcode", t / "o.gcode"], "nesting.json: parts_file"),
    Case("nesting parts_file", "empty",
         lambda w, t: ["export", _nesting(w, t, ""), "--gcode", t / "o.gcode"], "nesting.json: parts_file"),
]


# --- the survey (items 10 and 11) ------------------------------------------------------------------------------

SURVEY_CASES: list[Case] = []


# --- design, geometry and nesting (items 10 and 11) ------------------------------------------------------------

GEOMETRY_CASES: list[Case] = []


CASES = PROFILE_CASES + SURVEY_CASES + GEOMETRY_CASES


def _capped() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def run_capped(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """`fabline ARGS` in a process of its own, under the memory and time caps."""
    return subprocess.run([sys.executable, "-m", "fabline", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=TIME_CAP_S, preexec_fn=_capped, env={**os.environ, "COLUMNS": "120"})


@pytest.mark.parametrize("case", CASES, ids=[f"{c.kind}: {c.name}" for c in CASES])
def test_a_hostile_case_meets_a_bound_in_one_line(case, tmp_path):
    world = world_folder()
    before = _digest(world)
    done = run_capped(case.command(world, tmp_path), cwd=tmp_path)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.returncode == 2, f"exit {done.returncode}: {done.stderr[-800:]}"
    assert len(lines) == 1 and lines[0].startswith("fabline"), done.stderr[-800:]
    assert case.says.lower() in lines[0].lower(), lines[0]
    assert _digest(world) == before, "an input changed"
