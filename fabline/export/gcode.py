"""G-code text for one sheet: a header, the profile's start and end blocks, and every toolpath with its passes.

One command per line, coordinates in fixed precision, arcs as G2/G3 with I/J relative to the start
(Grbl's default), only the words the profile lists, no line longer than the controller accepts, and
nothing that varies between runs, so the same input gives the same bytes.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache

import numpy as np

from fabline.errors import FablineError
from fabline.export.contours import reverse
from fabline.export.toolpath import Toolpath
from fabline.machine.motion import MoveLog
from fabline.machine.profile import MachineProfile, strip_comment
from fabline.unroll.parts import flatten_contour

ARC_FLATTEN_TOLERANCE = 0.005   # mm, for arcs written as lines (profile without arcs, or arcs too flat to write)
ARC_RADIUS_TOLERANCE = 0.002    # mm, largest start/end radius mismatch accepted after rounding (Grbl allows 0.005)
MIN_SAGITTA = 0.001             # mm, arcs flatter than this are written as a straight move
DWELL = re.compile(r"^\s*G0*4\s+P\s*([-+]?\d*\.?\d+)", re.IGNORECASE)
MOTION = re.compile(r"^\s*G0*([01])(?![\d.])", re.IGNORECASE)
UNPRINTABLE = re.compile(r"[^\x20-\x7e]|[?!~]")   # not allowed in a comment line (Grbl acts on ? ! ~ at once)
BRACKETS = str.maketrans("()", "[]")          # parentheses would open an RS-274 comment inside the `;` one
AXIS = re.compile(r"([XY])\s*([-+]?\d*\.?\d+)", re.IGNORECASE)


class GcodeWriter:
    """Accumulates the lines of one program and the MoveLog that describes what the machine will do."""

    def __init__(self, profile: MachineProfile):
        self.profile = profile
        self.decimals = profile.decimals
        self.xy_format = f"X{{:.{profile.decimals}f}} Y{{:.{profile.decimals}f}}"   # for rounded values only
        self.ij_format = f"I{{:.{profile.decimals}f}} J{{:.{profile.decimals}f}}"
        self.lines: list[str] = []
        self.moves = MoveLog()
        self.position = (0.0, 0.0)
        self.feed: float | None = None
        self.power: float | None = None   # laser mode: the S cutting moves carry (None: templates switch the tool)
        self.speed = 0.0                  # laser mode: the modal S last written
        self.mark = False
        self.tool_on = False
        self.stop_pending = True
        self.dwell_pending = 0.0

    def fmt(self, value: float) -> str:
        """A coordinate in the profile's fixed precision, never "-0.000"."""
        return self.profile.number(value)

    def rounded(self, point) -> tuple[float, float]:
        """A point as it will read back from the file."""
        return (round(point[0], self.decimals) + 0.0, round(point[1], self.decimals) + 0.0)

    def comment(self, text: str) -> None:
        """A `;` comment line, ASCII only, cut to the line limit."""
        clean = UNPRINTABLE.sub("_", text).translate(BRACKETS)
        self.lines.append(f"; {clean}"[: self.profile.max_line_length])

    def template(self, lines: list[str]) -> None:
        """Profile command lines (checked when the profile was loaded); they stop the planner, and any dwell or
        straight move in them is tracked."""
        for line in lines:
            self.lines.append(line)
            dwell, rapid, axes, sets_feed = _template_effect(line)
            self.dwell_pending += dwell
            if axes:
                target = (axes.get("X", self.position[0]), axes.get("Y", self.position[1]))
                self._record(target, None, False, rapid=rapid, feed=self.feed)
            if sets_feed:
                self.feed = None      # the template changed the modal feed; state it again on the next move
        self.stop_pending = True

    def rapid(self, point, always: bool = False, rounded: tuple | None = None) -> None:
        """Tool-off travel to `point` (skipped when already there, unless `always`); `rounded`: the point already
        rounded, when the caller has it."""
        target = self.rounded(point) if rounded is None else rounded
        if target == self.position and not always:
            return
        self.lines.append(f"G0 {self.xy_format.format(*target)}")
        self._record(target, None, False, rapid=True)

    def line_to(self, point, feed: float) -> None:
        """A straight feed move."""
        target = self.rounded(point)
        if target == self.position:
            return
        self.lines.append(f"G1 {self.xy_format.format(*target)}{self._modal_words(feed)}")
        self._record(target, None, False, rapid=False, feed=feed)

    def contour(self, contour: np.ndarray, feed: float, rounded: list | None = None) -> None:
        """Feed moves along a contour from its first vertex (where the tool already is): G1 lines and G2/G3 arcs.

        `rounded` is the contour's vertices as `round_half_even` gives them, when the caller rounded many contours
        at once. Straight moves, most of a program, are written by a plain loop here (contours are short, so
        numpy's per-call cost would dominate) and logged straight into the MoveLog's rows, laid out as
        `MoveLog.add` lays them out; arcs go through `_bulge`.
        """
        if rounded is None:
            rounded = round_half_even(contour[:, :2], self.decimals).tolist()
        rows, fmt, logged_feed = contour.tolist(), self.xy_format.format, float(feed or 0.0)
        lines, log = self.lines, self.moves.rows
        for (x0, y0, bulge), (x1, y1, _), target in zip(rows, rows[1:], rounded[1:]):
            target = tuple(target)
            if bulge:
                self._bulge(x0, y0, bulge, x1, y1, target, feed)
                continue
            position = self.position
            if target == position:
                continue
            lines.append(f"G1 {fmt(*target)}{self._modal_words(feed)}")
            log.append((position[0], position[1], target[0], target[1], math.nan, math.nan, False, logged_feed, False,
                        self.tool_on, self.mark, self.stop_pending, self.dwell_pending))
            self.position = target
            self.stop_pending, self.dwell_pending = False, 0.0

    def _bulge(self, x0: float, y0: float, bulge: float, x1: float, y1: float, target: tuple, feed: float) -> None:
        """One arc segment to (x1, y1), `target` when rounded: G2/G3 if the profile has arcs and it survives
        rounding, else straight moves within ARC_FLATTEN_TOLERANCE."""
        sweep = 4.0 * math.atan(bulge)
        chord = math.hypot(x1 - x0, y1 - y0)
        radius = chord / (2.0 * abs(math.sin(sweep / 2.0)))
        if (self.profile.arcs and chord > 0 and radius * (1 - math.cos(sweep / 2)) >= MIN_SAGITTA
                and self._arc(target, _bulge_centre(x0, y0, x1, y1, sweep, chord), sweep < 0, feed)):
            return
        for point in flatten_contour(np.array([[x0, y0, bulge], [x1, y1, 0.0]]), ARC_FLATTEN_TOLERANCE)[1:].tolist():
            self.line_to(point, feed)

    def _arc(self, target: tuple, centre, clockwise: bool, feed: float) -> bool:
        """Write one arc to the (rounded) `target` if it survives rounding within ARC_RADIUS_TOLERANCE; False to
        have it written as lines."""
        start = self.position
        offset = self.rounded((centre[0] - start[0], centre[1] - start[1]))
        rounded_centre = (start[0] + offset[0], start[1] + offset[1])
        r_start = math.hypot(*offset)
        r_end = math.hypot(target[0] - rounded_centre[0], target[1] - rounded_centre[1])
        if abs(r_start - r_end) > ARC_RADIUS_TOLERANCE or target == start:
            return False
        self.lines.append(f"{'G2' if clockwise else 'G3'} {self.xy_format.format(*target)} "
                          f"{self.ij_format.format(*offset)}{self._modal_words(feed)}")
        self._record(target, rounded_centre, clockwise, rapid=False, feed=feed)
        return True

    def _modal_words(self, feed: float) -> str:
        """F (and in laser mode S) for a feed move, each written only when it changes."""
        words = ""
        if self.feed != feed:
            self.feed = feed
            words = f" F{self.fmt(feed)}"
        if self.power is not None and self.tool_on and self.speed != self.power:
            self.speed = self.power
            words += f" S{self.fmt(self.power)}"
        return words

    def _record(self, target, centre, clockwise: bool, rapid: bool, feed: float | None = None) -> None:
        self.moves.add(self.position, target, self.profile.rapid_rate if rapid else float(feed or 0.0), rapid,
                       self.tool_on and not rapid, self.mark, centre, clockwise, self.stop_pending, self.dwell_pending)
        self.position = target
        self.stop_pending, self.dwell_pending = False, 0.0

    def finish(self) -> str:
        """The program text with a trailing newline, after checking the line limit; a trailing dwell is kept as time."""
        if self.dwell_pending:
            self.moves.add(self.position, self.position, self.profile.rapid_rate, True, False, stop_before=True,
                           dwell=self.dwell_pending)
            self.dwell_pending = 0.0
        longest = max(self.lines, key=len, default="")
        if len(longest) > self.profile.max_line_length:
            raise FablineError(f"{self.profile.source}: max_line_length: a G-code line would be {len(longest)} characters "
                               f"(limit {self.profile.max_line_length}): {longest[:40]}...")
        return "\n".join(self.lines) + "\n"


def round_half_even(values: np.ndarray, decimals: int) -> np.ndarray:
    """`values` rounded as Python's round(value, decimals) rounds each (never a negative zero), for whole arrays.

    numpy's round scales by 10**decimals first, and that product can land on the other side of a half; the few
    values whose scaled fraction is that close to one half are rounded again one by one.
    """
    scaled = values * 10.0 ** decimals
    result = np.rint(scaled) / 10.0 ** decimals + 0.0
    doubtful = np.abs(scaled - np.floor(scaled) - 0.5) < 1e-6
    if doubtful.any():
        result[doubtful] = [round(value, decimals) + 0.0 for value in values[doubtful].tolist()]
    return result


def _bulge_centre(x0: float, y0: float, x1: float, y1: float, sweep: float, chord: float) -> tuple[float, float]:
    """Centre of the arc of signed `sweep` (radians) from (x0, y0) to (x1, y1): off the chord's middle to its left."""
    along = chord / (2.0 * math.tan(sweep / 2.0))
    return ((x0 + x1) / 2.0 - (y1 - y0) / chord * along, (y0 + y1) / 2.0 + (x1 - x0) / chord * along)


@lru_cache(maxsize=256)
def _template_effect(line: str) -> tuple[float, bool, dict, bool]:
    """What a template line does to the machine: dwell seconds, rapid or not, X/Y target (if a G0/G1 move), sets F."""
    dwell = DWELL.match(line)
    motion = MOTION.match(line)
    axes = {k.upper(): float(v) for k, v in AXIS.findall(line)} if motion else {}
    return (float(dwell.group(1)) if dwell else 0.0, bool(motion and motion.group(1) == "0"), axes,
            "F" in strip_comment(line).upper())


def header_block(texts: list[str], profile: MachineProfile) -> str:
    """Leading `;` comment lines for a program."""
    writer = GcodeWriter(profile)
    for text in texts:
        writer.comment(text)
    return writer.finish()


def sheet_program(paths: list[Toolpath], profile: MachineProfile) -> tuple[str, MoveLog]:
    """The G-code of one sheet (without header) and its MoveLog.

    An open path that starts where the previous one of the same operation ended (strokes of a letter) is run
    on without switching the tool off and on again. In laser mode the laser is armed once (tool_on with S0),
    every path starts with a G0 to its entry (the laser is off on G0) and its cutting moves carry the
    operation's power as S; the planner never has to stop for a spindle state change between paths.
    """
    writer = GcodeWriter(profile)
    writer.template(profile.render("program_start"))
    if profile.laser_mode:
        writer.template(profile.render("tool_on", power=0.0, depth=0.0))
    rounded, entries = _rounded_contours(paths, profile.decimals)
    for index, path in enumerate(paths):
        operation = profile.operations[path.operation]
        if not _continues(paths, entries, index, writer, operation.passes):
            writer.mark = path.operation.startswith("engrave")
            writer.comment(f"{path.operation} {path.part}")
            writer.rapid(path.entry, profile.laser_mode, None if path.lead_in is not None else entries[index])
        contour = path.contour
        for k in range(operation.passes):
            if (k == 0 and not writer.tool_on) or (k > 0 and profile.mode == "mill"):
                depth = -operation.depth * (k + 1) / operation.passes
                writer.tool_on = False
                if profile.laser_mode:
                    writer.power = operation.power
                else:
                    writer.template(profile.render("tool_on", power=operation.power, depth=depth))
                    if operation.pierce and k == 0:
                        writer.template([f"G4 P{profile.number(operation.pierce)}"])
                writer.tool_on = True
            if k == 0 and path.lead_in is not None:
                writer.line_to(contour[0, :2], operation.feed)
            writer.contour(contour, operation.feed, rounded[index] if contour is path.contour else None)
            if not path.closed:
                contour = reverse(contour)
        if not _continues(paths, entries, index + 1, writer, operation.passes):
            writer.tool_on = False
            if not profile.laser_mode:
                writer.template(profile.render("tool_off"))
    writer.mark = False
    if profile.laser_mode:
        writer.template(profile.render("tool_off"))
    writer.template(profile.render("program_end"))
    return writer.finish(), writer.moves


def _rounded_contours(paths: list[Toolpath], decimals: int) -> tuple[list[list], list[tuple]]:
    """Every path's vertices as they will read back from the file, rounded in one go for the whole sheet, and its
    first vertex as `GcodeWriter.rounded` rounds a numpy point (numpy's rounding: scaled, then to even), which is
    where the travel to the path goes."""
    if not paths:
        return [], []
    stacked = np.vstack([path.contour[:, :2] for path in paths])
    rounded = round_half_even(stacked, decimals).tolist()
    ends = np.cumsum([len(path.contour) for path in paths])
    firsts = np.concatenate([[0], ends[:-1]])
    entries = list(map(tuple, (np.round(stacked[firsts], decimals) + 0.0).tolist()))
    return [rounded[start:end] for start, end in zip(firsts.tolist(), ends.tolist())], entries


def _continues(paths: list[Toolpath], entries: list[tuple], index: int, writer: GcodeWriter, passes: int) -> bool:
    """Does paths[index] carry straight on from where the tool is, still on, in the same single-pass operation?"""
    if not writer.tool_on or index == 0 or index >= len(paths) or passes != 1:
        return False
    path, previous = paths[index], paths[index - 1]
    return (not path.closed and not previous.closed and path.operation == previous.operation
            and path.lead_in is None and entries[index] == writer.position)
