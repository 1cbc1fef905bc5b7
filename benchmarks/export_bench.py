"""Export benchmark: time to export a pavilion-sized job, and travel/time of fabline's ordering against peers.

    python benchmarks/export_bench.py [--nesting nesting.json] [--machine grbl-laser] [--sheets N] [--no-peers]

Without --nesting it uses the synthetic pavilion job (fabline.export.samplejob.pavilion_job: 700 strips,
1400 washers, 350 clamps). The export is timed as a whole (wall and CPU seconds of all processes), then
stage by stage in one process (CPU seconds), which shows where the time goes. Travel and estimated
machine time are compared for the same kerf-offset
toolpaths in three orders: the nesting's plain part order, fabline's (nearest neighbour + 2-opt with start
points), and vpype's `linesort` (greedy, and with --two-opt), the peer from PyPI (`bench` extra).
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import multiprocessing
import os
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.export import ToolpathOptions, export_job, load_job, sheet_toolpaths
from fabline.export import dxf, toolpath  # noqa: E402
from fabline.export.contours import reverse  # noqa: E402
from fabline.export.gcode import sheet_program  # noqa: E402
from fabline.export.samplejob import pavilion_job  # noqa: E402
from fabline.export.toolpath import Toolpath  # noqa: E402
from fabline.machine import OPERATIONS, load_machine, summarise


def benchmark_job(nesting_path: str | None):
    """The job to measure: a real nesting file when given, else the synthetic pavilion (re-point this for real data)."""
    if nesting_path:
        return load_job(nesting_path)
    nesting, partset = pavilion_job()
    return nesting, {p.id: p for p in partset.parts}


def timed(function, *args, **kwargs):
    """(result, wall seconds, CPU seconds of this process and its finished workers): CPU time is what counts
    on a shared machine; the export runs its sheets in worker processes."""
    wall, cpu = time.perf_counter(), _cpu_with_workers()
    result = function(*args, **kwargs)
    elapsed = time.perf_counter() - wall
    while multiprocessing.active_children():     # joins the export's workers so their CPU time is counted
        time.sleep(0.01)
    return result, elapsed, _cpu_with_workers() - cpu


def _cpu_with_workers() -> float:
    times = os.times()
    return times.user + times.system + times.children_user + times.children_system


def stage_times(nesting, parts, profile) -> dict[str, float]:
    """CPU seconds of each export stage over all sheets, run in this one process; the ordering steps inside
    the toolpaths are timed on their own as well."""
    seconds: dict[str, float] = defaultdict(float)

    def clocked(name, function):
        def run(*args, **kwargs):
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                seconds[name] += time.process_time() - start
        return run

    gc.freeze()         # as every export worker does with the job it inherits (job._start_worker)
    inner = {"  nearest neighbour": "_nearest_neighbour", "  2-opt": "_two_opt", "  start points": "_restart"}
    originals = {attribute: getattr(toolpath, attribute) for attribute in inner.values()}
    for label, attribute in inner.items():
        setattr(toolpath, attribute, clocked(label, originals[attribute]))
    try:
        options = ToolpathOptions(kerf=profile.kerf)
        for sheet in nesting.sheets:
            paths = clocked("toolpaths (kerf, order, starts)", sheet_toolpaths)(sheet, parts, options)
            _, moves = clocked("G-code text", sheet_program)(paths, profile)
            clocked("motion summary", summarise)(moves, profile.acceleration, profile.junction_deviation)
            clocked("DXF per sheet", dxf.drawing_text)([sheet], parts)
        clocked("DXF all sheets", dxf.drawing_text)(nesting.sheets, parts)
    finally:
        for attribute, function in originals.items():
            setattr(toolpath, attribute, function)
    order = ["toolpaths (kerf, order, starts)", *inner, "G-code text", "motion summary", "DXF per sheet", "DXF all sheets"]
    return {name: seconds[name] for name in order}


def vpype_order(paths: list[Toolpath], two_opt: bool) -> list[Toolpath]:
    """The same toolpaths ordered by vpype's linesort, operation group by operation group (cutting order kept)."""
    import vpype as vp
    import vpype_cli

    ordered = []
    for operation in OPERATIONS:
        group = [p for p in paths if p.operation == operation]
        if len(group) < 2:
            ordered.extend(group)
            continue
        by_ends = defaultdict(list)
        lines = vp.LineCollection()
        for path in group:
            points = path.contour[:, 0] + 1j * path.contour[:, 1]
            by_ends[(_key(points[0]), _key(points[-1]))].append(path)
            lines.append(points)
        document = vp.Document(lines)
        result = vpype_cli.execute("linesort --two-opt" if two_opt else "linesort", document)
        for line in next(iter(result.layers.values())):
            key = (_key(line[0]), _key(line[-1]))
            if by_ends.get(key):
                ordered.append(by_ends[key].pop())
            else:
                path = by_ends[key[::-1]].pop()
                ordered.append(Toolpath(path.operation, path.part, reverse(path.contour), path.closed))
    return ordered


def _key(point: complex) -> tuple[float, float]:
    return (round(point.real, 6), round(point.imag, 6))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nesting", help="a fabline.nesting/1 file (default: the synthetic pavilion job)")
    parser.add_argument("--machine", default="grbl-laser")
    parser.add_argument("--sheets", type=int, default=0, help="compare orders on the first N sheets only (0: all)")
    parser.add_argument("--no-peers", action="store_true", help="skip vpype")
    args = parser.parse_args(argv)

    nesting, parts = benchmark_job(args.nesting)
    profile = load_machine(args.machine)
    options = ToolpathOptions(kerf=profile.kerf)
    print(f"job: {len(nesting.sheets)} sheets, {sum(len(s.placements) for s in nesting.sheets)} placements, "
          f"{len(parts)} parts; machine {profile.name}, kerf {profile.kerf} mm")

    print("\nexport time (seconds)")
    print(f"{'what':<34}{'wall':>8}{'CPU':>8}   (CPU: all processes; {os.cpu_count()} cores)")
    with tempfile.TemporaryDirectory() as folder:
        for label, dxf_dir, gcode_dir, previews in (
                ("toolpaths + G-code", None, Path(folder) / "g", False),
                ("toolpaths + G-code + DXF", Path(folder) / "d", Path(folder) / "g2", False),
                ("  + cut-order previews", Path(folder) / "d3", Path(folder) / "g3", True)):
            _, wall, cpu = timed(export_job, nesting, parts, profile, ToolpathOptions(kerf=profile.kerf),
                                 dxf_dir, gcode_dir, "bench", previews=previews)
            print(f"{label:<34}{wall:>8.2f}{cpu:>8.2f}")

    print("\nwhere the CPU time goes (one process, CPU seconds)")
    stages = stage_times(nesting, parts, profile)
    total = sum(v for k, v in stages.items() if not k.startswith(" "))
    for label, seconds in stages.items():
        print(f"{label:<34}{seconds:>8.2f}{seconds / total * 100:>7.0f}%")
    print(f"{'total':<34}{total:>8.2f}")

    sheets = nesting.sheets[: args.sheets] if args.sheets else nesting.sheets
    orders = {"plain (nesting order)": lambda s: sheet_toolpaths(s, parts, ToolpathOptions(kerf=profile.kerf, optimise=False)),
              "fabline (NN + 2-opt + starts)": lambda s: sheet_toolpaths(s, parts, options)}
    if not args.no_peers:
        if importlib.util.find_spec("vpype") is None:
            print("vpype is not installed (pip install 'fabline[bench]'): peers skipped", file=sys.stderr)
        else:
            orders["vpype linesort"] = lambda s: vpype_order(orders["plain (nesting order)"](s), False)
            orders["vpype linesort --two-opt"] = lambda s: vpype_order(orders["plain (nesting order)"](s), True)
    print(f"\ntravel and estimated machine time over {len(sheets)} sheets (same toolpaths, different order)")
    print(f"{'order':<32}{'travel m':>10}{'vs plain':>10}{'time h':>9}{'order s':>9}")
    plain_travel = None
    for label, make in orders.items():
        travel = hours = seconds = 0.0
        for sheet in sheets:
            paths, _, cpu = timed(make, sheet)
            seconds += cpu
            summary = summarise(sheet_program(paths, profile)[1], profile.acceleration, profile.junction_deviation)
            travel += summary.travel / 1000
            hours += summary.time / 3600
        plain_travel = plain_travel or travel
        print(f"{label:<32}{travel:>10.1f}{(travel / plain_travel - 1) * 100:>9.1f}%{hours:>9.2f}{seconds:>9.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
