"""Machine moves and their run time: a Grbl-style planner with acceleration and junction deviation.

The G-code writer and `gcode-check` both reduce a program to a MoveLog and use the same statistics here,
so the summary printed at export time and the one recomputed from a file agree. The log is columnar
(one row of numbers per move) so a program of 100 000 moves is summarised in a fraction of a second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ARC_TOLERANCE = 0.002
"""Grbl's default $12 (mm): how far an arc's chords may stray from it."""
PLANNER_BLOCKS = 15
"""The planner buffer of a stock Grbl 1.1h build (16 blocks, one kept free)."""
IDLE_LOCK = 0.025
"""Grbl's default $1 (s): st_go_idle (stepper.c) waits this long in the stepper interrupt each time the machine
comes to rest, before the cycle ends; whatever waits for the planner to empty (M5, G4, M2) waits for it too."""
N_ARC_CORRECTION = 12
"""Grbl's config.h: mc_arc rotates the radius vector by a small-angle approximation and recomputes it exactly after
every 12 approximate steps."""
ARC_ANGULAR_TRAVEL_EPSILON = 5e-7
"""Grbl's config.h (radians): an arc whose end is within this angle of its start, on the side it turns to, is a
full circle."""

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
        clockwise = table[arc, CLOCKWISE] > 0
        radius[arc] = rad
        length[arc] = rad * np.abs(arc_travel(r0, r1, clockwise))
        sign = np.where(clockwise, -1.0, 1.0)[:, None]
        safe = np.maximum(rad, 1e-12)[:, None]
        t_start[arc] = sign * np.column_stack([-r0[:, 1], r0[:, 0]]) / safe
        t_end[arc] = sign * np.column_stack([-r1[:, 1], r1[:, 0]]) / np.maximum(np.hypot(r1[:, 0], r1[:, 1]), 1e-12)[:, None]
    return length, radius, t_start, t_end


def arc_travel(r0: np.ndarray, r1: np.ndarray, clockwise: np.ndarray) -> np.ndarray:
    """Signed angle (radians, counter-clockwise positive) arcs turn through from radius vectors `r0` (N, 2) to
    `r1`, as mc_arc reckons it: one atan2, then a full turn added where the end is within
    ARC_ANGULAR_TRAVEL_EPSILON of the start on the side the arc turns to (a full circle, not an empty arc)."""
    travel = np.arctan2(r0[:, 0] * r1[:, 1] - r0[:, 1] * r1[:, 0], r0[:, 0] * r1[:, 0] + r0[:, 1] * r1[:, 1])
    return np.where(clockwise, np.where(travel >= -ARC_ANGULAR_TRAVEL_EPSILON, travel - 2 * np.pi, travel),
                    np.where(travel <= ARC_ANGULAR_TRAVEL_EPSILON, travel + 2 * np.pi, travel))


def summarise(log: MoveLog, acceleration: float, junction_deviation: float, max_rate: float = math.inf, *,
              idle_lock: float = IDLE_LOCK) -> MotionSummary:
    """Cut, mark and travel lengths and the run time; tool-on engrave moves count as marks, other tool-on moves as cuts.
    `max_rate` (mm/min) is every axis's maximum rate ($110, $111); `idle_lock` the seconds the controller holds at
    every stop (Grbl's $1; 0 for a controller that does not)."""
    table = log.table()
    length, _, _, _ = move_geometry(table)
    on, mark = table[:, TOOL_ON] > 0, table[:, MARK] > 0
    return MotionSummary(
        cut_length=float(length[on & ~mark].sum()), mark_length=float(length[on & mark].sum()),
        travel=float(length[~on].sum()),
        time=estimate_time(table, acceleration, junction_deviation, max_rate=max_rate, idle_lock=idle_lock),
        moves=len(table))


def estimate_time(table: np.ndarray, acceleration: float, junction_deviation: float, *, max_rate: float = math.inf,
                  arc_tolerance: float = ARC_TOLERANCE, planner_blocks: int = PLANNER_BLOCKS,
                  idle_lock: float = IDLE_LOCK) -> float:
    """Run time in seconds of a move table on a Grbl controller kept fed by its host (see `move_times`)."""
    return float(move_times(table, acceleration, junction_deviation, max_rate=max_rate, arc_tolerance=arc_tolerance,
                            planner_blocks=planner_blocks, idle_lock=idle_lock).sum())


def move_times(table: np.ndarray, acceleration: float, junction_deviation: float, *, max_rate: float = math.inf,
               arc_tolerance: float = ARC_TOLERANCE, planner_blocks: int = PLANNER_BLOCKS,
               idle_lock: float = IDLE_LOCK) -> np.ndarray:
    """Seconds each move of a table takes (its dwell included), planned as Grbl 1.1h plans it: arcs split into
    chords as mc_arc splits them by the $12 `arc_tolerance`, trapezoidal speed profiles with the X/Y
    `acceleration` (mm/s^2) and `max_rate` (mm/min) limited per axis, junction speeds by the $11
    `junction_deviation` rule, and a look-ahead of the `planner_blocks` the planner buffer holds (the newest block
    must end at rest). The machine starts and ends at rest, and stops where a move says so; each time it comes to
    rest the steppers hold for `idle_lock` s ($1) before the next stopping move (or, at the end, the last move)."""
    count = len(table)
    times = table[:, DWELL].astype(float).copy() if count else np.zeros(0)
    if count == 0:
        return times
    start, end, owner, stop = _chords(table, arc_tolerance)
    chord = end - start
    length = np.hypot(chord[:, 0], chord[:, 1])
    kept = np.flatnonzero(length > 0)                     # Grbl drops blocks of no steps ...
    if len(kept) == 0:
        return times
    carried = np.zeros(len(kept), dtype=bool)             # ... but not the stop before one
    following = np.searchsorted(kept, np.flatnonzero(stop))
    carried[following[following < len(kept)]] = True
    chord, length, owner, stop = chord[kept], length[kept], owner[kept], carried
    stop[0] = True
    resting = owner[np.append(stop[1:], True)]            # rows of the chords the machine comes to rest after
    stop_rows = np.append(np.flatnonzero(table[:, STOP] > 0), count - 1)  # the lock: to the next stopping row
    np.add.at(times, stop_rows[np.searchsorted(stop_rows[:-1], resting, side="right")], idle_lock)
    unit = chord / length[:, None]
    axis = np.maximum(np.abs(unit).max(axis=1), 1e-12)    # limit_value_by_axis_maximum for equal X and Y limits
    accel = acceleration / axis
    feed, limit_rate = table[owner, FEED], max_rate / axis
    rapid = table[owner, RAPID] > 0   # Grbl's rapid rate is the axis-limited maximum, above $110 on a diagonal
    nominal = np.where(rapid & np.isfinite(limit_rate), limit_rate, np.minimum(feed, limit_rate)) / 60.0
    turn = unit[1:] - unit[:-1]
    cos_theta = -np.einsum("ij,ij->i", unit[:-1], unit[1:])
    turn_axis = np.abs(turn).max(axis=1) / np.maximum(np.hypot(turn[:, 0], turn[:, 1]), 1e-12)
    sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos_theta), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        junction = acceleration / np.maximum(turn_axis, 1e-12) * junction_deviation * sin_half / (1.0 - sin_half)
    junction = np.where(cos_theta > 0.999999, 0.0, np.where(cos_theta < -0.999999, np.inf, junction))
    limit = np.zeros(len(length) + 1)                      # squared entry speed of chord i; limit[-1]: the end
    limit[1:-1] = np.minimum(junction, np.minimum(nominal[:-1], nominal[1:]) ** 2)
    limit[:-1][stop] = 0.0
    gain = 2.0 * accel * length
    window = max(int(planner_blocks) - 1, 1)               # chords after a junction that are in the planner with it
    travelled = np.concatenate([[0.0], np.cumsum(gain)])
    ahead = travelled[np.minimum(np.arange(len(length) + 1) + window, len(length))] - travelled
    entry2 = np.maximum(_reachable(np.minimum(limit, ahead), gain), 0.0)
    v0, v1 = np.sqrt(entry2[:-1]), np.sqrt(entry2[1:])
    with np.errstate(divide="ignore", invalid="ignore"):
        cruise = length - (nominal ** 2 - v0 ** 2) / (2 * accel) - (nominal ** 2 - v1 ** 2) / (2 * accel)
        trapezoid = (nominal - v0) / accel + (nominal - v1) / accel + cruise / nominal
        peak = np.sqrt(np.maximum((2 * accel * length + v0 ** 2 + v1 ** 2) / 2.0, 0.0))
        triangle = (peak - v0) / accel + (peak - v1) / accel
    np.add.at(times, owner, np.where(cruise >= 0, trapezoid, triangle))
    return times


def _chords(table: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The planner blocks of a move table: lines as they are, arcs split as Grbl 1.1h's mc_arc splits them
    (see `_arc_points`). Returns chord starts and ends, the row each chord belongs to, and whether the machine
    stops before it (a row's stop applies to its first chord)."""
    _, radius, _, _ = move_geometry(table)
    arc = np.isfinite(radius)
    travel = np.zeros(len(table))
    if np.any(arc):
        centre = table[arc][:, [CX, CY]]
        travel[arc] = arc_travel(table[arc][:, [X0, Y0]] - centre, table[arc][:, [X1, Y1]] - centre,
                                 table[arc, CLOCKWISE] > 0)
    pieces = np.maximum(arc_segments(travel, radius, tolerance), 1)
    owner = np.repeat(np.arange(len(table)), pieces)
    first = np.concatenate([[0], np.cumsum(pieces)[:-1]])
    index = np.arange(len(owner)) - first[owner]           # chord number within its row
    rows = table[owner]
    start, end = rows[:, [X0, Y0]].copy(), rows[:, [X1, Y1]].copy()
    split = pieces[owner] > 1
    if np.any(split):
        for points, point in ((start, index), (end, index + 1)):
            inner = split & (point > 0) & (point < pieces[owner])
            points[inner] = _arc_points(rows[inner], travel[owner[inner]] / pieces[owner[inner]], point[inner])
    stop = (table[owner, STOP] > 0) & (index == 0)
    stop[0] = True
    return start, end, owner, stop


def arc_segments(travel, radius, tolerance: float) -> np.ndarray:
    """mc_arc's segment count for arcs turning `travel` radians at `radius`: floor(|0.5 travel r| /
    sqrt(tol (2 r - tol))), 0 where that is no number (a radius under tol / 2; lines, whose radius is inf)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        segments = np.floor(np.abs(0.5 * np.asarray(travel) * radius) / np.sqrt(tolerance * (2 * radius - tolerance)))
    return np.where(np.isfinite(segments), segments, 0).astype(np.int64)


def _arc_points(rows: np.ndarray, theta: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Where mc_arc puts the end of the `point`-th chord (0 < point < segments) of each arc row, turning `theta`
    per chord: the radius vector is turned by the small-angle matrix (cos ~ 1 - theta^2/2, sin ~ theta - theta^3/6:
    a rotation by psi that scales by rho, so the points drift off the circle) from the last exact one, the start or
    every (N_ARC_CORRECTION + 1)-th point, which mc_arc computes with cos and sin."""
    centre = rows[:, [CX, CY]]
    r0 = rows[:, [X0, Y0]] - centre
    cos_t, sin_t = 1.0 - theta * theta / 2.0, theta * (6.0 - theta * theta) / 6.0
    exact = (N_ARC_CORRECTION + 1) * (point // (N_ARC_CORRECTION + 1))
    steps = point - exact
    angle = exact * theta + steps * np.arctan2(sin_t, cos_t)
    scale = np.hypot(cos_t, sin_t) ** steps
    cos_a, sin_a = np.cos(angle), np.sin(angle)
    return centre + scale[:, None] * np.column_stack([r0[:, 0] * cos_a - r0[:, 1] * sin_a,
                                                      r0[:, 0] * sin_a + r0[:, 1] * cos_a])


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


def line_timeline(blocks, settings: dict[int, float], planner_blocks: int = PLANNER_BLOCKS) -> np.ndarray:
    """Planned machine seconds from the start to the end of each line of a program, the lines given as the
    interpreter's blocks (`fabline.machine.gcode.Block`, one per line) and the controller as its Grbl `$N`
    settings ($1, $11, $12, $110, $111, $120, $121). The machine stops where Grbl syncs: before a spindle or
    coolant change, a dwell, after a program pause or end (an S change alone does not stop it, as in laser mode);
    the line that syncs waits for the steppers' $1 lock too (none with $1=255)."""
    rows: list[tuple] = []
    owners: list[int] = []
    previous = None

    def sync(index: int, block, dwell: float = 0.0) -> None:   # a zero-length row: the machine at rest before it
        x, y = block.position[0], block.position[1]
        rows.append((x, y, x, y, math.nan, math.nan, 0, 1.0, 1, 0, 0, 1, dwell))
        owners.append(index)

    for index, block in enumerate(blocks):
        modal = block.modal
        if block.dwell > 0 or (previous is not None and (modal.spindle != previous.spindle
                                                          or modal.coolant != previous.coolant)):
            sync(index, block, block.dwell)
        previous = modal
        for segment in (block.approach, block.segment):
            if segment is None or segment.length <= 0:
                continue
            centre = segment.center if segment.center is not None else (math.nan, math.nan)
            feed = settings[110] if segment.rapid else block.feed_rate
            if segment.center is not None and block.modal.feed_mode == "G93":
                feed = _inverse_time_arc_feed(segment, block.modal.feed, settings.get(12, ARC_TOLERANCE)) or feed
            rows.append((segment.start[0], segment.start[1], segment.end[0], segment.end[1], centre[0], centre[1],
                         segment.clockwise, feed, segment.rapid, 0, 0, 0, 0.0))
            owners.append(index)
        if block.pause or block.program_end:
            sync(index, block)
    per_line = np.zeros(len(blocks))
    if rows:
        x, y = rows[-1][X1], rows[-1][Y1]   # the end: the lock after the last move belongs to no line
        rows.append((x, y, x, y, math.nan, math.nan, 0, 1.0, 1, 0, 0, 1, 0.0))
        lock = 0.0 if settings.get(1, 25) == 255 else settings.get(1, 25) / 1000.0
        times = move_times(np.array(rows, dtype=float), min(settings[120], settings[121]), settings[11],
                           max_rate=min(settings[110], settings[111]), arc_tolerance=settings.get(12, ARC_TOLERANCE),
                           planner_blocks=planner_blocks, idle_lock=lock)
        np.add.at(per_line, np.array(owners), times[:-1])
    return np.cumsum(per_line)


def _inverse_time_arc_feed(segment, feed: float, tolerance: float) -> float:
    """The mm/min a G93 arc's chords run at in Grbl 1.1h: mc_arc multiplies F by its segment count and clears the
    inverse-time flag (so not F times the arc's length); 0 when it makes no segments (one block, F times its length)."""
    r0 = np.array([[segment.start[0] - segment.center[0], segment.start[1] - segment.center[1]]])
    r1 = np.array([[segment.end[0] - segment.center[0], segment.end[1] - segment.center[1]]])
    travel = arc_travel(r0, r1, np.array([segment.clockwise]))
    return feed * float(arc_segments(travel, float(np.hypot(*r0[0])), tolerance)[0])
