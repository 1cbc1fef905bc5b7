"""Check a G-code program against a machine profile by reading it back with pygcode (not fabline's writer).

Reports unsupported words, lines over the controller's limit, moves outside the bed, travel moves with
the tool on (laser firing or pen down during G0), and recomputes cut, mark and travel lengths and the run
time with the profile's acceleration.

For a Grbl profile every line also goes through the firmware's own parser (`fabline.machine.gcode`, for the
controller's build: stock Grbl 1.1h unless told otherwise), and each line Grbl would refuse is reported with
its error code in words; a refused line changes nothing, as on the controller. Whatever the profile, lines
that would act on the controller rather than be cut are problems: `$` system commands, the real-time
characters `? ! ~` and ctrl-x (Grbl acts on them as they arrive, even inside a comment), NUL bytes, and an
F0 feed on a motion line.

In a laser-mode profile (Grbl $32=1) the controller switches the laser off on G0, so a G0 with M4 active
is fine; instead every path (opened by its `; <operation>` comment) must reach its start with a G0, and a
feed move with the laser on (M3/M4 and S > 0) before that G0 is travel with the laser on.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_bytes
from fabline.machine.build import STOCK_BUILD, BuildInfo
from fabline.machine.codes import explain_error
from fabline.machine.gcode import REALTIME_COMMANDS, GcodeError, ModalState, compact_line, execute, split_words
from fabline.machine.motion import IDLE_LOCK, MotionSummary, MoveLog, summarise
from fabline.machine.profile import MOTION_PARAMETERS, MachineProfile, canonical_word

OPERATION_COMMENT = re.compile(r"^\s*;\s*((?:engrave|cut)-[a-z]+)\b")
MOTION_WORDS = {0: "rapid", 1: "line", 2: "cw", 3: "ccw"}
BED_TOLERANCE = 1e-6


@dataclass
class CheckReport:
    """Problems found (each with its line number) and the recomputed figures."""

    path: str
    problems: list[str] = field(default_factory=list)
    summary: MotionSummary | None = None
    lines: int = 0


def check_gcode(path: str | os.PathLike, profile: MachineProfile, build: BuildInfo = STOCK_BUILD) -> CheckReport:
    """Parse a G-code file and check it against `profile` (a Grbl one for `build`); an unreadable file is a
    FablineError."""
    data = read_bytes(path, "gcode")
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise FablineError(f"{path}:{line}: byte 0x{data[exc.start]:02x} is not ASCII (G-code must be ASCII)") from None
    return check_program(text, profile, str(path), build)


def check_program(text: str, profile: MachineProfile, source: str = "program",
                  build: BuildInfo = STOCK_BUILD) -> CheckReport:
    """Check program text against `profile`, listing every problem (see the module docstring)."""
    import pygcode   # imported here: it is slow to import and only this check needs it

    report = CheckReport(source)
    state = _State(profile)
    firmware = _Firmware(build if profile.grbl else None)
    raw_lines = text.splitlines()
    report.lines = len(raw_lines)
    for number, raw in enumerate(raw_lines, start=1):
        where = f"line {number}"
        if len(raw) > profile.max_line_length:
            report.problems.append(f"{where}: {len(raw)} characters, over the limit of {profile.max_line_length}")
        marker = OPERATION_COMMENT.match(raw)
        if marker:
            state.operation = marker.group(1)
            state.positioned = False
        if not firmware.accepts(raw, where, report.problems):
            continue
        try:
            block = pygcode.Line(raw).block
        except Exception as exc:   # pygcode raises several exception types for malformed words
            if not profile.grbl:   # (a Grbl profile's lines were parsed by the firmware's rules above)
                report.problems.append(f"{where}: cannot parse: {exc}")
            continue
        state.apply(block, where, report.problems)
    state.finish()
    report.summary = summarise(state.moves, profile.acceleration, profile.junction_deviation, profile.rapid_rate,
                               idle_lock=IDLE_LOCK if profile.grbl else 0.0)
    return report


class _Firmware:
    """What the controller does with each raw line: real-time characters, `$` commands, NUL bytes and F0 feeds
    are problems for any controller; a Grbl build's parser (None: not a Grbl profile) also checks the G-code."""

    def __init__(self, build: BuildInfo | None):
        self.build = build
        self.modal, self.position = ModalState(), (0.0, 0.0, 0.0)

    def accepts(self, raw: str, where: str, problems: list[str]) -> bool:
        """Report what is wrong with `raw`; False when the line must not be read further (the controller would
        refuse it, or it is not G-code)."""
        for char in sorted({c for c in raw if c in REALTIME_COMMANDS}):
            problems.append(f"{where}: {char!r} is the Grbl real-time command {REALTIME_COMMANDS[char]}, which the "
                            "controller acts on the moment it arrives (even inside a comment): remove it")
        if "\0" in raw:
            problems.append(f"{where}: NUL byte (0x00) in the line: the file is damaged or not G-code")
        try:
            line = compact_line(raw)
            if line.startswith("$"):
                problems.append(f"{where}: {line!r} is a Grbl system command ($), not G-code: a program must not "
                                "contain it")
                return False
            words = split_words(line)
            if ("F", 0.0) in words and any(letter in "XYZ" or (letter == "G" and value in (0, 1, 2, 3))
                                           for letter, value in words):
                problems.append(f"{where}: F0 feed on a motion line: no feed move can run at F0 (error:22): "
                                f"{raw.strip()}")
            if self.build is not None:
                block = execute(line, self.modal, self.position, build=self.build)
                self.modal, self.position = block.modal, block.position
        except GcodeError as exc:
            if self.build is None:
                return True   # another controller: the profile's words and line length are checked below
            problems.append(f"{where}: {explain_error(exc.code)}: {raw.strip()}")
            return False
        return True


def _non_negative(word, previous: float, where: str, problems: list[str]) -> float:
    """An F, S or P word's value; a negative one, which GRBL refuses (error:4), is reported and `previous` kept."""
    if word.value < 0:
        problems.append(f"{where}: {word.letter}{word.value:g} is negative (GRBL refuses it: error:4)")
        return previous
    return float(word.value)


class _State:
    """The controller's modal state while reading a program: position, motion mode, feed, tool."""

    def __init__(self, profile: MachineProfile):
        self.profile = profile
        self.position = np.zeros(3)
        self.motion = None
        self.feed = 0.0
        self.spindle = False
        self.speed = 0.0
        self.absolute = True
        self.operation = ""
        self.moves = MoveLog()
        self.stop_pending = True
        self.dwell = 0.0
        self.positioned = True      # laser mode: the current path's G0 to its start has been read

    def tool_on(self) -> bool:
        """Is the tool cutting: laser on with power, pen down (S other than pen-up), or cutter below the top."""
        if self.profile.mode == "laser":
            return self.spindle and self.speed > 0
        if self.profile.mode == "plotter":
            return self.spindle and self.speed != self.profile.variables.get("pen_up", 0.0)
        return self.position[2] < 0

    def apply(self, block, where: str, problems: list[str]) -> None:
        """Update the state from one parsed block and record its move, reporting what the controller would refuse."""
        motion_params = {}
        for gcode in block.gcodes:
            letter, value = gcode.word.letter, gcode.word.value
            word = canonical_word(f"{letter}{value}") if letter in "GM" else None
            if word is not None and word not in self.profile.words:
                problems.append(f"{where}: {word} is not supported by {self.profile.name}")
            if letter == "F":
                self.feed = _non_negative(gcode.word, self.feed, where, problems)
            elif letter == "S":
                self.speed = _non_negative(gcode.word, self.speed, where, problems)
            elif word in ("M3", "M4"):
                self.spindle = True
                self.stop_pending = True
            elif word == "M5":
                self.spindle = False
                self.stop_pending = True
            elif word == "G90":
                self.absolute = True
            elif word == "G91":
                self.absolute = False
            elif word == "G4":
                self.dwell += _non_negative(gcode.params["P"], 0.0, where, problems) if "P" in gcode.params else 0.0
                self.stop_pending = True
            elif letter == "G" and int(value) in MOTION_WORDS and value == int(value):
                self.motion = int(value)
                motion_params = {k: float(v.value) for k, v in gcode.params.items()}
        for word in block.modal_params:
            if word.letter not in MOTION_PARAMETERS:
                problems.append(f"{where}: {word.letter}{word.value:g} is not supported by {self.profile.name}")
            elif word.letter in "XYZIJ":
                motion_params[word.letter] = float(word.value)
            elif word.letter == "F":
                self.feed = _non_negative(word, self.feed, where, problems)
            elif word.letter == "S":
                self.speed = _non_negative(word, self.speed, where, problems)
        if motion_params and self.motion is not None and any(k in motion_params for k in "XYZ"):
            self._move(motion_params, where, problems)

    def _move(self, params: dict, where: str, problems: list[str]) -> None:
        target = self.position.copy()
        for axis, index in (("X", 0), ("Y", 1), ("Z", 2)):
            if axis in params:
                target[index] = params[axis] if self.absolute else target[index] + params[axis]
        start = self.position.copy()
        centre = None
        if self.motion in (2, 3):
            if "I" not in params and "J" not in params:
                problems.append(f"{where}: arc without I/J offsets (R arcs are not checked)")
                self.position = target
                return
            centre = (start[0] + params.get("I", 0.0), start[1] + params.get("J", 0.0))
        self.position = target
        cutting = self.tool_on() and not (self.motion == 0 and self.profile.laser_mode)
        if self.motion == 0:
            self.positioned = True
            if cutting and np.hypot(*(target[:2] - start[:2])) > 0:
                problems.append(f"{where}: travel move (G0) with the tool on")
        elif cutting and not self.positioned and self.profile.laser_mode:
            problems.append(f"{where}: travel with the laser on (G{self.motion} before the G0 to the start of "
                            f"the {self.operation} path; in laser mode only G0 travels with the laser off)")
            self.positioned = True  # once per path: the moves after it are its cut
        self._check_bed(start[:2], target[:2], centre, self.motion == 2, where, problems)
        self.moves.add(tuple(start[:2]), tuple(target[:2]), self.profile.rapid_rate if self.motion == 0 else self.feed,
                       self.motion == 0, cutting and self.motion != 0, self.operation.startswith("engrave"), centre,
                       self.motion == 2, self.stop_pending, self.dwell)
        self.stop_pending, self.dwell = False, 0.0

    def _check_bed(self, start, end, centre, clockwise: bool, where: str, problems: list[str]) -> None:
        """Report a move whose extent (an arc's too, through its quadrant points) leaves the bed."""
        xs, ys = [start[0], end[0]], [start[1], end[1]]
        if centre is not None:
            radius = float(np.hypot(start[0] - centre[0], start[1] - centre[1]))
            a0 = np.arctan2(start[1] - centre[1], start[0] - centre[0])
            a1 = np.arctan2(end[1] - centre[1], end[0] - centre[0])
            sweep = ((a0 - a1) if clockwise else (a1 - a0)) % (2 * np.pi) or 2 * np.pi
            for k in range(4):     # the arc's extreme points where it passes 0, 90, 180, 270 degrees
                angle = k * np.pi / 2
                swept = ((a0 - angle) if clockwise else (angle - a0)) % (2 * np.pi)
                if swept <= sweep:
                    xs.append(centre[0] + radius * np.cos(angle))
                    ys.append(centre[1] + radius * np.sin(angle))
        if (min(xs) < -BED_TOLERANCE or min(ys) < -BED_TOLERANCE or max(xs) > self.profile.bed_width + BED_TOLERANCE
                or max(ys) > self.profile.bed_height + BED_TOLERANCE):
            problems.append(f"{where}: move reaches x {min(xs):.3f}..{max(xs):.3f}, y {min(ys):.3f}..{max(ys):.3f} mm, "
                            f"outside the bed (0..{self.profile.bed_width:g} x 0..{self.profile.bed_height:g} mm)")

    def finish(self) -> None:
        """Keep a trailing dwell as time."""
        if self.dwell:
            p = tuple(self.position[:2])
            self.moves.add(p, p, self.profile.rapid_rate, True, False, stop_before=True, dwell=self.dwell)
