"""Support for the jobs and runner tests (no tests here): small G-code sheet programs, executed-line logs, the CLI."""

from __future__ import annotations

import sys
from pathlib import Path

from fabline.link import load_program

JOBS_CLI = [sys.executable, "-c", (
    "import argparse, sys\n"
    "from fabline.cli import jobs\n"
    "parser = argparse.ArgumentParser(prog='fabline')\n"
    "jobs.register(parser.add_subparsers(dest='command', required=True))\n"
    "args = parser.parse_args()\n"
    "sys.exit(args.func(args))\n")]
"""`fabline` with only the jobs stage's subcommands, the same handlers: a restarted runner need not wait for
every other stage's imports (scipy and friends), which would dominate a test that restarts it 21 times."""


def square_program(path: Path, x: float, y: float, squares: int = 1, size: float = 5.0) -> Path:
    """A laser program cutting `squares` squares in a row starting at (x, y); coordinates make it unique."""
    lines = ["G21 G90 G17 G94", "M5"]
    for k in range(squares):
        x0 = x + k * (size + 2)
        lines += [f"G0 X{x0:.3f} Y{y:.3f}", "M4 S1000", f"G1 X{x0 + size:.3f} Y{y:.3f} F3000",
                  f"G1 X{x0 + size:.3f} Y{y + size:.3f}", f"G1 X{x0:.3f} Y{y + size:.3f}", f"G1 X{x0:.3f} Y{y:.3f}", "M5"]
    lines += ["G0 X0 Y0", "M2"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


def wire_lines(path: Path) -> list[str]:
    """The program's lines exactly as the controller receives (and the simulator logs) them."""
    return [line.wire.decode("ascii").strip() for line in load_program(path).lines]


def executed_program_lines(log: Path) -> list[str]:
    """The simulator's executed-line log without a resume's modal preamble (lines without an N word)."""
    if not log.exists():
        return []
    return [text for text in log.read_text(encoding="ascii").splitlines() if text.startswith("N")]
