"""An in-process GRBL 1.1h controller simulator: receive buffer, planner, motion in (scaled) time, faults.

It answers like the firmware captured in `grbl-1.1h-transcript.txt` (banner, `$$`, `$I`, `$G`, `$#`,
`ok`/`error:N`, `ALARM:N`, status reports per `$10`, check mode, feed hold) and records every line it
executes, in execution order, to an append-only executed-line log. Deviations from real firmware:
constant speed (no acceleration ramps except when decelerating into a feed hold), one planner block per
arc, work offsets fixed at zero.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

from fabline.link.gcode import Block, GcodeError, ModalState, Segment, execute
from fabline.link.protocol import RX_BUFFER_SIZE

VERSION = "1.1h"
BUILD = "[VER:1.1h.20190830:]"
OPTIONS = "[OPT:V,15,128]"
BANNER = f"Grbl {VERSION} ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
PLANNER_BLOCKS = 15
LINE_BUFFER_SIZE = 80
_REALTIME_BYTES = (b"?", b"!", b"~", b"\x18")
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


@dataclass
class _Pending:
    """A parsed line waiting for planner room, or (spindle, coolant, dwell changes) for the planner to empty."""

    line: str
    block: Block
    sync: bool
    queued: bool = False
    accessory_change: bool = False


@dataclass
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
    spindle: str = "M5"
    speed: float = 0.0


class GrblSimulator:
    """A GRBL 1.1h controller in a background thread; `time_scale` > 1 makes motion run faster.

    `line_time` is the firmware's time (real seconds, not scaled) to parse and plan one line before it
    answers and reads the next: an 8-bit Grbl needs a few milliseconds, 0 makes the controller instant.
    """

    def __init__(self, *, time_scale: float = 1.0, executed_log: str | Path | None = None,
                 faults: Faults | None = None, tick: float = 0.001, settings: dict[int, float] | None = None,
                 line_time: float = 0.0):
        self.time_scale = time_scale
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
        self._power_on()
        self._thread = threading.Thread(target=self._run, name="grbl-sim", daemon=True)
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
                room = RX_BUFFER_SIZE - len(self._rx)  # the common case, taken in one step: plain line bytes
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
                elif len(self._rx) < RX_BUFFER_SIZE:
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
        self.modal = ModalState()
        self._parse_position = self.position
        self._hold = None
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
        return sum(1 for block in self.planner if block.segment is not None)

    # ----- real-time commands ----------------------------------------------------------------------
    def _realtime(self, byte: int) -> None:
        if byte == 0x3F:
            self._say(self._status_report())
        elif byte == 0x21:
            if self.state in ("Run", "Jog") and self._hold is None:
                self._hold = "decelerating"
                self.state = "Hold"
        elif byte == 0x7E:
            if self.state == "Hold" and self._hold == "complete":
                self._hold = None
                self.state = "Run" if self._moving else "Idle"
        elif byte == 0x18:
            self._soft_reset()
        elif byte == 0x85 and self.state == "Jog":
            self.planner = deque(block for block in self.planner if not block.jog)
            self.state = "Idle"

    def _soft_reset(self) -> None:
        lost = self.state in ("Run", "Jog", "Hold")
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
            parts.append(f"Bf:{PLANNER_BLOCKS - self._motion_blocks()},{RX_BUFFER_SIZE - len(self._rx)}")
        if self.planner and self.planner[0].line_number and self.state in ("Run", "Hold", "Jog"):
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
                if pending.sync and self.planner:
                    return
                if not pending.sync and self._motion_blocks() >= PLANNER_BLOCKS:
                    return
                if not pending.queued:
                    if pending.accessory_change:
                        self._ovr_counter = 0  # the firmware reports a spindle or coolant change at once
                    self._queue(pending.line, pending.block)
                    pending.queued = True
                    if pending.block.dwell > 0:
                        return
                self._pending = None
                self._say("ok")
                continue
            if not self._rx:
                return
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
            block = execute(line, self.modal, self._parse_position)
        except GcodeError as exc:
            return exc.code
        if self.faults.error_line is not None and block.line_number == self.faults.error_line:
            self.faults.error_line = None
            return self.faults.error_code
        accessory_change = block.modal.spindle != self.modal.spindle or block.modal.coolant != self.modal.coolant
        sync = accessory_change or block.dwell > 0 or block.program_end
        self.modal = block.modal
        if block.segment is not None:  # check mode moves nothing but parses on from the target, as Grbl does
            self._parse_position = block.segment.end
        if self.state == "Check":
            return 0
        self._pending = _Pending(line, block, sync, accessory_change=accessory_change)
        return None

    def _queue(self, line: str, block: Block | None, jog: bool = False) -> None:
        planned = _Planned(text=line, line_number=block.line_number if block else None, jog=jog)
        if block is not None:
            planned.spindle, planned.speed = block.modal.spindle, block.modal.speed
            planned.dwell = block.dwell
            if block.segment is not None and block.segment.length > 0:
                planned.segment = block.segment
                planned.programmed_rate = block.modal.feed * (25.4 if block.modal.units == "G20" else 1.0)
                planned.rate = self._rate(block.segment, planned.programmed_rate)
        self.planner.append(planned)
        if planned.segment is None and planned.dwell <= 0 and len(self.planner) == 1:
            self._complete()  # nothing ahead of it: Grbl executes a non-motion line in the parser, before its ok
        elif planned.segment is not None and self.state == "Idle":
            self.state = "Jog" if jog else "Run"

    def _rate(self, segment: Segment, programmed: float) -> float:
        """Nominal speed in mm/s: the feed (or rapid) limited so no axis exceeds its maximum rate."""
        span = [e - s for s, e in zip(segment.start, segment.end)]
        length = math.hypot(*span) or segment.length
        limit = math.inf
        for axis, delta in enumerate(span):
            if delta and segment.center is None:
                limit = min(limit, self.settings[110 + axis] * length / abs(delta))
        if segment.center is not None:
            limit = min(self.settings[110 + a] for a in segment.plane[:2])
        rate = limit if segment.rapid else min(programmed, limit)
        return rate / 60.0

    def _advance(self, dt: float) -> None:
        """Run the planner for `dt` seconds of machine time."""
        while self.planner and not self._critical:
            block = self.planner[0]
            if block.segment is None and block.dwell <= 0:
                self._complete()
                continue
            if self._hold == "complete" or dt <= 0:
                break
            if block.segment is None:
                used = min(dt, block.dwell)
                block.dwell -= used
                dt -= used
                continue
            if self._hold is None:
                self._speed = block.rate
            if self._hold == "decelerating":
                accel = self.settings[120]
                step = min(dt, self._speed / accel) if accel > 0 else dt
                travel = self._speed * step - 0.5 * accel * step * step
                self._speed = max(0.0, self._speed - accel * step)
                dt -= step
                if self._speed <= 1e-9:
                    self._hold = "complete"
            else:
                travel = self._speed * dt
                dt = 0.0
            length = block.segment.length
            before = block.progress
            block.progress += travel
            alarm = self.faults.alarm_line
            if alarm is not None and block.line_number == alarm and before < length / 2 <= block.progress:
                self.faults.alarm_line = None
                block.progress = length / 2
                self.position = block.segment.point_at(0.5)
                self._alarm(self.faults.alarm_code)
                return
            if block.progress >= length:
                if self._speed > 0 and self._hold is None:
                    dt += (block.progress - length) / self._speed
                self._complete()
            else:
                self.position = block.segment.point_at(block.progress / length)
        if not self.planner and self.state in ("Run", "Jog"):
            self.state = "Idle"
            self._speed = 0.0

    def _complete(self) -> None:
        block = self.planner.popleft()
        if block.segment is not None:
            self.position = block.segment.end
        if self._log and not block.jog:
            self._log.write(block.text + "\n")
            self._log.flush()

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
            self._say(BUILD)
            self._say(OPTIONS)
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
        self._queue("$J=" + text, block, jog=True)
        return 0
