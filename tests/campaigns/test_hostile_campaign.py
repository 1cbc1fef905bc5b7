"""The hostile campaign (issue 25): options and files that ask for more than any job needs (a size, a count, a
memory or a duration) or that break a parser from the inside (format strings, deep nesting, numbers at the ends
of the range). Every case runs as a user runs it, in its own process under a 6 GiB address-space cap and a 60 s
clock, and must end in one line on stderr that says what is at fault, exit 2 and no traceback, with the world's
files unchanged. The count of cases per kind is printed at the end of the run (conftest.py)."""

from __future__ import annotations

import json
import math
import os
import resource
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest

from .test_bad_input_campaign import _digest, _png_claiming, world_folder

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
    *(Case("sim options", f"stream sim:// {option}={v}",
           lambda w, t, o=option, v=v: ["stream", w / "program.gcode", "--port", f"sim://grbl?{o}={v}"], f"{option}=")
      for option, v in (("line_time", "nan"), ("line_time", "inf"), ("stall_seconds", "nan"),
                        ("stall_seconds", "inf"), ("error_line", "1e400"), ("error_line", "1" + "0" * 400),
                        ("alarm_code", "-1"), ("planner_blocks", "0"), ("rx_buffer", "1e9"))),
    Case("nesting parts_file", "NUL byte",
         lambda w, t: ["export", _nesting(w, t, "parts\0.json"), "--gcode", t / "o.gcode"], "nesting.json: parts_file"),
    Case("nesting parts_file", "empty",
         lambda w, t: ["export", _nesting(w, t, ""), "--gcode", t / "o.gcode"], "nesting.json: parts_file"),
]


# --- the survey (items 10 and 11) ------------------------------------------------------------------------------

def _simulate(*option: str) -> Callable[[Path, Path], list[str]]:
    return lambda world, tmp: ["survey", "simulate", "--model", world / "net.json", "-o", tmp / "sim", *option]


def _survey_job(line: str) -> Callable[[Path, Path], list[str]]:
    """`fabline run` on a job of the world's model whose [survey] section simulates with `line` in it."""
    def command(world: Path, tmp: Path) -> list[str]:
        (tmp / "job.toml").write_text(f'name = "hostile"\n[model]\nfile = "{world / "net.json"}"\n'
                                      f'[output]\nfolder = "{tmp / "out"}"\n[survey]\nsimulate = true\n{line}\n')
        return ["run", tmp / "job.toml"]
    return command


def _tag_map_offset(offset: str) -> Callable[[Path, Path], list[str]]:
    """`survey measure` with a tag map whose mounting offset is `offset` (JSON text)."""
    def command(world: Path, tmp: Path) -> list[str]:
        (tmp / "photos").mkdir()
        (tmp / "photos" / "photo.png").write_bytes((world / "photo.png").read_bytes())
        (tmp / "tagmap.json").write_text('{"schema": "fabline.tagmap/1", "family": "tag36h11", "tag_size_mm": 65, '
                                         f'"mount_offset_mm": {offset}, "tags": [{{"tag": 0, "node": "n0"}}]}}')
        return ["survey", "measure", tmp / "photos", "--model", world / "net.json", "--tags", tmp / "tagmap.json",
                "-o", tmp / "out"]
    return command


def _bad_crc_png(width: int, height: int) -> bytes:
    """`_png_claiming` with every chunk's CRC wrong, so that a reader checking them gives up on the header."""
    data = bytearray(_png_claiming(width, height))
    at = 8
    while at < len(data):
        length = int.from_bytes(data[at:at + 4], "big")
        data[at + 8 + length:at + 12 + length] = bytes(b ^ 0xFF for b in data[at + 8 + length:at + 12 + length])
        at += 12 + length
    return bytes(data)


def _jpeg_claiming(width: int, height: int) -> bytes:
    """A JPEG's first segments: a comment, then a baseline frame header claiming width x height grey pixels."""
    comment = b"\xff\xfe" + (2 + 5).to_bytes(2, "big") + b"hello"
    frame = b"\xff\xc0" + (11).to_bytes(2, "big") + bytes([8]) + height.to_bytes(2, "big") + width.to_bytes(2, "big") \
        + bytes([1, 1, 0x11, 0])
    return b"\xff\xd8" + comment + frame + b"\xff\xda" + b"\0" * 64 + b"\xff\xd9"


def _detect(name: str, data: bytes) -> Callable[[Path, Path], list[str]]:
    def command(world: Path, tmp: Path) -> list[str]:
        (tmp / name).write_bytes(data)
        return ["survey", "detect", tmp / name]
    return command


SURVEY_CASES: list[Case] = [
    Case("survey options", "--resolution 200000x200000", _simulate("--resolution", "200000x200000"), "megapixels"),
    Case("survey options", "--photos 100000", _simulate("--photos", "100000"), "the limit is 1000"),
    Case("survey options", "--seed -1", _simulate("--seed", "-1"), "0..2147483647"),
    Case("survey options", "job survey.resolution 200000x200000", _survey_job('resolution = "200000x200000"'),
         "survey.resolution"),
    Case("survey options", "job survey.photos 100000", _survey_job("photos = 100000"), "survey.photos"),
    Case("survey options", "job survey.seed 2**31", _survey_job(f"seed = {2**31}"), "survey.seed"),
    Case("tag map", "mount_offset_mm 1e300", _tag_map_offset("1e300"), "mount_offset_mm"),
    Case("tag map", "mount_offset_mm -2e6", _tag_map_offset("-2e6"), "mount_offset_mm"),
    Case("photo header", "PNG 25000 x 25000 with bad CRCs", _detect("big.png", _bad_crc_png(25000, 25000)),
         "25000 x 25000"),
    Case("photo header", "JPEG frame 60000 x 60000", _detect("big.jpg", _jpeg_claiming(60000, 60000)),
         "60000 x 60000"),
]


# --- design, geometry and nesting (items 10 and 11) ------------------------------------------------------------

SURFACE = Path(__file__).resolve().parents[2] / "examples" / "surface.obj"  # 7.3 m across, anticlastic


def _washer(pid: str, radius: float) -> dict:
    """A round part of `radius` (mm), four quarter arcs (bulge tan(pi/8))."""
    b = math.tan(math.pi / 8)
    return {"id": pid, "kind": "washer", "grain": False, "holes": [],
            "outline": [[-radius, 0, b], [0, -radius, b], [radius, 0, b], [0, radius, b], [-radius, 0, 0]]}


def _nesting_of(world: Path, tmp: Path, parts: list[dict], sheets: list[list[tuple[str, float, float]]]) -> Path:
    """tmp/nesting.json (the world's settings) with these sheets of (part, x, y), and tmp/parts.json with `parts`."""
    partset, nesting = (json.loads((world / name).read_text()) for name in ("parts.json", "nesting.json"))
    (tmp / "parts.json").write_text(json.dumps({**partset, "parts": parts}))
    sheet = nesting["sheets"][0]
    nesting["sheets"] = [{**sheet, "id": f"S{k + 1:03d}", "common_cuts": [], "placements": [
        {"part": pid, "x": x, "y": y, "rotation": 0.0} for pid, x, y in placed]} for k, placed in enumerate(sheets)]
    (tmp / "nesting.json").write_text(json.dumps(nesting))
    return tmp / "nesting.json"


def _stacked(world: Path, tmp: Path, radius: float) -> Path:
    """One washer placed 20,000 times at one spot of one sheet."""
    return _nesting_of(world, tmp, [_washer("W", radius)], [[("W", 500.0, 500.0)] * 20_000])


def _boundary(tmp: Path, side: float) -> Path:
    """A saddle-shaped closed boundary `side` m across."""
    path = tmp / "edges.json"
    corners = [[0, 0, 0], [side, 0, 0.3 * side], [side, side, 0], [0, side, 0.3 * side], [0, 0, 0]]
    path.write_text(json.dumps({"units": "m", "curves": [corners]}))
    return path


def _dxf(tmp: Path, name: str, add) -> Path:
    """tmp/NAME, a DXF in metres with what `add(modelspace)` draws."""
    import ezdxf

    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6
    add(doc.modelspace())
    doc.saveas(tmp / name)
    return tmp / name


def _huge_arc(space) -> None:
    space.add_line((0, 0, 0), (1, 0, 0), dxfattribs={"layer": "A"})
    space.add_arc((0, 0), 1e300, 0, 90, dxfattribs={"layer": "B"})


def _long_curve(space) -> None:
    """Two 300,000-point polylines (0.03 mm apart along them), one per family."""
    import numpy as np

    t = np.linspace(0.0, 1.0, 300_000)
    points = np.c_[9.0 * t, np.sin(20.0 * t), 0.1 * np.cos(7.0 * t)]
    space.add_polyline3d(points.tolist(), dxfattribs={"layer": "A"})
    space.add_polyline3d(points[:, [1, 0, 2]].tolist(), dxfattribs={"layer": "B"})


def _tiny_part(world: Path, tmp: Path) -> Path:
    """The world's parts and one 50 mm long, 1e-4 mm wide sliver."""
    partset = json.loads((world / "parts.json").read_text())
    sliver = {"id": "SLIVER", "kind": "washer", "grain": False, "holes": [],
              "outline": [[0, 0, 0], [50, 0, 0], [0, 1e-4, 0], [0, 0, 0]]}
    (tmp / "parts.json").write_text(json.dumps({**partset, "parts": partset["parts"] + [sliver]}))
    return tmp / "parts.json"


GEOMETRY_CASES: list[Case] = [
    Case("design bounds", "asymptotic --spacing 0.01 on a 7 m surface (4e6 tracing points)",
         lambda w, t: ["design", "asymptotic", "--surface", SURFACE, "--spacing", "0.01", "-o", t / "n.json"],
         "the limit is 1e+06"),
    Case("design bounds", "asymptotic --step 0.0001 (3e6 tracing points)",
         lambda w, t: ["design", "asymptotic", "--surface", SURFACE, "--spacing", "0.35", "--step", "0.0001",
                       "-o", t / "n.json"], "give a larger --step"),
    Case("design bounds", "minimal surface spanning a boundary 1e12 m across (a 30 TiB lattice)",
         lambda w, t: ["design", "minimal", "--boundary", _boundary(t, 1e12), "--mesh-size", "1", "-o", t / "s.obj"],
         "vertices; the limit is 1e+06"),
    Case("design bounds", "minimal surface spanning a boundary 100 km across at 1 m",
         lambda w, t: ["design", "minimal", "--boundary", _boundary(t, 1e5), "--mesh-size", "1", "-o", t / "s.obj"],
         "give a larger --mesh-size"),
    Case("curve bounds", "import a DXF arc of radius 1e300",
         lambda w, t: ["import", _dxf(t, "arc.dxf", _huge_arc), "-o", t / "n.json"], "radius 1e+300"),
    Case("curve bounds", "design minimal from a DXF circle of radius 1e300",
         lambda w, t: ["design", "minimal", "--boundary", _dxf(t, "ring.dxf", lambda s: s.add_circle((0, 0), 1e300)),
                       "--mesh-size", "1", "-o", t / "s.obj"], "radius 1e+300"),
    Case("curve bounds", "import two 300,000-point DXF polylines (4e7 segment pairs, 6 GB)",
         lambda w, t: ["import", _dxf(t, "long.dxf", _long_curve), "--surface", w / "surface.stl", "-o", t / "n.json"],
         "300000 points; the limit is 100000"),
    Case("nesting size", "nest --check: one 40 mm washer placed 20,000 times on one sheet",
         lambda w, t: ["nest", "--check", _stacked(w, t, 20.0)], "cannot all fit"),
    Case("nesting size", "export: one 40 mm washer placed 20,000 times on one sheet",
         lambda w, t: ["export", _stacked(w, t, 20.0), "-o", t / "out"], "cannot all fit"),
    Case("part outline", "nest a part 1e-4 mm wide",
         lambda w, t: ["nest", _tiny_part(w, t), "-o", t / "nesting.json"], "part SLIVER"),
]


def test_twenty_thousand_washers_that_fit_on_three_sheets_check_ok(tmp_path):
    """The bound refuses only what cannot fit: 20,000 distinct washers on a 30 mm grid, three sheets, pass."""
    world = world_folder()
    ids = [f"W{k:05d}" for k in range(20_000)]
    grid = [(20.0 + 30.0 * (k % 132), 20.0 + 30.0 * (k // 132 % 65)) for k in range(len(ids))]
    sheets = [[(pid, *grid[k]) for k, pid in enumerate(ids) if k // (132 * 65) == s] for s in range(3)]
    done = run_capped(["nest", "--check", _nesting_of(world, tmp_path, [_washer(pid, 10.0) for pid in ids], sheets)],
                      cwd=tmp_path)
    assert done.returncode == 0 and ": ok: 20000 placements on 3 sheets" in done.stdout, done.stderr[-800:]


def test_twenty_thousand_stacked_washers_that_fit_by_area_are_checked_in_bounded_memory(tmp_path):
    """A 20 mm washer 20,000 times at one spot covers less than the sheet: the pair check lists 100 problems and
    stops, under the memory cap (it asked for 4e8 pairs at once, 6 GB, before)."""
    done = run_capped(["nest", "--check", _stacked(world_folder(), tmp_path, 10.0)], cwd=tmp_path)
    assert done.returncode == 1 and "FAILED" in done.stdout, done.stderr[-800:]
    assert "sheet S001: stopped after 100 problems" in done.stderr


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
