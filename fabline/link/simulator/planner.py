"""Grbl's motion planner (planner.c, motion_control.c): arcs into chords, per-axis limits, junction speeds and
the backward and forward replanning passes over the planner buffer."""

from __future__ import annotations

import math
from dataclasses import dataclass

from fabline.machine.gcode import Block, Segment

N_ARC_CORRECTION = 12
"""config.h: mc_arc's approximate rotations between two exact ones."""
ARC_ANGULAR_TRAVEL_EPSILON = 5e-7
"""config.h (radians): an arc ending this close to its start, on the side it turns to, is a full circle."""


@dataclass(slots=True)
class Pending:
    """A parsed line waiting for planner room, or (spindle, coolant, dwell changes) for the planner to empty."""

    line: str
    block: Block
    sync: bool
    queued: bool = False
    accessory_change: bool = False
    pause: bool = False
    pieces: list[Segment] | None = None
    """Motion blocks still to go into the planner (an arc's chords wait for room one by one, as in Grbl's mc_arc)."""
    segments: int = 0
    """mc_arc's segment count for an arc split into chords (0 for a line or an arc that is one block)."""


@dataclass(slots=True)
class Planned:
    """A line queued for execution: a motion, a dwell, or a zero-time modal change."""

    text: str
    segment: Segment | None = None
    rate: float = 0.0
    programmed_rate: float = 0.0
    inverse_time: float = 0.0
    """G93's F (1/min) when the block's programmed rate is F times its length (plan_buffer_line), else 0."""
    dwell: float = 0.0
    progress: float = 0.0
    line_number: int | None = None
    jog: bool = False
    pause: bool = False
    spindle: str = "M5"
    speed: float = 0.0
    final: bool = True
    """The last planner block of its line (an arc's last chord): completing it completes the line."""
    length: float = 0.0
    accel: float = 0.0
    unit: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_entry2: float = 0.0
    entry2: float = 0.0


class Planner:
    """GrblSimulator's planner buffer: parsed lines in, planner blocks with their entry speeds out."""

    @property
    def _moving(self) -> bool:
        return any(block.segment is not None or block.dwell for block in self.planner)

    def _motion_blocks(self) -> int:
        return len(self._moves)

    def _queue(self, pending: Pending, jog: bool = False) -> bool:
        """Put a parsed line into the planner; an arc's chords go in while there is room. True once all are in."""
        block = pending.block
        if pending.pieces is None:
            segment = block.segment if block.segment is not None and block.segment.length > 0 else None
            pieces, pending.segments = self._chords(segment) if segment is not None else ([], 0)
            pending.pieces = pieces[::-1]  # next chord last
            if not pending.pieces:
                planned = Planned(text=pending.line, line_number=block.line_number, jog=jog, pause=pending.pause,
                                   spindle=block.modal.spindle, speed=block.modal.speed, dwell=block.dwell)
                self.planner.append(planned)
                if planned.dwell <= 0 and len(self.planner) == 1:
                    self._complete()  # nothing ahead of it: Grbl executes a non-motion line in the parser, before its ok
                return True
        modal, inverse = block.modal, 0.0
        if modal.feed_mode == "G94" or jog:
            programmed = modal.feed * (25.4 if modal.units == "G20" else 1.0)
        elif pending.segments:  # mc_arc multiplies F by its segments and clears the inverse-time flag: mm/min
            programmed = modal.feed * pending.segments
        else:
            programmed, inverse = 0.0, modal.feed
        while pending.pieces and (jog or len(self._moves) < self.build.planner_blocks):
            piece = pending.pieces.pop()
            planned = Planned(text=pending.line, line_number=block.line_number, jog=jog, pause=pending.pause,
                               spindle=modal.spindle, speed=modal.speed, segment=piece, programmed_rate=programmed,
                               inverse_time=inverse, final=not pending.pieces)
            self._plan(planned)
            if self.state == "Idle":
                self.state = "Jog" if jog else "Run"
        return not pending.pieces

    def _chords(self, segment: Segment) -> tuple[list[Segment], int]:
        """The planner blocks of a motion as motion_control.c makes them, and mc_arc's segment count (0 if it makes
        none): a line is one block (mc_line); an arc (mc_arc) is floor(|travel| r / 2 / sqrt(tol (2 r - tol)))
        chords ($12 = tol, travel the angle it turns through; one to the target if that is 0), the radius vector
        turned by a small-angle rotation from chord to chord and recomputed exactly after every N_ARC_CORRECTION of
        them, the linear axis rising evenly, the last chord ending on the target. Chords of no length are dropped,
        as plan_buffer_line drops blocks of no steps."""
        if segment.center is None:
            return [segment], 0
        a, b, linear = segment.plane
        start, target, centre = segment.start, segment.end, segment.center
        offset_a, offset_b = centre[a] - start[a], centre[b] - start[b]
        r_a, r_b = -offset_a, -offset_b
        rt_a, rt_b = target[a] - centre[a], target[b] - centre[b]
        travel = math.atan2(r_a * rt_b - r_b * rt_a, r_a * rt_a + r_b * rt_b)
        if segment.clockwise and travel >= -ARC_ANGULAR_TRAVEL_EPSILON:
            travel -= 2 * math.pi
        elif not segment.clockwise and travel <= ARC_ANGULAR_TRAVEL_EPSILON:
            travel += 2 * math.pi
        radius, tolerance = math.hypot(offset_a, offset_b), self.settings[12]
        bound = tolerance * (2 * radius - tolerance)
        segments = math.floor(abs(0.5 * travel * radius) / math.sqrt(bound)) if bound > 0 else 0
        points = [start]
        if segments > 1:
            theta, rise = travel / segments, (target[linear] - start[linear]) / segments
            cos_t = 2.0 - theta * theta
            sin_t = theta * (cos_t + 4.0) / 6.0
            cos_t *= 0.5
            position, count = list(start), 0
            for i in range(1, segments):
                if count < N_ARC_CORRECTION:
                    r_a, r_b = r_a * cos_t - r_b * sin_t, r_a * sin_t + r_b * cos_t
                    count += 1
                else:
                    cos_i, sin_i = math.cos(i * theta), math.sin(i * theta)
                    r_a, r_b = -offset_a * cos_i + offset_b * sin_i, -offset_a * sin_i - offset_b * cos_i
                    count = 0
                position[a], position[b] = centre[a] + r_a, centre[b] + r_b
                position[linear] += rise
                points.append(tuple(position))
        points.append(target)
        return [Segment(p, q, False) for p, q in zip(points, points[1:]) if p != q], segments

    def _axis_limit(self, first_setting: int, unit: tuple[float, float, float]) -> float:
        """Grbl's limit_value_by_axis_maximum: the largest value along `unit` with no axis over its own setting."""
        settings, limit = self.settings, math.inf
        x, y, z = unit
        if x:
            limit = settings[first_setting] / abs(x)
        if y:
            limit = min(limit, settings[first_setting + 1] / abs(y))
        if z:
            limit = min(limit, settings[first_setting + 2] / abs(z))
        return limit

    def _plan(self, block: Planned) -> None:
        """Add a motion block to the planner (planner.c, plan_buffer_line) and replan the buffer."""
        segment = block.segment
        start, end = segment.start, segment.end
        dx, dy, dz = end[0] - start[0], end[1] - start[1], end[2] - start[2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        unit = (dx / length, dy / length, dz / length)
        rapid_rate = self._axis_limit(110, unit)
        if block.inverse_time:
            block.programmed_rate = block.inverse_time * length
        block.rate = (rapid_rate if segment.rapid else min(block.programmed_rate, rapid_rate)) / 60.0
        block.length, block.unit, block.accel = length, unit, self._axis_limit(120, unit)
        nominal2 = block.rate * block.rate
        if not self._moves:
            block.max_entry2 = 0.0  # the planner is empty: the machine stands still
        else:
            previous = self._moves[-1]
            px, py, pz = previous.unit
            cos_theta = -(px * unit[0] + py * unit[1] + pz * unit[2])
            if cos_theta > 0.999999:
                junction2 = 0.0  # a full reversal
            elif cos_theta < -0.999999:
                junction2 = math.inf  # straight on
            else:
                tx, ty, tz = unit[0] - px, unit[1] - py, unit[2] - pz
                norm = math.sqrt(tx * tx + ty * ty + tz * tz)
                accel = self._axis_limit(120, (tx / norm, ty / norm, tz / norm))
                sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
                junction2 = accel * self.settings[11] * sin_half / (1.0 - sin_half)
            block.max_entry2 = min(junction2, nominal2, previous.rate * previous.rate)
        self.planner.append(block)
        self._moves.append(block)
        self._replan()

    def _replan(self) -> None:
        """Grbl's planner_recalculate over the blocks after the optimal pointer: the backward pass from the newest
        block (which ends at rest), then the forward pass from the executing block's actual speed."""
        moves, first = self._moves, self._optimal
        last = len(moves) - 1
        if last <= first:
            return
        newest = moves[last]
        newest.entry2 = min(newest.max_entry2, 2.0 * newest.accel * newest.length)
        for index in range(last - 1, first, -1):
            current = moves[index]
            if current.entry2 != current.max_entry2:
                current.entry2 = min(current.max_entry2, moves[index + 1].entry2 + 2.0 * current.accel * current.length)
        for index in range(first, last):
            current, following = moves[index], moves[index + 1]
            if index == 0:
                entry2, length = self._speed * self._speed, current.length - current.progress
            else:
                entry2, length = current.entry2, current.length
            if entry2 < following.entry2:
                reachable = entry2 + 2.0 * current.accel * length
                if reachable < following.entry2:
                    following.entry2 = reachable
                    self._optimal = index + 1
            if following.entry2 == following.max_entry2:
                self._optimal = index + 1
