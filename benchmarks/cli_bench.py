"""How long the command line takes to answer: `fabline --help`, every command's `--help`, and the first output line
of a few real commands (each a fresh process, as a user starts it).

Usage: python benchmarks/cli_bench.py [--repeat 5] [--only-help]

Prints one row per command: the median wall time from start to the first line of output (stdout or stderr) over
N runs, the median to the process's end, and its peak resident memory (MB, from wait4); the load average is
printed first, since on a shared machine the figures scale with it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def commands_with_help() -> list[list[str]]:
    """`fabline --help` and `fabline ... --help` of every command and sub-command, listed by a process of its own:
    a child inherits its parent's peak memory on Linux, so this process must not grow by building the parser."""
    script = """
import argparse, json
from fabline.cli import build_parser
found = []
def walk(parser, path):
    found.append(path + ["--help"])
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                walk(sub, path + [name])
walk(build_parser(), [])
print(json.dumps(found))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, env=_env())
    return json.loads(done.stdout)


def real_commands(folder: Path) -> list[list[str]]:
    """A few commands whose first line a user waits for, with their inputs made in `folder`."""
    net, program, queue = folder / "net.json", folder / "program.gcode", folder / "runner.sqlite"
    subprocess.run(_argv(["design", "catenoid", "--count", "8", "-o", net]), check=True, capture_output=True)
    program.write_text("G21\nG90\nG0 X1 Y1\nG1 X5 Y5 F1000\nM2\n")
    subprocess.run([sys.executable, "-c", f"from fabline.jobs.queue import JobQueue; JobQueue({str(queue)!r})"],
                   check=True, env=_env())
    return [["limits"], ["limits", "--radius", "2m", "--twist", "0.5"], ["runner", "status", "--db", queue],
            ["gcode-check", program], ["inspect", net], ["nest", folder / "missing.json", "-o", folder / "n.json"],
            ["design", "catenoid", "--count", "8", "-o", folder / "c.json"]]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _argv(args: list) -> list[str]:
    return [sys.executable, "-m", "fabline", *map(str, args)]


def run_once(args: list) -> tuple[float, float, float]:
    """(seconds to the first output line, seconds to the end, peak RSS in MB) of one fresh `fabline ARGS`."""
    start = time.perf_counter()
    process = subprocess.Popen(_argv(args), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=_env())
    process.stdout.readline()
    first = time.perf_counter() - start
    process.stdout.read()
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    process.stdout.close()
    return first, time.perf_counter() - start, usage.ru_maxrss / 1024  # ru_maxrss is in KB on Linux


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per command (the median is shown)")
    parser.add_argument("--only-help", action="store_true", help="only the --help commands")
    options = parser.parse_args()
    print(f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())}; {os.cpu_count()} cores; "
          f"median of {options.repeat} runs; peak RSS is at least this process's "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.1f} MB (a child inherits it)")
    print(f"{'command':<44}{'first line s':>13}{'end s':>8}{'peak RSS MB':>13}")
    with tempfile.TemporaryDirectory(prefix="fabline-cli-bench-") as folder:
        commands = commands_with_help() + ([] if options.only_help else real_commands(Path(folder)))
        worst = {"help": 0.0, "other": 0.0}
        for args in commands:
            runs = [run_once(args) for _ in range(options.repeat)]
            first, end, rss = (statistics.median(r[k] for r in runs) for k in range(3))
            shown = " ".join(str(a).replace(folder + "/", "") for a in args)
            print(f"{'fabline ' + shown:<44}{first:>13.3f}{end:>8.3f}{rss:>13.1f}", flush=True)
            kind = "help" if args[-1] == "--help" else "other"
            worst[kind] = max(worst[kind], first)
    print(f"slowest --help {worst['help']:.3f} s (goal 0.3 s)"
          + ("" if options.only_help else f"; slowest first line of the others {worst['other']:.3f} s (goal 0.5 s)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
