"""The transport to a controller: a pyserial URL opened, locked, read as classified lines, logged both ways.

Nothing here knows a program; what the lines mean to a job is the `listener`'s (the record of what ran).
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import serial

from fabline.errors import FablineError
from fabline.fileio import open_append
from fabline.link.journal import JournalError
from fabline.link.ports import port_endpoints
from fabline.link.protocol import STATUS_QUERY, LineSplitter, Response, StatusReport, classify
from fabline.locks import exclusive_lock, lock_path
from fabline.machine.codes import explain_error
from fabline.machine.gcode import Vector


class Lost(Exception):
    """The port failed (device vanished, socket closed)."""


class Connection:
    """One port (`/dev/ttyUSB0`, `socket://host:port`, `rfc2217://...`, `sim://grbl`, ...) and its exchange log.

    `listener` (or None) is told of every line read, after `status` and `wco` are updated from it: `heard(response)`,
    and `reset()` when the controller flushed what it held."""

    def __init__(self, url: str, *, baud: int = 115200, connect_timeout: float = 5.0, settle_timeout: float = 600.0,
                 status_interval: float = 0.2, exchange_log: str | os.PathLike | None = None):
        self.url, self.baud = url, baud
        self.connect_timeout, self.settle_timeout, self.status_interval = connect_timeout, settle_timeout, status_interval
        self.exchange_log_path = exchange_log
        self.port = None
        self.log = None
        self.listener = None
        self.status: StatusReport | None = None
        self.wco: tuple[float, ...] | None = None
        self.bytes_sent = 0
        self.explain_error = explain_error
        """`error:N` in words; the controller sets its dialect's once it knows it."""
        self.last_heard = time.monotonic()
        self._splitter = LineSplitter()

    @property
    def answer_wait(self) -> float:
        """s to wait for the answer to one command."""
        return max(self.connect_timeout, 2.0)

    def lock(self, locks: contextlib.ExitStack) -> None:
        """Hold this port's locks in `locks`: one per device or address, whatever URL names it (`port_endpoints`),
        so a console and a stream, or two URLs of one machine, never talk to it at once."""
        for endpoint in port_endpoints(self.url):
            locks.enter_context(exclusive_lock(lock_path(endpoint), f"port {self.url}"))

    def connect(self) -> None:
        """Open the port (exclusively, for a device)."""
        try:
            port = serial.serial_for_url(self.url, do_not_open=True, baudrate=self.baud, timeout=0.01,
                                         write_timeout=10)
            if "://" not in self.url:
                port.exclusive = True
            port.open()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise FablineError(f"port {self.url}: cannot open: {exc}") from None
        self.port = port
        self._splitter.clear()
        self.exchange("#", f"opened {self.url}")

    def start_log(self, greeting: str) -> None:
        """Open the exchange log (if one was asked for) once a controller answered; a log that cannot be begun
        closes the port and is not left behind empty."""
        if self.exchange_log_path is None:
            return
        new_log = not Path(self.exchange_log_path).exists()
        try:
            self.log = open_append(self.exchange_log_path, "exchange log", errors="replace")
            self.exchange("#", greeting)
        except FablineError:
            self.close_port()
            if new_log and self.log is None:  # created here and not even its first record went in
                Path(self.exchange_log_path).unlink(missing_ok=True)
            raise

    def close_port(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.port = None

    def close(self) -> None:
        self.close_port()
        if self.log is not None:
            self.log.close()
            self.log = None

    def exchange(self, direction: str, text: str) -> None:
        """Append to the exchange log; a log that cannot be written is closed and raised as a JournalError."""
        if self.log is not None:
            try:
                self.log.write(f"{time.time():.3f} {direction} {text}\n")
                self.log.flush()
            except OSError as exc:
                log, self.log = self.log, None
                try:
                    log.close()
                except OSError:
                    pass  # its buffer cannot be written either
                raise JournalError(f"{self.exchange_log_path}: cannot write the exchange log: "
                                   f"{exc.strerror or exc}") from None

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise Lost(str(exc)) from None
        self.bytes_sent += len(data)
        if data != STATUS_QUERY:
            self.exchange(">>>", data.decode("ascii", errors="replace").replace("\x18", "<ctrl-x>").rstrip("\n")
                          .replace("\n", "\n>>> "))

    def read(self, timeout: float) -> list[Response]:
        """Classified lines that arrived within about `timeout` seconds."""
        try:
            if self.port.timeout != timeout:  # setting it reconfigures a real tty: only when it changes
                self.port.timeout = timeout
            data = self.port.read(max(1, self.port.in_waiting))
            if self.port.in_waiting:
                data += self.port.read(self.port.in_waiting)
        except (serial.SerialException, OSError) as exc:
            raise Lost(str(exc)) from None
        if data:
            self.last_heard = time.monotonic()
        responses, logged = [], []
        for text in self._splitter.feed(data):
            response = classify(text)
            if response.kind == "status":
                self.status = response.status
                if response.status.wco is not None:
                    self.wco = response.status.wco
            if self.listener is not None:
                self.listener.heard(response)
            responses.append(response)
            logged += [text] if response.kind != "status" else []
        for text in logged:  # once every answer is counted: a log that fails loses no `ok`
            self.exchange("<<<", text)
        return responses

    def command(self, line: bytes, expect_error: bool = False, until_banner: bool = False,
                every_line: bool = False) -> list[str]:
        """Send one line with nothing else in flight; return the feedback lines before its ok
        (or, with `expect_error`, before its error; with `every_line`, plain lines too: FluidNC's `$CD` YAML). A `$` query refused because the controller is running
        (error:8: lines a lost connection left in its buffer, found idle a moment before) is asked again once
        the controller stands still."""
        self.write(line)
        feedback, answered, waited = [], False, False
        deadline = time.monotonic() + self.answer_wait
        while time.monotonic() < deadline:
            for response in self.read(0.02):
                if response.kind in ("feedback", "setting", "message") or (every_line and response.kind == "other"):
                    feedback.append(response.text)
                elif response.kind == ("error" if expect_error else "ok"):
                    answered = True
                elif response.kind == "error" and response.code == 8 and line.startswith(b"$") and not waited:
                    self.settle()  # bounded by settle_timeout, with its own message
                    waited, feedback = True, []
                    self.write(line)
                    deadline = time.monotonic() + self.answer_wait
                elif response.kind == "error":
                    raise FablineError(f"{self.url}: {line.decode().strip()!r} answered {self.explain_error(response.code)}")
                elif response.kind == "banner" and until_banner and answered:
                    return feedback
            if answered and not until_banner:
                return feedback
        raise FablineError(f"{self.url}: no answer to {line.decode().strip()!r} within {self.answer_wait:g} s")

    def query_status(self) -> StatusReport:
        """Ask for one status report and wait for it."""
        deadline = time.monotonic() + self.answer_wait
        while time.monotonic() < deadline:
            self.write(STATUS_QUERY)
            end = time.monotonic() + 0.25
            while time.monotonic() < end:
                for response in self.read(0.02):
                    if response.kind == "status":
                        return response.status
        raise FablineError(f"{self.url}: the controller stopped answering status queries")

    def settle(self) -> StatusReport:
        """Wait until the controller has finished what it was given (Idle, Alarm or a stop), its work position known."""
        deadline = time.monotonic() + self.settle_timeout
        while True:
            status = self.query_status()
            settled = status.state in ("Idle", "Alarm", "Check") or (status.state == "Hold" and status.substate == 0)
            if settled and (self.wco is not None or status.wpos is not None):
                return status
            if time.monotonic() > deadline:
                raise FablineError(f"{self.url}: the controller is still {status.state} after {self.settle_timeout:g} s "
                                   "of waiting for it to finish its buffered moves; stop it (reset), check the part "
                                   "and resume with --from-line")
            time.sleep(self.status_interval if not settled else 0.02)

    def work_position(self) -> Vector:
        """The controller's work position now: where a new run's motion starts."""
        deadline = time.monotonic() + self.answer_wait
        while time.monotonic() < deadline:
            status = self.query_status()
            position = status.work_position(self.wco) if (self.wco or status.wpos) else None
            if position is not None and len(position) >= 3:
                return tuple(float(v) for v in position[:3])
            time.sleep(0.02)
        raise FablineError(f"{self.url}: the controller reports no work position (no WCO in its status reports)")

    def machine_clock(self) -> float | None:
        """The controller's own clock (seconds), where the port has one (`sim://`); None for a real machine."""
        clock = getattr(self.port, "machine_time", None)
        return float(clock) if isinstance(clock, (int, float)) else None
