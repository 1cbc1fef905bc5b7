"""Controller compatibility, checked before the first move: do the controller's settings (`$$`) and build (`$I`)
suit the program and the machine profile that made it?

A laser program on a controller with `$32=0` fires the beam on every G0 travel; a program wider than the
travel (`$130..$132`) or outside the soft limits stops with an alarm mid-sheet; M7 on a build without mist
coolant is refused mid-job (error:20); a feed above the max rates (`$110..$112`) is capped by Grbl without a word,
which with a laser at constant power (M3 in laser mode) burns more than planned. Each problem is one line naming the
setting and the fix; a capped feed that only runs slower (M4 scales the power with the speed) is a note. Settings
are in Grbl's numbers whatever the firmware (fabline.link.dialects reads grblHAL's and FluidNC's into them); the fix
is said in the controller's dialect (FluidNC's laser mode is a `Laser:` spindle in its config, not `$32=1`).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Sequence

import numpy as np

from fabline.errors import FablineError
from fabline.link.dialects import GRBL, Dialect
from fabline.machine.build import BuildInfo
from fabline.machine.gcode import Block, Vector
from fabline.machine.program import Program

if TYPE_CHECKING:
    from fabline.machine.profile import MachineProfile

_MIST = re.compile(r"M0*7(?![0-9.])")
_AXES = "XYZ"
_ARC_SAMPLES = 64
_WHY = {32: "laser mode: the beam is off on G0 travel only when $32=1; a spindle or pen servo needs $32=0"}


def program_machine(program: Program, machine: str | None) -> "MachineProfile | None":
    """The profile a program is checked against: `machine` (an operator's --machine) or the one its header names."""
    name = machine or program.machine
    if name is None:
        return None
    from fabline.machine.profile import load_machine  # the export stage is heavy to import: only when a profile is named
    try:
        return load_machine(name)
    except FablineError as exc:
        if machine:
            raise
        raise FablineError(f"{program.name}: made for machine {name}, which is not known here ({exc}); "
                           "give --machine NAME or the path of its profile") from None


def controller_problems(program: Program, blocks: Sequence[Block], origin: Vector, settings: dict[int, float],
                        build: BuildInfo, profile: "MachineProfile | None",
                        wco: Vector | None, dialect: Dialect = GRBL) -> list[str]:
    """Every way the controller conflicts with the program (and its profile), each as a one-line message."""
    problems = []
    if profile is None:
        problems += _laser_mode_problems(program, blocks, settings, dialect)
    else:
        for requirement in profile.required_settings:
            actual = settings.get(requirement.number)
            if actual is None:
                problems.append(f"machine {profile.name} needs {requirement}, but the controller ({dialect.label}) did "
                                f"not report ${requirement.number} in $$ (is it a Grbl 1.1, grblHAL or FluidNC?)")
            elif not requirement.met_by(actual):
                why = f" ({_WHY[requirement.number]})" if requirement.number in _WHY else ""
                problems.append(f"machine {profile.name} needs {requirement}{why}, but the controller has "
                                f"${requirement.number}={actual:g}; "
                                f"{dialect.change(requirement.number, requirement.value)}"
                                ", or give --machine with the profile of this machine")
    if not build.mist_coolant:
        mist = next((line for line in program.lines if _MIST.search(line.command)), None)
        if mist is not None:
            problems.append(f"{program.name}:{mist.file_line}: M7 (mist coolant) is not in this controller's build "
                            f"([OPT:{build.options},...] has no M, Grbl answers error:20); use M8, or a build with M7")
    problems += _travel_problems(blocks, origin, settings, wco)
    problems += feed_problems(program, blocks, settings)[0]
    return problems


def feed_problems(program: Program, blocks: Sequence[Block], settings: dict[int, float]) -> tuple[list[str], list[str]]:
    """Feeds the controller caps (Grbl's limit_value_by_axis_maximum: no axis beyond its `$110+i` along the move):
    (problems, notes). A capped cut with a laser at constant power ($32=1, M3, S > 0) is a problem: the same power
    over a slower cut burns more; any other capped feed is a note (it runs slower than planned)."""
    rates = [settings.get(110 + axis) for axis in range(3)]
    if any(rate is None or rate <= 0 for rate in rates):
        return [], []
    burning, slower = [], []
    for line, block in zip(program.lines, blocks):
        segment = block.segment
        if segment is None or segment.rapid or segment.length <= 0:
            continue
        cap = _rate_cap(segment, rates)
        if block.feed_rate > cap * (1 + 1e-6):
            constant = settings.get(32) == 1 and block.modal.spindle == "M3" and block.modal.speed > 0
            (burning if constant else slower).append((line, block.feed_rate, cap))
    return _feed_messages(program, burning, True), _feed_messages(program, slower, False)


def _rate_cap(segment, rates: list[float]) -> float:
    """The fastest feed (mm/min) along `segment` with no axis over its max rate (an arc: over its sampled chords)."""
    points = [segment.start] + (segment.points(_ARC_SAMPLES) if segment.center is not None else [segment.end])
    cap = np.inf
    for start, end in zip(points, points[1:]):
        step = np.subtract(end, start)
        length = float(np.linalg.norm(step))
        if length > 0:
            moving = np.abs(step) > 1e-12
            cap = min(cap, float(np.min(np.asarray(rates)[moving] * length / np.abs(step[moving]))))
    return cap


def _feed_messages(program: Program, capped: list, burning: bool) -> list[str]:
    if not capped:
        return []
    line, feed, cap = capped[0]
    more = f" (and {len(capped) - 1} more line{'s' if len(capped) > 2 else ''})" if len(capped) > 1 else ""
    effect = ("with the laser at constant power (M3) the slower cut burns more than planned" if burning
              else "the cut runs slower than planned")
    return [f"{program.name}:{line.file_line}: feed {feed:g} mm/min is above what the controller's max rates "
            f"($110..$112) allow along this move, {cap:.0f} mm/min{more}: Grbl caps it and {effect}; lower the "
            "program's feed, or raise the max rates"]


def _laser_mode_problems(program: Program, blocks: Sequence[Block], settings: dict[int, float],
                         dialect: Dialect) -> list[str]:
    """Without a profile, a program that switches a tool on with power (M3/M4 with S) is taken for a laser program."""
    if settings.get(32, 0.0) == 1:
        return []
    for line, block in zip(program.lines, blocks):
        if block.modal.spindle in ("M3", "M4") and block.modal.speed > 0:
            return [f"{program.name}:{line.file_line}: {line.source.strip()!r} switches a laser on, but the controller "
                    f"has $32={settings.get(32, 0.0):g} (laser mode off): every G0 travel would run with the beam on; "
                    f"{dialect.change(32, 1)}, or give --machine with the (non-laser) profile that made the program"]
    return []


def program_extent(blocks: Sequence[Block], origin: Vector) -> tuple[list[float], list[float]]:
    """The lowest and highest work coordinate per axis the program visits, starting at `origin` (arcs sampled)."""
    points = [origin]
    for block in blocks:
        segment = block.segment
        if segment is None:
            continue
        if segment.center is None:
            points.append(segment.end)
        else:
            points.extend(segment.points(_ARC_SAMPLES))
    visited = np.array(points, dtype=float)
    return visited.min(axis=0).tolist(), visited.max(axis=0).tolist()


def _travel_problems(blocks: Sequence[Block], origin: Vector, settings: dict[int, float],
                     wco: Vector | None) -> list[str]:
    """The program must fit the travel ($130..$132); with soft limits on ($20=1) it must also lie inside the machine
    space Grbl checks, -travel..0 in machine coordinates (gnea/grbl system_check_travel_limits)."""
    low, high = program_extent(blocks, origin)
    problems = []
    for axis in range(3):
        travel = settings.get(130 + axis)
        if travel is None:
            continue
        letter = _AXES[axis]
        if high[axis] - low[axis] > travel + 1e-6:
            problems.append(f"the program spans {high[axis] - low[axis]:.3f} mm in {letter} ({low[axis]:.3f} to "
                            f"{high[axis]:.3f}) but the controller's {letter} travel ${130 + axis} is {travel:g} mm; "
                            "use a machine that fits the sheet, or correct the travel setting")
        elif settings.get(20) == 1 and wco is not None:
            top, bottom = high[axis] + wco[axis], low[axis] + wco[axis]
            if top > 1e-6 or bottom < -travel - 1e-6:
                problems.append(f"soft limits are on ($20=1) and the program reaches machine {letter} "
                                f"{bottom:.3f} to {top:.3f}, outside -{travel:g}..0 (${130 + axis}): Grbl would stop it "
                                "with ALARM:2; move the work origin so the sheet lies inside the travel")
    return problems
