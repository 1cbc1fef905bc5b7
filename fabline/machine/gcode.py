"""A Grbl 1.1h G-code block interpreter: parse one line, check it like the firmware, track modal state.

The controller simulator uses it to accept or reject lines with the firmware's error codes and to plan
motions; the streamer uses it to know the modal state and position after each program line, which is
what a resume needs to re-establish; `gcode-check` uses it to list what the firmware would refuse.

The command set, the order of the checks and the error codes follow Grbl 1.1h's parser (gnea/grbl
`grbl/gcode.c`, `gc_execute_line`: word import, then error checks in NIST execution order) and its
documentation (`doc/markdown/commands.md`, "G-code"; the supported and unsupported list at the end of
gcode.c): G0-G3, G4, G10 L2/L20, G17-G19, G20/G21, G28/G28.1, G30/G30.1, G38.2-G38.5, G40, G43.1, G49,
G53, G54-G59, G61, G80, G90/G91, G91.1, G92/G92.1, G93/G94; M0-M2, M30, M3-M5, M7 (build option M),
M8, M9, M56 (build option R); value words F I J K L N P R S T X Y Z. Positions are machine millimetres;
the work offsets (G54-G59 data, G92, tool length) live in the ModalState, starting at zero as on a
controller whose stored offsets are zero.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, replace

from fabline.machine.build import STOCK_BUILD, BuildInfo

Vector = tuple[float, float, float]

MAX_LINE_NUMBER = 10_000_000
"""gcode.c's limit, the largest line number a 32-bit float holds safely: N10000000 is accepted, N10000001 is error:27."""
MAX_TOOL_NUMBER = 255
LINE_BUFFER_SIZE = 80
"""Grbl's line buffer: at most 79 characters once whitespace and comments are removed, else error:11."""
REALTIME_COMMANDS = {"?": "status report query", "!": "feed hold", "~": "cycle start / resume",
                     "\x18": "soft reset (ctrl-x)"}
"""The single-character commands Grbl's serial input acts on the moment they arrive, wherever they are in a line
(bytes 0x80-0xff are its extended real-time commands: overrides, safety door, jog cancel)."""
MM_PER_INCH = 25.4
ZERO: Vector = (0.0, 0.0, 0.0)
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)")
_WORD = re.compile(r"([A-Z])([+-]?(?:\d+\.?\d*|\.\d+))")
_WELL_FORMED = re.compile(r"(?:[A-Z][+-]?(?:\d+\.?\d*|\.\d+))*")
_PLANES = {"G17": (0, 1, 2), "G18": (2, 0, 1), "G19": (1, 2, 0)}
_VALUE_LETTERS = frozenset("FIJKLNPRSTXYZ")
_NON_NEGATIVE = frozenset("FNPST")
_SINGLE_MEANING = frozenset("NFST")
_AXES = "XYZ"
_STORED_REFERENCES = frozenset({"G10", "G28", "G30", "G38.2", "G38.3", "G38.4", "G38.5", "G43.1", "G53", "G92"})
"""Commands whose positions depend on offsets or positions stored in the controller (see Block.stored_reference)."""


class GcodeError(Exception):
    """A line the firmware rejects, carrying Grbl's numeric error code."""

    def __init__(self, code: int):
        super().__init__(f"error:{code}")
        self.code = code


@dataclass(frozen=True)
class ModalState:
    """The parser state: what `$G` reports, and the offsets `$#` reports (machine = work + offsets).

    `feed` is in the current units per minute (inverse minutes under G93); `systems` are the stored
    G54-G59 origins, `homes` the stored G28 and G30 positions, `g92` the G92 offset and `tool_offset` the
    G43.1 tool length offset on Z, all in machine millimetres.
    """

    motion: str = "G0"
    coord: str = "G54"
    plane: str = "G17"
    units: str = "G21"
    distance: str = "G90"
    feed_mode: str = "G94"
    spindle: str = "M5"
    coolant: str = "M9"
    tool: int = 0
    feed: float = 0.0
    speed: float = 0.0
    tool_length: str = "G49"
    tool_offset: float = 0.0
    g92: Vector = ZERO
    systems: tuple[Vector, ...] = (ZERO,) * 6
    homes: tuple[Vector, Vector] = (ZERO, ZERO)

    def report(self) -> str:
        """The firmware's `$G` answer, e.g. `[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]` (F in mm/min)."""
        feed = self.feed * MM_PER_INCH if self.units == "G20" and self.feed_mode == "G94" else self.feed
        return (f"[GC:{self.motion} {self.coord} {self.plane} {self.units} {self.distance} {self.feed_mode} "
                f"{self.spindle} {self.coolant} T{self.tool} F{feed:.0f} S{self.speed:.0f}]")

    @property
    def work_offset(self) -> Vector:
        """The WCO of status reports: machine position minus work position (coordinate system + G92 + tool length)."""
        origin = self.systems[int(self.coord[1:]) - 54]
        x, y, z = (o + g for o, g in zip(origin, self.g92))
        return (x, y, z + self.tool_offset)

@dataclass(frozen=True)
class Segment:
    """One commanded motion in machine millimetres: a straight move or an arc in a plane."""

    start: Vector
    end: Vector
    rapid: bool
    center: Vector | None = None
    clockwise: bool = False
    plane: tuple[int, int, int] = (0, 1, 2)

    def _arc(self) -> tuple[float, float, float]:
        """Radius, start angle and signed sweep of an arc."""
        a, b, _ = self.plane
        radius = math.hypot(self.start[a] - self.center[a], self.start[b] - self.center[b])
        angle0 = math.atan2(self.start[b] - self.center[b], self.start[a] - self.center[a])
        angle1 = math.atan2(self.end[b] - self.center[b], self.end[a] - self.center[a])
        sweep = angle1 - angle0
        if self.clockwise:
            sweep = sweep - 2 * math.pi if sweep >= -1e-9 else sweep
        else:
            sweep = sweep + 2 * math.pi if sweep <= 1e-9 else sweep
        return radius, angle0, sweep

    @property
    def length(self) -> float:
        """Path length in mm (helical arcs included)."""
        if self.center is None:
            return math.dist(self.start, self.end)
        radius, _, sweep = self._arc()
        linear = self.end[self.plane[2]] - self.start[self.plane[2]]
        return math.hypot(radius * abs(sweep), linear)

    def point_at(self, fraction: float) -> Vector:
        """The point a `fraction` (0..1) of the way along the path."""
        if self.center is None:
            return tuple(s + (e - s) * fraction for s, e in zip(self.start, self.end))
        a, b, c = self.plane
        radius, angle0, sweep = self._arc()
        point = [0.0, 0.0, 0.0]
        angle = angle0 + sweep * fraction
        point[a] = self.center[a] + radius * math.cos(angle)
        point[b] = self.center[b] + radius * math.sin(angle)
        point[c] = self.start[c] + (self.end[c] - self.start[c]) * fraction
        return tuple(point)

    def points(self, count: int) -> list[Vector]:
        """The points 1/count, 2/count, ... 1 of the way along the path (as `point_at` gives them, an arc evaluated
        once)."""
        if self.center is None:
            return [self.point_at(i / count) for i in range(1, count + 1)]
        a, b, c = self.plane
        radius, angle0, sweep = self._arc()
        centre_a, centre_b, start_c, rise = self.center[a], self.center[b], self.start[c], self.end[c] - self.start[c]
        points = []
        for i in range(1, count + 1):
            point = [0.0, 0.0, 0.0]
            angle = angle0 + sweep * i / count
            point[a], point[b] = centre_a + radius * math.cos(angle), centre_b + radius * math.sin(angle)
            point[c] = start_c + rise * i / count
            points.append(tuple(point))
        return points

    def contains(self, point: Vector, tolerance: float) -> bool:
        """Whether `point` lies on this path within `tolerance` mm: a straight move by projection, an arc by its
        radius, sweep and rise (no sampling: a stopped machine is matched against every line it may have been on)."""
        if self.center is None:
            start, end = self.start, self.end
            span = [e - s for s, e in zip(start, end)]
            norm2 = sum(d * d for d in span)
            t = 0.0 if norm2 == 0 else max(0.0, min(1.0, sum((p - s) * d for p, s, d in zip(point, start, span)) / norm2))
            return math.dist(point, self.point_at(t)) <= tolerance
        if math.dist(point, self.start) <= tolerance or math.dist(point, self.end) <= tolerance:
            return True
        a, b, c = self.plane
        radius, angle0, sweep = self._arc()
        if abs(math.hypot(point[a] - self.center[a], point[b] - self.center[b]) - radius) > tolerance:
            return False
        turned = math.atan2(point[b] - self.center[b], point[a] - self.center[a]) - angle0
        turned = turned % (2 * math.pi) if sweep > 0 else -((-turned) % (2 * math.pi))
        if not 0 <= turned / sweep <= 1:
            return False
        return abs(point[c] - (self.start[c] + (self.end[c] - self.start[c]) * turned / sweep)) <= tolerance


@dataclass(frozen=True)
class Block:
    """What one accepted line does: the modal state after it, its motion (if any), its dwell.

    `approach` is the first leg of a G28/G30 move (to the intermediate point) when `segment` is the second;
    `position` is the parser's machine position after the line (Grbl keeps tracking it in check mode);
    `stored_reference` names the command (G10, G28, G30, G38.x, G43.1, G49, G53, G92, G92.1) whose positions
    depend on offsets or positions the controller stores, which a resume after this line cannot re-establish;
    `pause` is M0 (Grbl ignores M1).
    """

    modal: ModalState
    segment: Segment | None
    dwell: float = 0.0
    line_number: int | None = None
    program_end: bool = False
    position: Vector = ZERO
    approach: Segment | None = None
    stored_reference: str | None = None
    pause: bool = False

    @property
    def feed_rate(self) -> float:
        """The programmed feed of this block's motion in mm/min (G93: the segment's length per 1/F minutes)."""
        modal = self.modal
        if modal.feed_mode == "G93":
            return self.segment.length * modal.feed if self.segment is not None else 0.0
        return modal.feed * MM_PER_INCH if modal.units == "G20" else modal.feed


def compact_line(text: str, buffer: int = LINE_BUFFER_SIZE) -> str:
    """What Grbl's protocol loop keeps of a received line (protocol.c): real-time characters, whitespace and
    control characters, `/`, `( )` and `;` comments removed, letters uppercased; error:11 when more than
    `buffer` - 1 characters remain (79 in Grbl's 80-byte line buffer)."""
    out, comment = [], None
    for char in text:
        if char in REALTIME_COMMANDS or char >= "\x80":
            continue
        if comment:
            if comment == "(" and char == ")":
                comment = None
        elif char == "(" or char == ";":
            comment = char
        elif char > " " and char != "/":
            if len(out) >= buffer - 1:
                raise GcodeError(11)
            out.append(char)
    return "".join(out).upper()


def split_words(line: str) -> list[tuple[str, float]]:
    """Split a compact uppercase line into (letter, value) words, failing like the firmware (error 1, 2)."""
    return list(iter_words(line))


def iter_words(line: str) -> Iterator[tuple[str, float]]:
    """The (letter, value) words of a compact line one at a time, as gc_execute_line imports them: a malformed
    word fails (error 1, 2) only when reached, after the words before it were checked."""
    if _WELL_FORMED.fullmatch(line):
        yield from ((letter, float(value)) for letter, value in _WORD.findall(line))
        return
    position = 0
    while position < len(line):
        letter = line[position]
        if not "A" <= letter <= "Z":
            raise GcodeError(1)
        match = _NUMBER.match(line, position + 1)
        if not match:
            raise GcodeError(2)
        yield letter, float(match.group())
        position = match.end()


@dataclass
class _Parsed:
    """Step 2 of gc_execute_line: the block's commands by modal group and its value words."""

    commands: dict[str, str]
    values: dict[str, float]
    axis_command: str | None   # None, "non_modal" (G10/G28/G30/G92), "motion" or "tool_length"


def parse_block(line: str, build: BuildInfo = STOCK_BUILD) -> _Parsed:
    """Import the words of a compact line like Grbl's parser: unsupported commands (20), non-integer command
    values (23), axis-command conflicts (24), modal group violations (21), repeated words (25), negative
    F/N/P/S/T (4), tool number above 255 (38)."""
    commands: dict[str, str] = {}
    values: dict[str, float] = {}
    axis_command = None
    for letter, value in iter_words(line):   # word by word, as the firmware: `E1 X` is error:20, not error:2
        if letter == "G" or letter == "M":
            integer = math.trunc(value)
            mantissa = round(100 * (value - integer))
            if letter == "G":
                group, code, axis_command = _g_command(integer, mantissa, axis_command)
            else:
                if mantissa:
                    raise GcodeError(23)
                group, code = _m_command(integer, build)
            if group in commands:
                raise GcodeError(21)
            commands[group] = code
        elif letter in _VALUE_LETTERS:
            if letter == "T" and value > MAX_TOOL_NUMBER:
                raise GcodeError(38)
            if letter in values:
                raise GcodeError(25)
            if letter in _NON_NEGATIVE and value < 0:
                raise GcodeError(4)
            values[letter] = value
        else:
            raise GcodeError(20)
    return _Parsed(commands, values, axis_command)


def _g_command(integer: int, mantissa: int, axis_command: str | None) -> tuple[str, str, str | None]:
    """(modal group, canonical code, axis command) of a G word, or the firmware's error."""
    if integer in (10, 28, 30, 92):
        if mantissa == 0:
            if axis_command:
                raise GcodeError(24)
            axis_command = "non_modal"
        if integer != 10:
            if mantissa not in (0, 10):
                raise GcodeError(20)
            return "non_modal", f"G{integer}.1" if mantissa else f"G{integer}", axis_command
        group = "non_modal"
    elif integer in (4, 53):
        group = "non_modal"
    elif integer in (0, 1, 2, 3, 38):
        if axis_command:
            raise GcodeError(24)
        axis_command = "motion"
        if integer == 38:
            if mantissa not in (20, 30, 40, 50):
                raise GcodeError(20)
            return "motion", f"G38.{mantissa // 10}", axis_command
        group = "motion"
    elif integer == 80:
        group = "motion"
    elif integer in (17, 18, 19):
        group = "plane"
    elif integer in (90, 91):
        if mantissa == 0:
            group = "distance"
        elif mantissa == 10 and integer == 91:
            return "arc_distance", "G91.1", axis_command   # IJK are always incremental in Grbl: no effect
        else:
            raise GcodeError(20)
    elif integer in (93, 94):
        group = "feed_mode"
    elif integer in (20, 21):
        group = "units"
    elif integer == 40:
        group = "cutter_comp"
    elif integer in (43, 49):
        if axis_command:
            raise GcodeError(24)
        if integer == 43 and mantissa != 10:
            raise GcodeError(20)
        return "tool_length", "G49" if integer == 49 else "G43.1", "tool_length"   # gcode.c clears the mantissa
    elif 54 <= integer <= 59:
        group = "coord"
    elif integer == 61:
        if mantissa:
            raise GcodeError(20)
        group = "path_control"
    else:
        raise GcodeError(20)
    if mantissa:
        raise GcodeError(23)
    return group, f"G{integer}", axis_command


def _m_command(integer: int, build: BuildInfo) -> tuple[str, str]:
    """(modal group, code) of an M word; M7 needs build option M, M56 option R (parking override control)."""
    if integer in (0, 1, 2, 30):
        return "stop", f"M{integer}"
    if integer in (3, 4, 5):
        return "spindle", f"M{integer}"
    if integer in (8, 9) or (integer == 7 and build.mist_coolant):
        return "coolant", f"M{integer}"
    if integer == 56 and "R" in build.options:
        return "override", "M56"
    raise GcodeError(20)


def execute(line: str, modal: ModalState, position: Vector, *, build: BuildInfo = STOCK_BUILD) -> Block:
    """Interpret one compact (no spaces or comments) uppercase line from `modal` at machine `position`,
    checking it in the order of gcode.c's step 3 and raising GcodeError with the firmware's code."""
    parsed = parse_block(line, build)
    commands, values, axis_command = parsed.commands, parsed.values, parsed.axis_command
    used = set(_SINGLE_MEANING)
    axis_words = [letter for letter in _AXES if letter in values]
    if axis_words and not axis_command:
        axis_command = "motion"
    if values.get("N", 0.0) > MAX_LINE_NUMBER:
        raise GcodeError(27)

    units = commands.get("units", modal.units)
    feed_mode = commands.get("feed_mode", modal.feed_mode)
    motion = commands.get("motion", modal.motion)
    non_modal = commands.get("non_modal")
    scale = MM_PER_INCH if units == "G20" else 1.0
    if feed_mode == "G93":   # inverse time: F is required on every feed move and never carried over
        if axis_command == "motion" and motion not in ("G0", "G80") and "F" not in values:
            raise GcodeError(22)
        feed = values.get("F", 0.0)
    elif "F" in values:
        feed = values["F"]
    elif modal.feed_mode == "G94":   # the firmware keeps mm/min: a unit change converts the carried feed
        feed = modal.feed if units == modal.units else modal.feed * (1 / MM_PER_INCH if units == "G20" else MM_PER_INCH)
    else:
        feed = 0.0
    if "override" in commands and "P" in values:
        used.add("P")
    dwell = 0.0
    if non_modal == "G4":
        if "P" not in values:
            raise GcodeError(28)
        dwell = values["P"]
        used.add("P")
    plane = _PLANES[commands.get("plane", modal.plane)]
    xyz = {letter: values[letter] * scale for letter in axis_words}

    tool_length, tool_offset = modal.tool_length, modal.tool_offset
    if axis_command == "tool_length":
        tool_length = commands["tool_length"]
        if tool_length == "G43.1":
            if axis_words != ["Z"]:
                raise GcodeError(37)
            tool_offset = xyz["Z"]
        else:
            tool_offset = 0.0
    coord = commands.get("coord", modal.coord)
    origin = modal.systems[int(coord[1:]) - 54]
    systems, homes, g92 = modal.systems, modal.homes, modal.g92
    target = position
    home = None
    if non_modal == "G10":
        systems = _set_coordinate_data(modal, values, xyz, coord, position, used)
    elif non_modal == "G92":
        if not xyz:
            raise GcodeError(26)
        g92 = tuple(position[i] - origin[i] - xyz[_AXES[i]] - (modal.tool_offset if i == 2 else 0.0)
                    if _AXES[i] in xyz else g92[i] for i in range(3))
    else:
        if axis_command != "tool_length" and xyz:
            target = tuple(_target(i, xyz, position, non_modal, commands.get("distance", modal.distance), origin,
                                   modal) for i in range(3))
        if non_modal in ("G28", "G30"):
            stored = homes[0 if non_modal == "G28" else 1]
            home = tuple(stored[i] if _AXES[i] in xyz or not xyz else position[i] for i in range(3))
            if not xyz:
                axis_command = None
        elif non_modal == "G53" and motion not in ("G0", "G1"):
            raise GcodeError(30)

    segment = None
    if motion == "G80":
        if xyz:
            raise GcodeError(31)
    elif axis_command == "motion":
        if motion in ("G0", "G1"):
            if motion == "G1" and feed == 0:
                raise GcodeError(22)
            if xyz:
                segment = Segment(position, target, rapid=motion == "G0")
        else:
            if feed == 0:
                raise GcodeError(22)
            if not xyz:
                raise GcodeError(26)
            if motion in ("G2", "G3"):
                segment = _arc_segment(motion, plane, position, target, xyz, values, scale, used)
            else:
                if target == position:
                    raise GcodeError(33)
                segment = Segment(position, target, rapid=False)
    leftover = set(values) - used - (set(_AXES) if axis_command else set())
    if leftover:
        raise GcodeError(36)

    approach = None
    if home is not None:
        approach = Segment(position, target, rapid=True) if xyz else None
        segment = Segment(target if xyz else position, home, rapid=True)
    elif non_modal in ("G28.1", "G30.1"):
        homes = (position, homes[1]) if non_modal == "G28.1" else (homes[0], position)
    elif non_modal == "G92.1":
        g92 = ZERO
    changes = {"motion": motion, "coord": coord, "plane": commands.get("plane", modal.plane), "units": units,
               "distance": commands.get("distance", modal.distance), "feed_mode": feed_mode,
               "spindle": commands.get("spindle", modal.spindle), "coolant": _coolant(modal.coolant, commands.get("coolant")),
               "tool": int(values.get("T", 0)), "feed": feed, "speed": values.get("S", modal.speed),
               "tool_length": tool_length, "tool_offset": tool_offset, "g92": g92, "systems": systems, "homes": homes}
    stop = commands.get("stop")
    program_end = stop in ("M2", "M30")
    if program_end:
        changes.update(motion="G1", coord="G54", plane="G17", distance="G90", feed_mode="G94", spindle="M5", coolant="M9")
    new = modal if all(getattr(modal, k) == v for k, v in changes.items()) else replace(modal, **changes)
    reference = non_modal if non_modal in _STORED_REFERENCES else motion if motion.startswith("G38") and segment else None
    if reference is None and (new.g92 != modal.g92 or new.tool_offset != modal.tool_offset):
        reference = non_modal or tool_length   # G92.1 or G49 that cleared an offset
    line_number = int(values["N"]) if "N" in values else None
    end = segment.end if segment is not None else position
    return Block(new, segment, dwell, line_number, program_end, end, approach, reference, stop == "M0")


def _target(axis: int, xyz: dict, position: Vector, non_modal: str | None, distance: str, origin: Vector,
            modal: ModalState) -> float:
    """The machine coordinate an axis word asks for: G53 as is, G90 plus the work offsets, G91 plus the position."""
    letter = _AXES[axis]
    if letter not in xyz:
        return position[axis]
    if non_modal == "G53":
        return xyz[letter]
    if distance == "G91":
        return position[axis] + xyz[letter]
    return xyz[letter] + origin[axis] + modal.g92[axis] + (modal.tool_offset if axis == 2 else 0.0)


def _set_coordinate_data(modal: ModalState, values: dict, xyz: dict, coord: str, position: Vector,
                         used: set) -> tuple[Vector, ...]:
    """G10 L2 (origin as given) or L20 (origin so that here is the given work position), checked like gcode.c."""
    if not xyz:
        raise GcodeError(26)
    if "P" not in values and "L" not in values:
        raise GcodeError(28)
    select = math.trunc(values.get("P", 0.0))
    if select > 6:
        raise GcodeError(29)
    level = math.trunc(values.get("L", 0.0))
    if level == 2:
        if "R" in values:
            raise GcodeError(20)
    elif level != 20:
        raise GcodeError(20)
    used |= {"L", "P"}
    index = select - 1 if select > 0 else int(coord[1:]) - 54
    stored = modal.systems[index]
    if level == 20:
        data = tuple(position[i] - modal.g92[i] - xyz[_AXES[i]] - (modal.tool_offset if i == 2 else 0.0)
                     if _AXES[i] in xyz else stored[i] for i in range(3))
    else:
        data = tuple(xyz.get(_AXES[i], stored[i]) for i in range(3))
    return modal.systems[:index] + (data,) + modal.systems[index + 1:]


def _coolant(state: str, command: str | None) -> str:
    """M7 and M8 add mist and flood (both may be on, `$G` shows `M7 M8`); M9 turns both off."""
    if command is None or command == state:
        return state
    if command == "M9" or state == "M9":
        return command
    return "M7 M8"


def _arc_segment(motion: str, plane: tuple[int, int, int], start: Vector, target: Vector, xyz: dict, values: dict,
                 scale: float, used: set) -> Segment:
    """Check an arc like the firmware (errors 32-35) and return its path."""
    a, b, _ = plane
    if _AXES[a] not in xyz and _AXES[b] not in xyz:
        raise GcodeError(32)
    dx, dy = target[a] - start[a], target[b] - start[b]
    center = list(start)
    if "R" in values:
        used.add("R")
        if target == start:
            raise GcodeError(33)
        radius = values["R"] * scale
        h2 = 4 * radius * radius - dx * dx - dy * dy
        if h2 < 0:
            raise GcodeError(34)
        h = -math.sqrt(h2) / math.hypot(dx, dy)
        if motion == "G3":
            h = -h
        if radius < 0:
            h = -h
        center[a] = start[a] + 0.5 * (dx - dy * h)
        center[b] = start[b] + 0.5 * (dy + dx * h)
    else:
        offsets = {"I": 0, "J": 1, "K": 2}
        if not any(letter in values and axis in (a, b) for letter, axis in offsets.items()):
            raise GcodeError(35)
        used |= {"I", "J", "K"}
        for letter, axis in offsets.items():
            if axis in (a, b):
                center[axis] = start[axis] + values.get(letter, 0.0) * scale
        radius_start = math.hypot(start[a] - center[a], start[b] - center[b])
        radius_end = math.hypot(target[a] - center[a], target[b] - center[b])
        delta = abs(radius_end - radius_start)
        if delta > 0.005 and (delta > 0.5 or delta > 0.001 * radius_start):
            raise GcodeError(33)
    return Segment(start, target, rapid=False, center=tuple(center), clockwise=motion == "G2", plane=plane)
