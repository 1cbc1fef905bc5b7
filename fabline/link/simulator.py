"""An in-process GRBL 1.1h controller simulator: receive buffer, planner, motion in (scaled) time, faults.

It answers like the firmware captured in `grbl-1.1h-transcript.txt` (banner, `$$`, `$I`, `$G`, `$#`,
`ok`/`error:N`, `ALARM:N`, status reports per `$10`, check mode, feed hold) and records every line it
executes, in execution order, to an append-only executed-line log. It is a stock build unless told
otherwise (`build=BuildInfo(options="VN")` adds `Ln:` to status reports, bigger `planner_blocks` or
`rx_buffer` model other boards): `$I` answers the build, and the buffers have the build's sizes.
M0 pauses like the firmware (planner emptied, then a completed feed hold until cycle start); M1 is
ignored (Grbl has no optional-stop switch).

Motion follows Grbl's planner (gnea/grbl `planner.c`, `motion_control.c`): arcs are split into chords by
the $12 arc tolerance, every chord and line is a planner block with its nominal speed and acceleration
limited per axis ($110-$112, $120-$122), junction speeds follow the $11 junction deviation rule, and each
new block replans the blocks in the planner buffer (15 on a stock build) with Grbl's backward and forward
passes, the newest block ending at rest. Blocks run trapezoidal speed profiles, so status reports (`MPos`,
`FS:`) follow the ramps, and a planner the host does not keep filled makes the machine slow down and stop.
Deviations from real firmware: no step timing (a profile is exact, not in 10 ms acceleration ticks), no
overrides, work offsets fixed at zero.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

from fabline.link.build import STOCK_BUILD, BuildInfo
from fabline.link.gcode import Block, GcodeError, ModalState, Segment, execute

VERSION = "1.1h"
BANNER = f"Grbl {VERSION} ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
LINE_BUFFER_SIZE = 80
_REALTIME_BYTES = (b"?", b"!", b"~", b"\x18")
_BLANK = bytes(range(33))  # what the protocol loop drops from a line: control characters and space
_INT_SETTINGS = {0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0, 20: 0, 21: 0, 22: 0,
    23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}


class ConnectionDropped(Exception):
    """Raised to the transport when an injected fault cuts the connection."""


@dataclass
class Faults:
    """Faults to inject. Byte offsets count every byte the controller received since it was created.

    drop_at: cut the connection once the controller has received this many bytes (one per entry).
    corrupt_at: replace the byte at this offset with '#', as line noise would.
    error_line: answer error:`error_code` instead of executing the line numbered N<error_line> (once).
    alarm_line: raise ALARM:`alarm_code` halfway through executing line N<alarm_line> (once).
    stall_at / stall_seconds: stop reading and answering for a while once this many bytes arrived.
    """

    drop_at: list[int] = field(default_factory=list)
    corrupt_at: list[int] = field(default_factory=list)
    error_line: int | None = None
    error_code: int = 20
    alarm_line: int | None = None
    alarm_code: int = 1
    stall_at: int | None = None
    stall_seconds: float = 0.0


@dataclass(slots=True)
class _Pending:
    """A parsed line waiting for planner room, or (spindle, coolant, dwell changes) for the planner to empty."""

    line: str
    block: Block
    sync: bool
    queued: bool = False
    accessory_change: bool = False
    pause: bool = False
    pieces: list[Segment] | None = None
    """Motion blocks still to go into the planner (an arc's chords wait for room one by one, as in Grbl's mc_arc)."""


@dataclass(slots=True)
class _Planned:
    """A line queued for execution: a motion, a dwell, or a zero-time modal change."""

    text: str
    segment: Segment | None = None
    rate: float = 0.0
    programmed_rate: float = 0.0
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


TIME_SCALE_MAX = 1e6
"""The fastest a simulator runs (machine seconds per real second): at 1e6 one 1 ms tick is 17 min of machine time,
faster than any job needs; beyond it the tick arithmetic loses the planner's millisecond steps (1e308 overflows)."""


def check_time_scale(value: float) -> float:
    """`value` if it is a usable time scale (finite, above 0, at most TIME_SCALE_MAX), else ValueError saying so."""
    if not 0 < value <= TIME_SCALE_MAX:  # also refuses NaN
        raise ValueError(f"time_scale must be above 0 and at most {TIME_SCALE_MAX:g}, not {value:g}")
    return value


class GrblSimulator:
    """A GRBL 1.1h controller in a background thread; `time_scale` > 1 makes motion run faster.

    `line_time` is the firmware's time (real seconds, not scaled) to parse and plan one line before it
    answers and reads the next: an 8-bit Grbl needs a few milliseconds, 0 makes the controller instant.
    `threaded=False` runs no main loop: the caller drives machine time with `step` (deterministic timing).
    """

    def __init__(self, *, time_scale: float = 1.0, executed_log: str | Path | None = None,
                 faults: Faults | None = None, tick: float = 0.001, settings: dict[int, float] | None = None,
                 line_time: float = 0.0, build: BuildInfo = STOCK_BUILD, threaded: bool = True):
        self.build = build
        self.time_scale = check_time_scale(time_scale)
        self.line_time = line_time
        self.faults = faults or Faults()
        unknown = sorted(set(settings or {}) - set(DEFAULT_SETTINGS))
        if unknown:
            raise ValueError(f"unknown Grbl setting(s) {', '.join(f'${n}' for n in unknown)}")
        self.settings = {**DEFAULT_SETTINGS, **(settings or {})}
        self.position: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.received = 0
        self.connection = 0
        self._log = open(executed_log, "a", encoding="ascii") if executed_log else None
        self._lock = threading.RLock()
        self._output = bytearray()
        self._output_ready = threading.Condition(self._lock)
        self._connected = False
        self._tick = tick
        self._input_arrived = threading.Event()
        self._stall_until = 0.0
        self._stopping = False
        self.completed: list[tuple[str, float]] | None = None
        """When a list: (line, machine time) appended as each line completes (see `step`)."""
        self.machine_time = 0.0
        """Seconds of machine time the controller has run (moving or dwelling) since it was created."""
        self._power_on()
        self._thread = threading.Thread(target=self._run, name="grbl-sim", daemon=True) if threaded else None
        if self._thread is not None:
            self._thread.start()

    # ----- host side -------------------------------------------------------------------------------------
    def attach(self) -> int:
        """A host connects; returns the connection's number. Output nobody read before is gone."""
        with self._lock:
            self._output.clear()
            self._connected = True
            self.connection += 1
            return self.connection

    def detach(self, connection: int | None = None) -> None:
        """The host went away (only if `connection` is still the current one); the controller carries on."""
        with self._lock:
            if connection in (None, self.connection):
                self._connected = False
                self._output.clear()

    def receive(self, data: bytes) -> None:
        """Bytes from the host. Real-time bytes act at once; others queue in the 128-byte receive buffer."""
        with self._lock:
            faults = self.faults
            if (not faults.drop_at and not faults.corrupt_at and faults.stall_at is None and not self._critical
                    and data.isascii() and not any(byte in data for byte in _REALTIME_BYTES)):
                room = self.build.rx_buffer - len(self._rx)  # the common case, taken in one step: plain line bytes
                self.received += len(data)
                self.overflowed += max(0, len(data) - room)
                self._rx += data[:room]
                if b"\n" in data[:room]:
                    self._input_arrived.set()
                return
            for byte in data:
                if self.faults.drop_at and self.received >= self.faults.drop_at[0]:
                    self.faults.drop_at.pop(0)
                    self._connected = False
                    self._output.clear()
                    raise ConnectionDropped(f"connection dropped after {self.received} bytes")
                if self.faults.stall_at is not None and self.received >= self.faults.stall_at:
                    self.faults.stall_at = None
                    self._stall_until = time.monotonic() + self.faults.stall_seconds
                if self.faults.corrupt_at and self.received == self.faults.corrupt_at[0]:
                    self.faults.corrupt_at.pop(0)
                    byte = ord("#")
                self.received += 1
                if byte == 0x3F and time.monotonic() < self._stall_until:
                    continue  # a stalled controller answers nothing, not even status queries
                if byte in (0x3F, 0x21, 0x7E, 0x18) or byte >= 0x80:
                    self._realtime(byte)
                elif self._critical:
                    continue
                elif len(self._rx) < self.build.rx_buffer:
                    self._rx.append(byte)
                    if byte == 0x0A:
                        self._input_arrived.set()
                else:
                    self.overflowed += 1

    def read(self, size: int, timeout: float | None) -> bytes:
        """Up to `size` bytes the controller sent, waiting up to `timeout` seconds for the first one."""
        with self._lock:
            if not self._output and timeout:
                self._output_ready.wait(timeout)
            data = bytes(self._output[:size])
            del self._output[:size]
            return data

    def pending_output(self) -> int:
        """Bytes the controller has sent that the host has not read."""
        with self._lock:
            return len(self._output)

    def close(self) -> None:
        """Stop the controller thread and close the executed-line log."""
        self._stopping = True
        if self._thread is not None:
            self._thread.join(timeout=2)
        if self._log:
            self._log.close()
            self._log = None

    # ----- state --------------------------------------------------------------------------------------
    def _power_on(self) -> None:
        self._rx = bytearray()
        self.overflowed = 0
        self.state = "Idle"
        self._critical = False
        self._reset_runtime()
        self._say(BANNER)

    def _reset_runtime(self) -> None:
        """What a reset clears: input, partial line, planner, parser state, hold; position is kept."""
        self._rx.clear()
        self._line = bytearray()
        self._line_overflow = False
        self._comment = False
        self._pending: _Pending | None = None
        self._parsing: tuple[str, bool] | None = None  # a complete line the firmware is still parsing ...
        self._parsed_at = 0.0                           # ... until this time.monotonic()
        self.planner: deque[_Planned] = deque()
        self._moves: deque[_Planned] = deque()  # the motion blocks of the planner, in order
        self._optimal = 0  # Grbl's block_buffer_planned: index in _moves before which the plan cannot improve
        self.modal = ModalState()
        self._parse_position = self.position
        self._hold = None
        self._hold_stopped_motion = False  # a reset aborts a cycle (ALARM:3) only if the hold stopped a motion
        self._speed = 0.0
        self._wco_counter = 0
        self._ovr_counter = 0

    def _say(self, text: str) -> None:
        if self._connected:
            self._output += text.encode("ascii") + b"\r\n"
            self._output_ready.notify_all()

    @property
    def _moving(self) -> bool:
        return any(block.segment is not None or block.dwell for block in self.planner)

    def _motion_blocks(self) -> int:
        return len(self._moves)

    # ----- real-time commands ----------------------------------------------------------------------
    def _realtime(self, byte: int) -> None:
        if byte == 0x3F:
            self._say(self._status_report())
        elif byte == 0x21:
            if self.state in ("Run", "Jog") and self._hold is None:
                self._hold, self.state, self._hold_stopped_motion = "decelerating", "Hold", True
            elif self.state == "Idle":  # Grbl: "If IDLE, Grbl is not in motion. ... hold is complete."
                self._hold, self.state, self._hold_stopped_motion = "complete", "Hold", False
        elif byte == 0x7E:
            if self.state == "Hold" and self._hold == "complete":
                self._hold = None
                self.state = "Run" if self._moving else "Idle"
                self._optimal = 0  # Grbl replans from rest (plan_cycle_reinitialize)
                self._replan()
        elif byte == 0x18:
            self._soft_reset()
        elif byte == 0x85 and self.state == "Jog":
            self.planner = deque(block for block in self.planner if not block.jog)
            self._moves = deque(block for block in self._moves if not block.jog)
            self._optimal = 0
            self._speed = 0.0
            self.state = "Idle"

    def _soft_reset(self) -> None:
        lost = self.state in ("Run", "Jog") or (self.state == "Hold" and self._hold_stopped_motion)
        was_alarm = self.state == "Alarm"
        self._critical = False
        self._reset_runtime()
        if lost:
            self._say("ALARM:3")
        self._say(BANNER)
        if lost or was_alarm:
            self.state = "Alarm"
            self._say("[MSG:'$H'|'$X' to unlock]")
        else:
            self.state = "Idle"

    def _alarm(self, code: int) -> None:
        """A critical alarm (limit): stop at once, flush everything, wait for a reset."""
        self._rx.clear()
        self._line = bytearray()
        self.planner.clear()
        self._moves.clear()
        self._optimal = 0
        self._pending = None
        self._parsing = None
        self._hold = None
        self.state = "Alarm"
        self._critical = True
        self._say(f"ALARM:{code}")
        self._say("[MSG:Reset to continue]")

    def _status_report(self) -> str:
        state = self.state
        if state == "Hold":
            state = f"Hold:{0 if self._hold == 'complete' else 1}"
        mask = int(self.settings[10])
        position = self.position
        parts = [state, ("MPos:" if mask & 1 else "WPos:") + ",".join(f"{v:.3f}" for v in position)]
        if mask & 2:
            parts.append(f"Bf:{self.build.planner_blocks - self._motion_blocks()},{self.build.rx_buffer - len(self._rx)}")
        if (self.build.line_numbers and self.planner and self.planner[0].line_number
                and self.state in ("Run", "Hold", "Jog")):
            parts.append(f"Ln:{self.planner[0].line_number}")
        feed, speed = self._current_feed_speed()
        parts.append(f"FS:{feed:.0f},{speed:.0f}")
        busy = self.state in ("Run", "Hold", "Jog")
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            self._wco_counter = 29 if busy else 9
            if self._ovr_counter == 0:
                self._ovr_counter = 1
            parts.append("WCO:0.000,0.000,0.000")
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = 19 if busy else 9
            parts.append("Ov:100,100,100")
            spindle = self._spindle_state()
            coolant = {"M7": "M", "M8": "F"}.get(self.modal.coolant, "")
            if spindle != "M5" or coolant:
                parts.append("A:" + {"M3": "S", "M4": "C", "M5": ""}[spindle] + coolant)
        return "<" + "|".join(parts) + ">"

    def _spindle_state(self) -> str:
        return self.planner[0].spindle if self.planner and self.planner[0].segment is not None else self.modal.spindle

    def _current_feed_speed(self) -> tuple[float, float]:
        if not self.planner or self.planner[0].segment is None or self.state not in ("Run", "Hold", "Jog"):
            laser = self.settings[32] == 1
            return 0.0, 0.0 if laser or self.modal.spindle == "M5" else self.modal.speed
        block = self.planner[0]
        feed = self._speed * 60.0
        if block.spindle == "M5" or block.jog:
            return feed, 0.0
        if self.settings[32] == 1:
            if block.segment.rapid:
                return feed, 0.0
            if block.spindle == "M4" and block.programmed_rate:
                return feed, block.speed * feed / block.programmed_rate
        return feed, block.speed

    # ----- the main loop -----------------------------------------------------------------------------
    def _run(self) -> None:
        last = time.monotonic()
        while not self._stopping:
            wait = self._tick if self._parsing is None else min(self._tick, max(0.0, self._parsed_at - time.monotonic()))
            self._input_arrived.wait(wait)  # GRBL's main loop picks a line up as soon as it is complete
            self._input_arrived.clear()
            now = time.monotonic()
            with self._lock:
                if now < self._stall_until:
                    last = now
                    continue
                self._advance((now - last) * self.time_scale)
                self._process_input()
            last = now

    def _process_input(self) -> None:
        """Pull characters into the line buffer and execute complete lines while the planner has room."""
        while not self._critical:
            if self._parsing is not None:
                if time.monotonic() < self._parsed_at:
                    return
                line, overflow = self._parsing
                self._parsing = None
                self._finish_line(line, overflow)
                continue
            pending = self._pending
            if pending is not None:
                if pending.sync and self.planner and (pending.pieces is None or pending.block.dwell > 0):
                    return
                if not pending.sync and self._motion_blocks() >= self.build.planner_blocks:
                    return
                if not pending.queued:
                    if pending.accessory_change and pending.pieces is None:
                        self._ovr_counter = 0  # the firmware reports a spindle or coolant change at once
                    pending.queued = self._queue(pending)
                    if not pending.queued or pending.block.dwell > 0:
                        return
                self._pending = None
                self._say("ok")
                continue
            if not self._rx:
                return
            if not self._comment and self._take_plain_text():
                continue
            char = chr(self._rx.pop(0))
            if char == "\n" or char == "\r":
                line, overflow = self._line.decode("ascii", errors="replace"), self._line_overflow
                self._line, self._line_overflow, self._comment = bytearray(), False, False
                if self.line_time > 0:
                    self._parsing, self._parsed_at = (line, overflow), time.monotonic() + self.line_time
                else:
                    self._finish_line(line, overflow)
            elif self._comment:
                if char == ")":
                    self._comment = False
            elif char == "(":
                self._comment = True
            elif char <= " ":
                continue
            elif len(self._line) >= LINE_BUFFER_SIZE - 1:
                self._line_overflow = True
            else:
                self._line += char.upper().encode("ascii", errors="replace")

    def _take_plain_text(self) -> bool:
        """Move the received characters before the next line end into the line buffer at once, as the loop below
        would one by one (whitespace and control characters dropped, letters uppercased, overflow past 79), when
        they hold no comment; False (nothing taken) when they do or a line end comes first."""
        rx = self._rx
        ends = [index for index in (rx.find(b"\n"), rx.find(b"\r")) if index >= 0]
        end = min(ends) if ends else len(rx)
        if end == 0 or rx.find(b"(", 0, end) >= 0:
            return False
        text = bytes(rx[:end]).translate(None, _BLANK).upper()
        del rx[:end]
        room = LINE_BUFFER_SIZE - 1 - len(self._line)
        if len(text) > room:
            text, self._line_overflow = text[:max(room, 0)], True
        self._line += text
        return True

    def _finish_line(self, line: str, overflow: bool) -> None:
        """Answer a complete input line: error:11 if it overflowed the line buffer, else execute it."""
        if overflow:
            self._say("error:11")
        else:
            self._execute_line(line)

    def _execute_line(self, line: str) -> None:
        if ";" in line:
            line = line[: line.index(";")]
        if not line:
            self._say("ok")
        elif line.startswith("$"):
            self._system_command(line)
        else:
            status = self._gcode_line(line)
            if status is not None:
                self._say(f"error:{status}" if status else "ok")

    def _gcode_line(self, line: str) -> int | None:
        """Parse a G-code line; return an error code, 0 for ok, or None when it waits for planner room."""
        if self.state in ("Alarm", "Jog"):
            return 9
        try:
            block = execute(line, self.modal, self._parse_position, build=self.build)
        except GcodeError as exc:
            return exc.code
        if self.faults.error_line is not None and block.line_number == self.faults.error_line:
            self.faults.error_line = None
            return self.faults.error_code
        accessory_change = block.modal.spindle != self.modal.spindle or block.modal.coolant != self.modal.coolant
        pause = block.pause
        sync = accessory_change or block.dwell > 0 or block.program_end or pause
        self.modal = block.modal
        self._parse_position = block.position  # check mode too: Grbl's parser keeps tracking its position
        if self.state == "Check":
            return 0
        self._pending = _Pending(line, block, sync, accessory_change=accessory_change, pause=pause)
        return None

    def _queue(self, pending: _Pending, jog: bool = False) -> bool:
        """Put a parsed line into the planner; an arc's chords go in while there is room. True once all are in."""
        block = pending.block
        if pending.pieces is None:
            segment = block.segment if block.segment is not None and block.segment.length > 0 else None
            pending.pieces = self._chords(segment)[::-1] if segment is not None else []  # next chord last
            if segment is None:
                planned = _Planned(text=pending.line, line_number=block.line_number, jog=jog, pause=pending.pause,
                                   spindle=block.modal.spindle, speed=block.modal.speed, dwell=block.dwell)
                self.planner.append(planned)
                if planned.dwell <= 0 and len(self.planner) == 1:
                    self._complete()  # nothing ahead of it: Grbl executes a non-motion line in the parser, before its ok
                return True
        programmed = block.modal.feed * (25.4 if block.modal.units == "G20" else 1.0)
        while pending.pieces and (jog or len(self._moves) < self.build.planner_blocks):
            piece = pending.pieces.pop()
            planned = _Planned(text=pending.line, line_number=block.line_number, jog=jog, pause=pending.pause,
                               spindle=block.modal.spindle, speed=block.modal.speed, segment=piece,
                               programmed_rate=programmed, final=not pending.pieces)
            self._plan(planned)
            if self.state == "Idle":
                self.state = "Jog" if jog else "Run"
        return not pending.pieces

    def _chords(self, segment: Segment) -> list[Segment]:
        """The planner blocks of a motion: a line is one; an arc is split into chords that stray at most $12 from
        it (motion_control.c, mc_arc: floor(length / sqrt(tol (2 r - tol))) chords, the last ending on target)."""
        if segment.center is None:
            return [segment]
        a, b, _ = segment.plane
        radius = math.hypot(segment.start[a] - segment.center[a], segment.start[b] - segment.center[b])
        tolerance = self.settings[12]
        chord = math.sqrt(tolerance * (2 * radius - tolerance)) if 2 * radius > tolerance > 0 else 0.0
        count = int(segment.length / chord) if chord > 0 else 1
        if count <= 1:
            return [Segment(segment.start, segment.end, segment.rapid)]
        points = [segment.start, *segment.points(count)[:-1], segment.end]
        return [Segment(p, q, False) for p, q in zip(points, points[1:])]

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

    def _plan(self, block: _Planned) -> None:
        """Add a motion block to the planner (planner.c, plan_buffer_line) and replan the buffer."""
        segment = block.segment
        start, end = segment.start, segment.end
        dx, dy, dz = end[0] - start[0], end[1] - start[1], end[2] - start[2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        unit = (dx / length, dy / length, dz / length)
        rapid_rate = self._axis_limit(110, unit)
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

    def _advance(self, dt: float, single: bool = False) -> float:
        """Run the planner for `dt` seconds of machine time (with `single`, stop once a block completes: `dt` may
        then be infinite); returns the machine time used."""
        spent, clock = 0.0, self.machine_time
        while self.planner and not self._critical:
            block = self.planner[0]
            if block.segment is None and block.dwell <= 0:
                self.machine_time = clock + spent
                self._complete()
                continue
            if self._hold == "complete" or dt - spent <= 0:
                break
            if block.segment is None:
                used = min(dt - spent, block.dwell)
                block.dwell -= used
                spent += used
                if single and block.dwell <= 0:
                    self.machine_time = clock + spent
                    self._complete()
                    break
                continue
            before = block.progress
            if self._hold == "decelerating":  # slow down at once, through the next blocks if need be
                accel, remaining, speed = block.accel, block.length - before, self._speed
                step = min(dt - spent, speed / accel)
                travel = speed * step - 0.5 * accel * step * step
                if travel >= remaining:
                    end = math.sqrt(max(speed * speed - 2.0 * accel * remaining, 0.0))
                    step, travel, speed = (speed - end) / accel, remaining, end
                else:
                    speed -= accel * step
                self._speed = speed if speed > 1e-9 else 0.0
                if self._speed == 0.0:
                    self._hold = "complete"
                block.progress += travel
                spent += step
            else:
                spent += self._profile(block, dt - spent)
            alarm = self.faults.alarm_line
            if alarm is not None and block.line_number == alarm and before < block.length / 2 <= block.progress:
                self.faults.alarm_line = None
                block.progress = block.length / 2
                self.position = block.segment.point_at(0.5)
                self._alarm(self.faults.alarm_code)
                break
            if block.progress >= block.length - 1e-9:
                self.machine_time = clock + spent
                self._complete()
                if self._pending is not None or self._rx:
                    self._process_input()  # the main loop refills the planner while the steppers run
                if single:
                    break
            else:
                self.position = block.segment.point_at(block.progress / block.length)
        if not self.planner and self.state in ("Run", "Jog"):
            self.state = "Idle"
            self._speed = 0.0
        elif not self.planner and self._hold == "decelerating":  # the last block ended while slowing: stopped
            self._hold = "complete"
            self._speed = 0.0
        self.machine_time = clock + spent
        return spent

    def _profile(self, block: _Planned, dt: float) -> float:
        """Move along `block` for up to `dt` seconds on its trapezoid from the current speed: accelerate to the
        nominal speed, cruise, and decelerate to the next block's planned entry speed (0 if none) at its end.
        Returns the time used (less than `dt` if the block ends)."""
        accel, nominal = block.accel, block.rate
        exit2 = self._moves[1].entry2 if len(self._moves) > 1 else 0.0
        speed, used = self._speed, 0.0
        while dt - used > 1e-12:
            remaining = block.length - block.progress
            if remaining <= 1e-9:
                break
            braking = (speed * speed - exit2) / (2.0 * accel)
            if braking >= remaining - 1e-9:  # decelerate to the end of the block
                end = math.sqrt(max(speed * speed - 2.0 * accel * remaining, 0.0))
                phase = (speed - end) / accel
                if phase <= 1e-12:  # already at the exit speed: the rounding is the rest of the block
                    phase = remaining / max(speed, 1e-9)
                    end = speed
                if used + phase <= dt:
                    used, speed, block.progress = used + phase, end, block.length
                    break
                step = dt - used
                block.progress += speed * step - 0.5 * accel * step * step
                speed, used = speed - accel * step, dt
            elif speed < nominal - 1e-9 and (peak := min(nominal, math.sqrt(
                    (2.0 * accel * remaining + speed * speed + exit2) / 2.0))) > speed + 1e-9:
                # accelerate to the nominal speed, or to the peak of a triangle where braking must begin
                phase = (peak - speed) / accel
                if used + phase <= dt:
                    block.progress = min(block.progress + (peak * peak - speed * speed) / (2.0 * accel), block.length)
                    used, speed = used + phase, peak
                    continue
                step = dt - used
                block.progress += speed * step + 0.5 * accel * step * step
                speed, used = speed + accel * step, dt
            else:  # cruise until braking must begin
                cruise = remaining - max(braking, 0.0)
                phase = cruise / max(speed, 1e-9)
                if used + phase <= dt:
                    block.progress += cruise
                    used += phase
                    continue
                block.progress += speed * (dt - used)
                used = dt
        self._speed = speed
        return used

    def _complete(self) -> None:
        block = self.planner.popleft()
        if block.segment is not None:
            self.position = block.segment.end
            self._moves.popleft()
            self._optimal = max(0, self._optimal - 1)
            if not block.final:
                return
        if self.completed is not None:
            self.completed.append((block.text, self.machine_time))
        if self._log and not block.jog:
            self._log.write(block.text + "\n")
            self._log.flush()
        if block.pause:  # M0: the planner is empty (it synchronised); hold until cycle start
            self._hold, self.state, self._hold_stopped_motion = "complete", "Hold", False

    def step(self, seconds: float | None = None) -> float:
        """One turn of the main loop of a controller made with `threaded=False`: take input, then run `seconds` of
        machine time (None: until the next planner block or dwell completes). Returns the machine time used."""
        with self._lock:
            self._process_input()
            used = self._advance(math.inf if seconds is None else seconds, single=seconds is None)
            self._process_input()
            return used

    # ----- system commands ($) -------------------------------------------------------------------------
    def _system_command(self, line: str) -> None:
        status = self._system(line)
        if status is not None:
            self._say("ok" if status == 0 else f"error:{status}")

    def _system(self, line: str) -> int | None:
        if line == "$":
            self._say(HELP)
            return 0
        if line.startswith("$J="):
            if self.state not in ("Idle", "Jog"):
                return 8
            return self._jog(line[3:])
        if line in ("$$", "$G", "$C", "$X"):
            return self._query_command(line[1])
        if line[1:2] in "$GCXJ":
            return 3
        if self.state not in ("Idle", "Alarm"):
            return 8
        if line == "$#":
            for name in ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
                self._say(f"[{name}:0.000,0.000,0.000]")
            self._say("[TLO:0.000]")
            self._say("[PRB:0.000,0.000,0.000:0]")
            return 0
        if line == "$I":
            for text in self.build.lines():
                self._say(text)
            return 0
        if line == "$N":
            self._say("$N0=")
            self._say("$N1=")
            return 0
        if line == "$H":
            return 5 if not self.settings[22] else 3
        if line.startswith("$RST="):
            if line not in ("$RST=$", "$RST=#", "$RST=*"):
                return 3
            if line != "$RST=#":
                self.settings = dict(DEFAULT_SETTINGS)
            self._say("[MSG:Restoring defaults]")
            self._say("ok")
            self._soft_reset()
            return None
        return self._store_setting(line[1:])

    def _query_command(self, letter: str) -> int:
        if letter == "$":
            if self.state in ("Run", "Hold"):
                return 8
            for key, value in self.settings.items():
                self._say(f"${key}={value:.0f}" if key in _INT_SETTINGS else f"${key}={value:.3f}")
        elif letter == "G":
            self._say(self.modal.report())
        elif letter == "C":
            if self.state == "Check":
                self._reset_runtime()
                self.state = "Idle"
                self._say("[MSG:Disabled]")
                self._say("ok")
                self._say(BANNER)
                return None
            if self.state != "Idle":
                return 8
            self.state = "Check"
            self._say("[MSG:Enabled]")
        elif letter == "X" and self.state == "Alarm":
            self._say("[MSG:Caution: Unlocked]")
            self.state = "Idle"
        return 0

    def _store_setting(self, text: str) -> int:
        key, equals, value = text.partition("=")
        try:
            number = int(key)
        except ValueError:
            return 3 if key.isalpha() else 2
        if not equals:
            return 3
        try:
            parsed = float(value)
        except ValueError:
            return 2
        if parsed < 0:
            return 4
        if number not in self.settings:
            return 3
        self.settings[number] = float(int(parsed)) if number in _INT_SETTINGS else parsed
        return 0

    def _jog(self, text: str) -> int:
        try:
            block = execute(text, replace(self.modal, motion="G1", feed=0.0), self.position)
        except GcodeError:
            return 16
        if block.segment is None or "F" not in text:
            return 16
        self._queue(_Pending("$J=" + text, block, sync=False), jog=True)
        return 0


def timed_run(lines: list[str], *, settings: dict[int, float] | None = None,
              build: BuildInfo = STOCK_BUILD) -> list[tuple[str, float]]:
    """Run program `lines` in machine time on a controller whose host keeps its receive buffer full (a line is
    sent as soon as it fits): (line as executed, machine time in s when it completed) for every line, in order.
    Deterministic: no wall clock, no thread. A line the controller refuses is a ValueError."""
    simulator = GrblSimulator(settings=settings, build=build, threaded=False)
    simulator.completed = []
    simulator.attach()
    waiting = deque(line.encode("ascii") + b"\n" for line in lines)
    while waiting or simulator.planner or simulator._pending is not None or simulator._rx:
        while waiting and len(waiting[0]) <= build.rx_buffer - len(simulator._rx):
            simulator.receive(waiting.popleft())
        progress = (len(simulator.completed), len(simulator._rx), simulator.machine_time)
        simulator.step()
        answers = simulator.read(1 << 20, None).decode("ascii")
        if "error" in answers or "ALARM" in answers:
            raise ValueError(f"the controller refused a line: {answers.strip()}")
        if progress == (len(simulator.completed), len(simulator._rx), simulator.machine_time):
            raise ValueError(f"the controller stopped: state {simulator.state}")
    simulator.close()
    return simulator.completed
