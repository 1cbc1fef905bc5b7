"""Check a G-code program against a machine: what its controller would refuse, moves off the bed, travel with
the tool on, and the cut, mark and travel lengths and run time recomputed with the profile's acceleration.

For a Grbl profile every line goes through the firmware's own parser (`fabline.machine.gcode`, for the
controller's build: stock Grbl 1.1h unless told otherwise), not fabline's writer: each line Grbl would refuse
is a problem with its error code in words (error:11 when the line, spaces and comments removed as Grbl's
line buffer removes them, is over 79 characters), and a refused line changes nothing, as on the controller.
The moves are the parser's own, in machine coordinates (stored offsets zero, as a controller whose G54-G59,
G28 and G30 data were never set): G20, G53, G91.1, G92/G92.1, G10 L2/L20, G28/G30 via their intermediate point,
G43.1/G49 and the G93 inverse-time feed are followed as the firmware follows them. A code the controller
accepts but the profile's exporter never writes (not in its `words`) is a warning, not a problem.
For another controller the lines are read by pygcode and only the profile's words are followed, so any
other code is a problem.

Whatever the profile, lines that would act on the controller rather than be cut are problems: `$` system
commands, the real-time characters `? ! ~` and ctrl-x (Grbl acts on them as they arrive, even inside a
comment), NUL bytes, and an F0 feed on a motion line.

In a laser-mode profile (Grbl $32=1) the controller switches the laser off unless the motion mode is G1-G3,
so a G0 with M4 active is fine; instead every path (opened by its `; <operation>` comment) must reach its start
with a G0, and a feed move with the laser on (M3/M4 and S > 0) before that G0 is travel with the laser on.
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
from fabline.machine.gcode import (LINE_BUFFER_SIZE, REALTIME_COMMANDS, Block, GcodeError, ModalState, Segment,
                                   compact_line, execute, parse_block, split_words)
from fabline.machine.motion import MotionSummary, MoveLog, summarise
from fabline.machine.profile import MOTION_PARAMETERS, MachineProfile, canonical_word

OPERATION_COMMENT = re.compile(r"^\s*;\s*((?:engrave|cut)-[a-z]+)\b")
MOTION_WORDS = {0: "rapid", 1: "line", 2: "cw", 3: "ccw"}
BED_TOLERANCE = 1e-6
ARC_CHORD = 0.5
"""mm: the chord length an arc outside the XY plane is logged in (its XY shadow is not a circle)."""


@dataclass
class CheckReport:
    """Problems found (each with its line number) and the recomputed figures."""

    path: str
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
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
    """Check program text against `profile`, listing every problem and every unexpected code (see the module
    docstring)."""
    report = CheckReport(source)
    state = _State(profile)
    firmware = _Firmware(build if profile.grbl else None, profile.max_line_length)
    unexpected = _Unexpected(profile)
    raw_lines = text.splitlines()
    report.lines = len(raw_lines)
    for number, raw in enumerate(raw_lines, start=1):
        where = f"line {number}"
        if not profile.grbl and len(raw) > profile.max_line_length:
            report.problems.append(f"{where}: {len(raw)} characters, over the limit of {profile.max_line_length}")
        marker = OPERATION_COMMENT.match(raw)
        if marker:
            state.operation = marker.group(1)
            state.positioned = False
        codes = firmware.accepts(raw, where, report.problems)
        if codes is None:
            continue
        if firmware.block is not None:
            unexpected.add(codes, number)
            state.follow(firmware.block, codes, where, report.problems)
        else:
            _read_with_pygcode(raw, state, where, report.problems)
    state.finish()
    report.warnings = unexpected.warnings()
    report.summary = summarise(state.moves, profile.acceleration, profile.junction_deviation, profile.rapid_rate)
    return report


def _read_with_pygcode(raw: str, state: "_State", where: str, problems: list[str]) -> None:
    """A line for a controller without a parser model here: read by pygcode, only the profile's words followed."""
    import pygcode   # imported here: it is slow to import and only a non-Grbl profile needs it

    try:
        block = pygcode.Line(raw).block
    except Exception as exc:   # pygcode raises several exception types for malformed words
        problems.append(f"{where}: cannot parse: {exc}")
        return
    state.apply(block, where, problems)


class _Firmware:
    """What the controller does with each raw line: real-time characters, `$` commands, NUL bytes and F0 feeds
    are problems for any controller; a Grbl build's parser (None: not a Grbl profile) also checks the G-code,
    the line's length as its line buffer counts it (spaces and comments removed) and keeps the modal state
    and machine position, whose Block for the last line accepted is `block`."""

    def __init__(self, build: BuildInfo | None, max_line_length: int):
        self.build, self.max_line_length = build, max_line_length
        self.modal, self.position = ModalState(), (0.0, 0.0, 0.0)
        self.block: Block | None = None

    def accepts(self, raw: str, where: str, problems: list[str]) -> tuple[str, ...] | None:
        """Report what is wrong with `raw` and return its G and M codes (canonical; none read for another
        controller); None when the line must not be read further (the controller would refuse it, or it is not
        G-code)."""
        self.block = None
        for char in sorted({c for c in raw if c in REALTIME_COMMANDS}):
            problems.append(f"{where}: {char!r} is the Grbl real-time command {REALTIME_COMMANDS[char]}, which the "
                            "controller acts on the moment it arrives (even inside a comment): remove it")
        if "\0" in raw:
            problems.append(f"{where}: NUL byte (0x00) in the line: the file is damaged or not G-code")
        line = compact_line(raw, len(raw) + 2)   # what the line buffer would hold, were it long enough
        if self.build is not None and len(line) >= LINE_BUFFER_SIZE:
            problems.append(f"{where}: {explain_error(11)}: {len(line)} characters once spaces and comments are "
                            f"removed, Grbl's line buffer holds {LINE_BUFFER_SIZE - 1}")
            return None
        if line.startswith("$"):
            problems.append(f"{where}: {line!r} is a Grbl system command ($), not G-code: a program must not "
                            "contain it")
            return None
        if self.build is not None and len(line) > self.max_line_length:
            problems.append(f"{where}: {len(line)} characters once spaces and comments are removed, over the "
                            f"profile's max_line_length of {self.max_line_length}")
        try:
            words = split_words(line)
        except GcodeError:
            words = []   # malformed: the parser below says where, with the firmware's code
        if ("F", 0.0) in words and any(letter in "XYZ" or (letter == "G" and value in (0, 1, 2, 3))
                                       for letter, value in words):
            problems.append(f"{where}: F0 feed on a motion line: no feed move can run at F0 (error:22): "
                            f"{raw.strip()}")
        if self.build is None:
            return ()
        try:
            codes = tuple(parse_block(line, self.build).commands.values())
            self.block = execute(line, self.modal, self.position, build=self.build)
        except GcodeError as exc:
            problems.append(f"{where}: {explain_error(exc.code)}: {raw.strip()}")
            return None
        self.modal, self.position = self.block.modal, self.block.position
        return codes


class _Unexpected:
    """The codes a Grbl accepts that the profile's exporter never writes (not in its `words`), with their lines."""

    SHOWN = 3   # line numbers named per code

    def __init__(self, profile: MachineProfile):
        self.profile = profile
        self.lines: dict[str, list[int]] = {}
        self.counts: dict[str, int] = {}

    def add(self, codes: tuple[str, ...], number: int) -> None:
        """Count the codes of line `number` that are not among the profile's words."""
        for code in codes:
            if canonical_word(code) not in self.profile.words:
                self.counts[code] = self.counts.get(code, 0) + 1
                if len(self.lines.setdefault(code, [])) < self.SHOWN:
                    self.lines[code].append(number)

    def warnings(self) -> list[str]:
        """One warning per code, in the order first seen, naming its first lines and how many more."""
        found = []
        for code, lines in self.lines.items():
            more = self.counts[code] - len(lines)
            named = [str(n) for n in lines]
            if more:
                where = f"lines {', '.join(named)} and {more} more"
            elif len(named) == 1:
                where = f"line {named[0]}"
            else:
                where = f"lines {', '.join(named[:-1])} and {named[-1]}"
            found.append(f"{code} ({where}): the controller accepts it, but {self.profile.name}'s exporter never "
                         f"writes it (not in the profile's words)")
        return found


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
        self.depth = 0.0            # the tool's work Z (a mill cuts below 0)

    def tool_on(self) -> bool:
        """Is the tool cutting: laser on with power, pen down (S other than pen-up), or cutter below the top."""
        if self.profile.mode == "laser":
            return self.spindle and self.speed > 0
        if self.profile.mode == "plotter":
            return self.spindle and self.speed != self.profile.variables.get("pen_up", 0.0)
        return self.depth < 0

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
                self.position, self.depth = target, target[2]
                return
            centre = (start[0] + params.get("I", 0.0), start[1] + params.get("J", 0.0))
        self.position, self.depth = target, target[2]
        self._record(start[:2], target[:2], centre, self.motion == 2, self.motion == 0, self.feed,
                     self.motion == 0 and self.profile.laser_mode, f"G{self.motion}", where, problems)

    def follow(self, block: Block, codes: tuple[str, ...], where: str, problems: list[str]) -> None:
        """Update the state from the firmware parser's reading of one accepted line and record its moves (a
        G28/G30 makes two: to the intermediate point, then to the stored position)."""
        modal = block.modal
        if any(code in ("M3", "M4", "M5") for code in codes):
            self.stop_pending = True
        self.spindle, self.speed = modal.spindle != "M5", modal.speed
        if block.dwell:
            self.dwell += block.dwell
            self.stop_pending = True
        laser_off = self.profile.laser_mode and modal.motion not in ("G1", "G2", "G3")   # Grbl's laser disable
        label = next((code for code in codes if code in ("G28", "G30")), modal.motion)
        for segment in (block.approach, block.segment):
            if segment is not None:
                self.depth = segment.end[2] - modal.work_offset[2]
                self._segment(segment, block.feed_rate, laser_off, label, where, problems)
        self.position = np.array(block.position)

    def _segment(self, segment: Segment, feed: float, laser_off: bool, label: str, where: str,
                 problems: list[str]) -> None:
        """Record one firmware segment (machine mm) in XY, as the move log keeps moves: an arc in the ZX or YZ
        plane as the chords of its XY shadow."""
        start, end = segment.start[:2], segment.end[:2]
        if segment.center is None or segment.plane[:2] == (0, 1):
            centre = None if segment.center is None else segment.center[:2]
            self._record(start, end, centre, segment.clockwise, segment.rapid, feed, laser_off, label, where, problems)
            return
        points = [segment.start] + segment.points(max(16, min(10_000, int(segment.length / ARC_CHORD) + 1)))
        self._report_extent([p[0] for p in points], [p[1] for p in points], where, problems)
        for a, b in zip(points, points[1:]):
            self._record(a[:2], b[:2], None, False, False, feed, laser_off, label, where, problems, bed=False)

    def _record(self, start, end, centre, clockwise: bool, rapid: bool, feed: float, laser_off: bool, label: str,
                where: str, problems: list[str], bed: bool = True) -> None:
        """Log one XY move and report travel with the tool on and moves off the bed."""
        cutting = self.tool_on() and not laser_off
        if rapid:
            self.positioned = True
            message = f"{where}: travel move ({label}) with the tool on"
            if cutting and np.hypot(end[0] - start[0], end[1] - start[1]) > 0 and message not in problems[-1:]:
                problems.append(message)   # once for a G28/G30's two legs
        elif cutting and not self.positioned and self.profile.laser_mode:
            problems.append(f"{where}: travel with the laser on ({label} before the G0 to the start of "
                            f"the {self.operation} path; in laser mode only G0 travels with the laser off)")
            self.positioned = True  # once per path: the moves after it are its cut
        if bed:
            self._check_bed(start, end, centre, clockwise, where, problems)
        self.moves.add(tuple(start), tuple(end), self.profile.rapid_rate if rapid else feed, rapid,
                       cutting and not rapid, self.operation.startswith("engrave"), centre, clockwise,
                       self.stop_pending, self.dwell)
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
        self._report_extent(xs, ys, where, problems)

    def _report_extent(self, xs, ys, where: str, problems: list[str]) -> None:
        """Report the extent of a move's points (machine mm) when it leaves the bed."""
        if (min(xs) < -BED_TOLERANCE or min(ys) < -BED_TOLERANCE or max(xs) > self.profile.bed_width + BED_TOLERANCE
                or max(ys) > self.profile.bed_height + BED_TOLERANCE):
            problems.append(f"{where}: move reaches x {min(xs):.3f}..{max(xs):.3f}, y {min(ys):.3f}..{max(ys):.3f} mm, "
                            f"outside the bed (0..{self.profile.bed_width:g} x 0..{self.profile.bed_height:g} mm)")

    def finish(self) -> None:
        """Keep a trailing dwell as time."""
        if self.dwell:
            p = tuple(self.position[:2])
            self.moves.add(p, p, self.profile.rapid_rate, True, False, stop_before=True, dwell=self.dwell)
