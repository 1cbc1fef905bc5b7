"""Machine moves and their run time: a Grbl-style planner with acceleration and junction deviation.

The G-code writer and `gcode-check` both reduce a program to a MoveLog and use the same statistics here,
so the summary printed at export time and the one recomputed from a file agree. The log is columnar
(one row of numbers per move) so a program of 100 000 moves is summarised in a fraction of a second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# columns of a MoveLog row
X0, Y0, X1, Y1, CX, CY, CLOCKWISE, FEED, RAPID, TOOL_ON, MARK, STOP, DWELL = range(13)


class MoveLog:
    """The motion blocks of a program in order: straight (rapid or feed) or arc, with the state each runs in."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []

    def __len__(self) -> int:
        return len(self.rows)

    def add(self, start, end, feed: float, rapid: bool, tool_on: bool, mark: bool = False, centre=None,
            clockwise: bool = False, stop_before: bool = False, dwell: float = 0.0) -> None:
        """One move: `feed` in mm/min, `centre` for arcs, `stop_before` when a tool change or dwell halts the
        machine first, `dwell` seconds spent standing still before it, `mark` for engrave moves."""
        cx, cy = (math.nan, math.nan) if centre is None else centre
        self.rows.append((start[0], start[1], end[0], end[1], cx, cy, clockwise, feed, rapid, tool_on, mark,
                          stop_before, dwell))

    def table(self) -> np.ndarray:
        """The moves as a float array (N, 13), columns as named at the top of this module."""
        return np.array(self.rows, dtype=float).reshape(-1, 13)


@dataclass
class MotionSummary:
    """Lengths by kind and the estimated run time of a program."""

    cut_length: float
    mark_length: float
    travel: float
    time: float
    moves: int

    def as_dict(self) -> dict:
        """JSON-ready, rounded to 0.001 mm and 0.1 s."""
        return {"cut_mm": round(self.cut_length, 3), "mark_mm": round(self.mark_length, 3),
                "travel_mm": round(self.travel, 3), "time_s": round(self.time, 1), "moves": self.moves}


def move_geometry(table: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Length, radius (inf for lines), and unit tangents at start and end of every move of a table."""
    start, end, centre = table[:, [X0, Y0]], table[:, [X1, Y1]], table[:, [CX, CY]]
    arc = ~np.isnan(centre[:, 0])
    chord = end - start
    length = np.hypot(chord[:, 0], chord[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_line = np.where(length[:, None] > 0, chord / length[:, None], 0.0)
    radius = np.full(len(table), np.inf)
    t_start, t_end = t_line.copy(), t_line.copy()
    if np.any(arc):
        r0, r1 = start[arc] - centre[arc], end[arc] - centre[arc]
        rad = np.hypot(r0[:, 0], r0[:, 1])
        a0, a1 = np.arctan2(r0[:, 1], r0[:, 0]), np.arctan2(r1[:, 1], r1[:, 0])
        clockwise = table[arc, CLOCKWISE] > 0
        sweep = np.where(clockwise, (a0 - a1) % (2 * np.pi), (a1 - a0) % (2 * np.pi))
        sweep = np.where(sweep == 0, 2 * np.pi, sweep)           # same start and end: a full circle
        radius[arc] = rad
        length[arc] = rad * sweep
        sign = np.where(clockwise, -1.0, 1.0)[:, None]
        safe = np.maximum(rad, 1e-12)[:, None]
        t_start[arc] = sign * np.column_stack([-r0[:, 1], r0[:, 0]]) / safe
        t_end[arc] = sign * np.column_stack([-r1[:, 1], r1[:, 0]]) / np.maximum(np.hypot(r1[:, 0], r1[:, 1]), 1e-12)[:, None]
    return length, radius, t_start, t_end


def summarise(log: MoveLog, acceleration: float, junction_deviation: float) -> MotionSummary:
    """Cut, mark and travel lengths and the run time; tool-on engrave moves count as marks, other tool-on moves as cuts."""
    table = log.table()
    length, _, _, _ = move_geometry(table)
    on, mark = table[:, TOOL_ON] > 0, table[:, MARK] > 0
    return MotionSummary(
        cut_length=float(length[on & ~mark].sum()), mark_length=float(length[on & mark].sum()),
        travel=float(length[~on].sum()), time=estimate_time(table, acceleration, junction_deviation),
        moves=len(table))


def estimate_time(table: np.ndarray, acceleration: float, junction_deviation: float) -> float:
    """Run time in seconds: trapezoidal speed profiles, junction speeds from Grbl's junction-deviation rule.

    `acceleration` is in mm/s^2, feeds in mm/min; arcs are limited to the speed where the centripetal
    acceleration equals `acceleration`. The machine starts and ends at rest, and stops where a move says so.
    """
    count = len(table)
    if count == 0:
        return 0.0
    a = float(acceleration)
    length, radius, t_start, t_end = move_geometry(table)
    v_max = np.minimum(table[:, FEED] / 60.0, np.sqrt(a * radius))
    junction = np.zeros(count + 1)             # junction[i]: speed entering move i; junction[count] = 0
    cos_theta = -np.einsum("ij,ij->i", t_end[:-1], t_start[1:])
    sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos_theta), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.sqrt(a * junction_deviation * sin_half / (1.0 - sin_half))
    v = np.where(cos_theta > 0.999999, 0.0, np.where(cos_theta < -0.999999, np.inf, v))
    v = np.minimum(v, np.minimum(v_max[:-1], v_max[1:]))
    moving = (length[:-1] > 0) & (length[1:] > 0) & (table[1:, STOP] == 0)
    junction[1:count] = np.where(moving, v, 0.0)
    junction = np.sqrt(np.maximum(_reachable(junction ** 2, 2 * a * length), 0.0))   # >= 0 whatever the rounding
    v0, v1 = junction[:-1], junction[1:]
    accel_dist = (v_max ** 2 - v0 ** 2) / (2 * a)
    decel_dist = (v_max ** 2 - v1 ** 2) / (2 * a)
    cruise = length - accel_dist - decel_dist
    with np.errstate(divide="ignore", invalid="ignore"):
        trapezoid = (v_max - v0) / a + (v_max - v1) / a + np.where(v_max > 0, cruise / v_max, 0.0)
        peak = np.sqrt(np.maximum((2 * a * length + v0 ** 2 + v1 ** 2) / 2.0, 0.0))
        triangle = (peak - v0) / a + (peak - v1) / a
    times = np.where(cruise >= 0, trapezoid, triangle)
    return float(np.sum(times[length > 0]) + table[:, DWELL].sum())


def _reachable(limit: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Squared junction speeds within `limit` that the machine can slow down to and speed up from in time.

    `gain[i]` is how much move i can change the squared speed (2 a L). Slowing down in time means
    s[i] <= s[i + 1] + gain[i] for every i (the backward pass of a planner), whose largest solution is the
    running minimum from the end of limit[j] + gain[i] + ... + gain[j - 1]; speeding up in time is the same
    forwards. Both are cumulative minimums over cumulative sums, so no Python loop over the moves.
    """
    travelled = np.concatenate([[0.0], np.cumsum(gain)])          # travelled[j] - travelled[i]: gain of moves i..j-1
    backward = np.minimum.accumulate((limit + travelled)[::-1])[::-1] - travelled
    return np.minimum.accumulate(backward - travelled) + travelled
