"""ETA benchmark: the planner's machine time per program against the time the simulator takes to run it.

    python benchmarks/eta_bench.py [--sheets N] [--gcode DIR]

For each program, `fabline.machine.motion.line_timeline` (the estimate the stream bar, `fabline run`, the report
and the runner page start from) is compared with the machine time the Grbl 1.1h simulator
(`fabline.link.simulator.timed_run`: acceleration, junction deviation, $12 arc chords as mc_arc makes them, the
$1 stepper lock at every stop, a 15-block planner the host keeps full) takes, both for the grbl-laser profile's settings. Programs: the first N sheets (default 2) of
the synthetic pavilion job exported with grbl-laser (or every .gcode in DIR, e.g. a `fabline run` output's
gcode folder), and synthetic programs: many short segments, arcs, long straight cuts. The goal is |error| < 5 %.
Simulated machine time is deterministic: the table does not depend on the computer.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.export import ToolpathOptions, export_job
from fabline.export.samplejob import pavilion_job  # noqa: E402
from fabline.link.simulator import DEFAULT_SETTINGS, timed_run  # noqa: E402
from fabline.machine import load_machine  # noqa: E402
from fabline.machine.gcode import ModalState  # noqa: E402
from fabline.machine.motion import line_timeline  # noqa: E402
from fabline.machine.program import parse_program  # noqa: E402
from fabline.units import duration  # noqa: E402

GOAL = 0.05


def synthetic_programs() -> dict[str, str]:
    """Programs that stress the planner in different ways, laser-style (M4 once, S on the cuts)."""
    head, tail = ["G21", "G90", "G17", "G94", "M4 S0"], ["M5", "G0 X0 Y0", "M2"]
    spiral = [f"G1 X{500 + (20 + i * 0.01) * math.cos(i * 0.05):.3f} Y{500 + (20 + i * 0.01) * math.sin(i * 0.05):.3f}"
              f"{' F6000 S800' if i == 0 else ''}" for i in range(20000)]
    holes = []
    for k in range(400):
        x, y = 50 + 60 * (k % 40), 50 + 60 * (k // 40)
        holes += [f"G0 X{x + 2.65:.3f} Y{y:.3f}", f"G3 X{x:.3f} Y{y + 2.65:.3f} I-2.650 J0 F1500 S1000",
                  f"G3 X{x - 2.65:.3f} Y{y:.3f} I0 J-2.650", f"G3 X{x:.3f} Y{y - 2.65:.3f} I2.650 J0",
                  f"G3 X{x + 2.65:.3f} Y{y:.3f} I0 J2.650"]
    straight = []
    for k in range(60):
        y = 20 + 30 * k
        straight += [f"G0 X20 Y{y}", f"G1 X3980 Y{y} F1500 S1000", f"G1 X3980 Y{y + 10}", f"G1 X20 Y{y + 10}"]
    return {"short segments (spiral, 1 mm at F6000)": "\n".join(head + spiral + tail),
            "arcs (400 holes r 2.65 at F1500)": "\n".join(head + holes + tail),
            "long straight cuts (3.96 m at F1500)": "\n".join(head + straight + tail)}


def pavilion_programs(count: int) -> dict[str, str]:
    """The first `count` sheets of the synthetic pavilion job, exported for grbl-laser."""
    nesting, partset = pavilion_job()
    nesting.sheets = nesting.sheets[:count]
    result = export_job(nesting, {p.id: p for p in partset.parts}, load_machine("grbl-laser"), ToolpathOptions(),
                        name="pavilion")
    return {f"pavilion sheet {sheet.sheet}": sheet.gcode for sheet in result.sheets}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sheets", type=int, default=2, help="pavilion sheets to run (default 2)")
    parser.add_argument("--gcode", help="a folder of .gcode programs to use instead of the synthetic pavilion")
    args = parser.parse_args()
    settings = {**DEFAULT_SETTINGS, **load_machine("grbl-laser").controller_settings()}
    programs = ({path.name: path.read_text(encoding="ascii") for path in sorted(Path(args.gcode).glob("*.gcode"))[:args.sheets]}
                if args.gcode else pavilion_programs(args.sheets))
    programs.update(synthetic_programs())
    print(f"{'program':44} {'lines':>7} {'planned':>10} {'simulated':>10} {'error':>8} {'sim CPU s':>9}")
    worst = 0.0
    for name, text in programs.items():
        program = parse_program(text.encode("ascii"), name)
        planned = float(line_timeline(program.plan(ModalState(), (0.0, 0.0, 0.0)), settings)[-1])
        started = time.process_time()
        simulated = timed_run([line.command for line in program.lines], settings=settings)[-1][1]
        cpu = time.process_time() - started
        error = planned / simulated - 1
        worst = max(worst, abs(error))
        print(f"{name[:44]:44} {len(program.lines):7d} {duration(planned):>10} {duration(simulated):>10} {100 * error:+7.2f}% "
              f"{cpu:9.1f}")
    print(f"worst |error| {100 * worst:.2f} % (goal < {100 * GOAL:.0f} %)")
    return 0 if worst < GOAL else 1


if __name__ == "__main__":
    sys.exit(main())
