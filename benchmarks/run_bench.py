"""Time `fabline run jobs/pavilion.toml` (the README's quick start) stage by stage; the goal is under 2 minutes.

    python benchmarks/run_bench.py [JOB.toml]

Runs the job in a fresh process (as a user would), then prints a table of the stage times from the
report's JSON twin and the wall-clock total against the goal.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
GOAL_S = 120.0


def main() -> int:
    """Run the job, print the table; exit 1 if it failed or missed the goal."""
    job = Path(sys.argv[1]) if len(sys.argv) > 1 else REPO / "jobs" / "pavilion.toml"
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "fabline", "run", str(job)], cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        print(done.stdout + done.stderr)
        print(f"fabline run {job} failed (exit {done.returncode}) after {wall:.1f} s")
        return 1
    report = next(line.split()[1] for line in done.stdout.splitlines() if line.startswith("report: "))
    data = json.loads(Path(report).with_suffix(".json").read_text(encoding="utf-8"))
    print(f"fabline run {job.relative_to(REPO) if job.is_relative_to(REPO) else job}")
    print(f"{'stage':<10}{'seconds':>10}")
    for stage, seconds in data["timings_s"].items():
        print(f"{stage:<10}{seconds:>10.1f}")
    print(f"{'wall':<10}{wall:>10.1f}   (goal < {GOAL_S:.0f} s: {'met' if wall < GOAL_S else 'MISSED'})")
    sheets, stream = data["nesting"]["sheets"], data["stream"]
    parts = data["parts"]["count"] if data["parts"] else 0
    print(f"{parts} parts on {len(sheets)} sheets; "
          f"{stream['executed']} of {stream['lines']} G-code lines executed on the simulator")
    return 0 if wall < GOAL_S else 1


if __name__ == "__main__":
    sys.exit(main())
