"""A GRBL 1.1 G-code block interpreter: parse one line, check it like the firmware, track modal state.

The controller simulator uses it to accept or reject lines with the firmware's error codes and to plan
motions; the streamer uses it to know the modal state and position after each program line, which is
what a resume needs to re-establish.  It covers the GRBL word set fabline writes and the common
mistakes; work offsets (G10/G92/G28/G30/G53) and probing answer error:20 here.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

Vector = tuple[float, float, float]

MAX_LINE_NUMBER = 9_999_999
MAX_TOOL_NUMBER = 255
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)")
_WORD = re.compile(r"([A-Z])([+-]?(?:\d+\.?\d*|\.\d+))")
_WELL_FORMED = re.compile(r"(?:[A-Z][+-]?(?:\d+\.?\d*|\.\d+))*")
_PLANES = {"G17": (0, 1, 2), "G18": (2, 0, 1), "G19": (1, 2, 0)}
_G_GROUPS = {
    0: "motion", 1: "motion", 2: "motion", 3: "motion", 80: "motion",
    4: "non_modal",
    17: "plane", 18: "plane", 19: "plane",
    20: "units", 21: "units",
    90: "distance", 91: "distance",
    94: "feed_mode",
    54: "coord", 55: "coord", 56: "coord", 57: "coord", 58: "coord", 59: "coord",
}
_M_GROUPS = {0: "stop", 1: "stop", 2: "stop", 30: "stop", 3: "spindle", 4: "spindle", 5: "spindle",
             7: "coolant", 8: "coolant", 9: "coolant"}
_VALUE_LETTERS = "FIJKLNPRSTXYZ"
_MODAL_FIELDS = {"motion", "coord", "plane", "units", "distance", "feed_mode", "spindle", "coolant"}


class GcodeError(Exception):
    """A line the firmware rejects, carrying GRBL's numeric error code."""

    def __init__(self, code: int):
        super().__init__(f"error:{code}")
        self.code = code


@dataclass(frozen=True)
class ModalState:
    """The parser state `$G` reports, with feed in mm/min (or inch/min under G20) and spindle speed."""

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

    def report(self) -> str:
        """The firmware's `$G` answer, e.g. `[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]`."""
        return (f"[GC:{self.motion} {self.coord} {self.plane} {self.units} {self.distance} {self.feed_mode} "
                f"{self.spindle} {self.coolant} T{self.tool} F{self.feed:.0f} S{self.speed:.0f}]")


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

    def contains(self, point: Vector, tolerance: float) -> bool:
        """Whether `point` lies on this path within `tolerance` mm."""
        if self.center is None:
            start, end = self.start, self.end
            span = [e - s for s, e in zip(start, end)]
            norm2 = sum(d * d for d in span)
            t = 0.0 if norm2 == 0 else max(0.0, min(1.0, sum((p - s) * d for p, s, d in zip(point, start, span)) / norm2))
            return math.dist(point, self.point_at(t)) <= tolerance
        samples = max(8, int(self.length / max(tolerance, 1e-3)) + 1)
        samples = min(samples, 20000)
        return any(math.dist(point, self.point_at(i / samples)) <= tolerance * 2 for i in range(samples + 1))


@dataclass(frozen=True)
class Block:
    """What one accepted line does: the modal state after it, its motion (if any) and its dwell."""

    modal: ModalState
    segment: Segment | None
    dwell: float = 0.0
    line_number: int | None = None
    program_end: bool = False


def split_words(line: str) -> list[tuple[str, float]]:
    """Split a compact uppercase line into (letter, value) words, failing like the firmware (error 1, 2)."""
    if _WELL_FORMED.fullmatch(line):
        return [(letter, float(value)) for letter, value in _WORD.findall(line)]
    words, position = [], 0
    while position < len(line):
        letter = line[position]
        if not "A" <= letter <= "Z":
            raise GcodeError(1)
        match = _NUMBER.match(line, position + 1)
        if not match:
            raise GcodeError(2)
        words.append((letter, float(match.group())))
        position = match.end()
    return words


def execute(line: str, modal: ModalState, position: Vector) -> Block:
    """Interpret one compact (no spaces or comments) uppercase line from `modal` at machine `position`."""
    words = split_words(line)
    commands: dict[str, str] = {}
    values: dict[str, float] = {}
    for letter, value in words:
        if letter in "GM":
            code = int(value)
            fraction = round(100 * (value - code))
            table = _G_GROUPS if letter == "G" else _M_GROUPS
            if fraction or code not in table:
                raise GcodeError(20)
            group = table[code]
            if group in commands:
                raise GcodeError(21)
            commands[group] = f"{letter}{code}"
        elif letter in _VALUE_LETTERS:
            if letter in values:
                raise GcodeError(25)
            if letter in "FNPST" and value < 0:
                raise GcodeError(4)
            values[letter] = value
        else:
            raise GcodeError(20)
    if "N" in values and values["N"] > MAX_LINE_NUMBER:
        raise GcodeError(27)
    if "T" in values and (values["T"] != int(values["T"])):
        raise GcodeError(23)
    if "T" in values and values["T"] > MAX_TOOL_NUMBER:
        raise GcodeError(38)

    units = commands.get("units", modal.units)
    scale = 25.4 if units == "G20" else 1.0
    changes = {group: code for group, code in commands.items() if group in _MODAL_FIELDS and getattr(modal, group) != code}
    for letter, name in (("T", "tool"), ("F", "feed"), ("S", "speed")):
        if letter in values and values[letter] != getattr(modal, name):
            changes[name] = int(values[letter]) if letter == "T" else values[letter]
    new = replace(modal, **changes) if changes else modal  # most lines change no modal state
    axes = {letter: values[letter] * scale for letter in "XYZ" if letter in values}
    used = set("FNST") | set("XYZ")
    dwell = 0.0
    if commands.get("non_modal") == "G4":
        if axes and "motion" in commands:
            raise GcodeError(24)
        if "P" not in values:
            raise GcodeError(28)
        dwell = values["P"]
        used.add("P")
        if axes:
            raise GcodeError(24)
    segment = None
    if axes or ("motion" in commands and new.motion in ("G2", "G3")):
        if new.motion == "G80":
            raise GcodeError(31)
        target = list(position)
        for index, letter in enumerate("XYZ"):
            if letter in axes:
                target[index] = axes[letter] + (position[index] if new.distance == "G91" else 0.0)
        target = tuple(target)
        if new.motion in ("G1", "G2", "G3") and new.feed == 0:
            raise GcodeError(22)
        if new.motion in ("G0", "G1"):
            segment = Segment(position, target, rapid=new.motion == "G0")
        else:
            segment = _arc_segment(new, position, target, axes, values, scale)
            used |= set("IJKR")
    leftover = set(values) - used
    if leftover:
        raise GcodeError(36)
    program_end = commands.get("stop") in ("M2", "M30")
    if program_end:
        new = replace(new, motion="G1", coord="G54", plane="G17", distance="G90", feed_mode="G94",
                      spindle="M5", coolant="M9")
    line_number = int(values["N"]) if "N" in values else None
    return Block(new, segment, dwell, line_number, program_end)


def _arc_segment(modal: ModalState, start: Vector, target: Vector, axes: dict, values: dict, scale: float) -> Segment:
    """Check an arc like the firmware (errors 26, 32-35) and return its path."""
    plane = _PLANES[modal.plane]
    a, b, _ = plane
    if "XYZ"[a] not in axes and "XYZ"[b] not in axes:
        raise GcodeError(32)
    dx, dy = target[a] - start[a], target[b] - start[b]
    center = list(start)
    if "R" in values:
        if dx == 0 and dy == 0:
            raise GcodeError(33)
        radius = values["R"] * scale
        h2 = 4 * radius * radius - dx * dx - dy * dy
        if h2 < 0:
            raise GcodeError(34)
        h = -math.sqrt(h2) / math.hypot(dx, dy)
        if modal.motion == "G3":
            h = -h
        if radius < 0:
            h = -h
        center[a] = start[a] + 0.5 * (dx - dy * h)
        center[b] = start[b] + 0.5 * (dy + dx * h)
    else:
        offsets = {"I": 0, "J": 1, "K": 2}
        if not any(letter in values and offsets[letter] in (a, b) for letter in "IJK"):
            raise GcodeError(35)
        for letter, axis in offsets.items():
            center[axis] = start[axis] + values.get(letter, 0.0) * scale
        radius_start = math.hypot(start[a] - center[a], start[b] - center[b])
        radius_end = math.hypot(target[a] - center[a], target[b] - center[b])
        delta = abs(radius_end - radius_start)
        if delta > 0.005 and (delta > 0.5 or delta > 0.001 * radius_start):
            raise GcodeError(33)
    return Segment(start, target, rapid=False, center=tuple(center), clockwise=modal.motion == "G2", plane=plane)
