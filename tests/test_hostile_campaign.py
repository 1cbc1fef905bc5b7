"""The hostile campaign (issue 25): options and files that ask for more than any job needs (a size, a count, a
memory or a duration) or that break a parser from the inside (format strings, deep nesting, numbers at the ends
of the range). Every case runs as a user runs it, in its own process under a 6 GiB address-space cap and a 60 s
clock, and must end in one line on stderr that says what is at fault, exit 2 and no traceback, with the world's
files unchanged. The count of cases per kind is printed at the end of the run (conftest.py)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest

from test_bad_input_campaign import _digest, _png_claiming, world_folder

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

PROFILE_CASES: list[Case] = []


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
