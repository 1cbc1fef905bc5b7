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

PROFILE_CASES: list[Case] = []


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
