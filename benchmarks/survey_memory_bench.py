"""Peak memory of `fabline survey simulate` and `fabline survey measure`: wall, CPU and peak resident set size.

Each command runs as a subprocess of the CLI (a fresh interpreter) started by a small watcher process of its own,
which reads `resource.getrusage(RUSAGE_CHILDREN)` after waiting for it: the kernel's maximum resident set of that one
child (the watcher has no other child, so no other run's peak can stand in for it). The model is the example job's Enneper design (9 x 12 m,
0.35 m spacing, k_max 1.05: 523 nodes); the default is the issue's case, 32 photos of 6000 x 4000 px (24 MP).
Run: python benchmarks/survey_memory_bench.py [--photos 32 8] [--resolution 6000x4000] [--no-measure]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def watch(arguments: list[str]) -> None:
    """In the watcher process: run one `fabline` command, print its wall s, CPU s and peak RSS GiB."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fabline", *arguments], check=True, cwd=ROOT,
                   env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(json.dumps([wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 2**20]))  # ru_maxrss: KiB on Linux


def run(arguments: list[str]) -> tuple[float, float, float]:
    """Wall s, CPU s (user + system) and peak RSS GiB of one `fabline` command, measured by its own watcher."""
    done = subprocess.run([sys.executable, __file__, "--watch", *arguments], check=True, stdout=subprocess.PIPE, text=True)
    return tuple(json.loads(done.stdout.splitlines()[-1]))


def main() -> None:
    if sys.argv[1:2] == ["--watch"]:
        watch(sys.argv[2:])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=int, nargs="+", default=[32])
    parser.add_argument("--resolution", default="6000x4000")
    parser.add_argument("--no-measure", action="store_true", help="time simulate only")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "model.network.json"
        subprocess.run([sys.executable, "-m", "fabline", "design", "enneper", "--size", "9x12", "--spacing", "0.35",
                        "--k-max", "1.05", "-o", str(model)], check=True, cwd=ROOT, stdout=subprocess.DEVNULL,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
        for photos in args.photos:
            folder = Path(tmp) / f"sim{photos}"
            wall, cpu, peak = run(["survey", "simulate", "--model", str(model), "-o", str(folder), "--photos", str(photos),
                                   "--resolution", args.resolution])
            rows.append(("simulate", photos, args.resolution, wall, cpu, peak))
            if not args.no_measure:
                wall, cpu, peak = run(["survey", "measure", str(folder / "photos"), "--model", str(model), "--camera",
                                       str(folder / "camera.json"), "--tags", str(folder / "tagmap.json"),
                                       "-o", str(Path(tmp) / f"survey{photos}")])
                rows.append(("measure", photos, args.resolution, wall, cpu, peak))
    print(f"{'command':<10}{'photos':>7}  {'resolution':<11}{'wall s':>8}{'CPU s':>8}{'peak RSS GiB':>13}")
    for command, photos, resolution, wall, cpu, peak in rows:
        print(f"{command:<10}{photos:>7}  {resolution:<11}{wall:>8.1f}{cpu:>8.1f}{peak:>13.2f}")


if __name__ == "__main__":
    main()
