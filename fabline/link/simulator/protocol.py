"""The controller's side of Grbl's line protocol: the receive buffer, real-time bytes, the line buffer, and each
line's `ok` or `error:N` (with faults applied as the bytes arrive)."""

from __future__ import annotations

import time
from collections import deque

from fabline.link.simulator.faults import ConnectionDropped
from fabline.link.simulator.planner import Pending
from fabline.machine.gcode import GcodeError, execute

LINE_BUFFER_SIZE = 80
_REALTIME_BYTES = (b"?", b"!", b"~", b"\x18")
_BLANK = bytes(range(33)) + b"/"  # what the protocol loop drops from a line: control characters, space, block delete


class LineProtocol:
    """GrblSimulator's host side: bytes in, answers out, lines parsed into the planner."""

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

    def _say(self, text: str) -> None:
        if self._connected:
            self._output += text.encode("ascii") + b"\r\n"
            self._output_ready.notify_all()

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
                if char == ")" and self._comment == "(":
                    self._comment = False
            elif char in "(;":
                self._comment = char  # "(" until ")", ";" to the line end
            elif char <= " " or char == "/":
                continue
            elif len(self._line) >= LINE_BUFFER_SIZE - 1:
                self._line_overflow = True
            else:
                self._line += char.upper().encode("ascii", errors="replace")

    def _take_plain_text(self) -> bool:
        """Move the received characters before the next line end into the line buffer at once, as the loop below
        would one by one (whitespace, control characters and `/` dropped, letters uppercased, overflow past 79), when
        they hold no comment; False (nothing taken) when they do or a line end comes first."""
        rx = self._rx
        ends = [index for index in (rx.find(b"\n"), rx.find(b"\r")) if index >= 0]
        end = min(ends) if ends else len(rx)
        if end == 0 or rx.find(b"(", 0, end) >= 0 or rx.find(b";", 0, end) >= 0:
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
        self._pending = Pending(line, block, sync, accessory_change=accessory_change, pause=pause)
        return None
