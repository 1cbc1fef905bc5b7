"""Stream a G-code program to a GRBL 1.1 controller over any pyserial URL, journaled so nothing is lost.

`Streamer(port).run(program, on_progress=..., journal=...)` is the one entry point the CLI and the job
runner use. It detects the controller, streams with character counting (or send-response), polls
status, stops safely on `error:N`, alarms, an abort or a lost connection, and resumes from the last
line known to be executed after re-establishing the modal state. How it knows what was executed:
  * `ok` means parsed into the planner; a status report `Ln:N` means every line before N is done;
    Idle with nothing in flight means every acknowledged line is done.
  * after a lost connection or a killed host it waits for the controller to finish, discards any
    half-received line (`#` + newline always fails to parse) and reads `$G`: its T word is the tag of
    the last line parsed, looked up among the lines the journal shows sent after its last `ok` (a batch's
    `sent` records are flushed before it goes to the port), so lines whose `ok` never arrived (or never
    reached the disk) are settled by the controller itself; its position must be where the program is after
    that line. A tag beyond the journaled sends or a position elsewhere (the journal lost records) is refused.
  * after an alarm or a halt (feed hold + reset) the planner is flushed; the interrupted line is found
    from the stopped position within the window of lines that can still have been in the planner (the
    acknowledged lines back to `planner_blocks` motion lines, or the `Ln:` of builds that report it), and
    it is run again from its start. A position that fits several lines of the window (a retraced path) is
    refused, naming the candidate file lines, for the operator to choose with --from-line.
  * a host that died during a feed hold: cycle start lets the controller finish what it holds, then `$G`.
Motion is planned from the controller's work position at the start of the run (kept in the journal).
Before the first move the controller's build (`$I`) and settings (`$$`) are checked against the program and
its machine profile (`fabline.link.compat`); the port and the journal are locked for the whole run.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import serial

from fabline.errors import FablineError
from fabline.fileio import open_append
from fabline.machine.build import ANY_BUILD, STOCK_BUILD, BuildInfo
from fabline.machine.codes import explain_alarm, explain_error, listing
from fabline.link.compat import controller_problems, program_machine
from fabline.machine.gcode import ModalState, Vector
from fabline.link.ports import check_port, port_endpoints
from fabline.link.journal import Journal, JournalError, JournalState, default_journal_path, read_journal
from fabline.machine.program import TAG_CYCLE, Program, line_tag, load_program
from fabline.link.protocol import (CYCLE_START, FEED_HOLD, OVERRIDES, SOFT_RESET, STATUS_QUERY, CharacterCounter,
                                   LineSplitter, Response, StatusReport, classify)
from fabline.locks import exclusive_lock, lock_path
from fabline.progress import Eta, estimate, simulated_speedup

MODES = ("counting", "send-response")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Ctrl-C, `kill` (a service stop) and a closed terminal: each stops a stream safely (feed hold, reset, journal)."""
SEGMENT_BUFFER = 6
"""Grbl's stepper segment buffer (SEGMENT_BUFFER_SIZE): up to this many blocks may still run after leaving the planner."""
POSITION_TOLERANCE = 0.01
"""mm: status reports carry three decimals; a stopped position is matched to a path within this."""
_FLUSH_LINE = b"#\n"
COMMIT_INTERVAL = 0.05
"""s between background journal fsyncs while streaming (stops commit at once): at 460 lines/s the journal
lags the controller by far fewer than the 255 lines a `$G` tag can tell apart."""
_TAG = re.compile(r"\bT(\d+)\b")
_MOTION_WORD = re.compile(r"G0*[0-3](?![0-9.])")


@dataclass(frozen=True)
class Progress:
    """What a progress callback receives: lines acknowledged of total, `percent` of the program's planned machine time
    done (not of its lines: one long cut can be most of a sheet), machine state and work position, times in s."""

    acked: int
    total: int
    percent: float
    state: str
    position: tuple[float, ...] | None
    elapsed: float
    remaining: float | None
    file_line: int | None
    message: str | None = None
    """Set while the program waits for the operator: `program paused (M0) at file line N: resume to continue`."""
    eta: Eta | None = None
    """Elapsed and remaining time from the planner's machine time per line, corrected by the pace made so far; the
    elapsed time leaves out the time held waiting for the operator, so waiting is not counted as work to come."""


@dataclass(frozen=True)
class StreamResult:
    """How a run ended: completed, or stopped by an abort (resumable with `resume=True`)."""

    completed: bool
    executed: int
    total: int
    reason: str | None
    elapsed: float
    bytes_sent: int
    machine: float | None = None
    """Machine time of this run: the controller's own clock where the port has one (a simulator's `machine_time`),
    else the wall time less the time held (a pause, an M0 waiting for the operator)."""
    held: float = 0.0
    """Wall seconds the machine stood held, waiting for the operator."""


class StreamInterrupted(FablineError):
    """The stream stopped on an error, an alarm or a lost connection; the journal allows a resume.

    `reason` is one of: error, alarm, connection, reset, undecided (the stopped position fits several lines:
    resume with --from-line), journal (the journal could not be written; resume with --from-line); `executed`
    counts the program lines known done.
    """

    def __init__(self, message: str, reason: str, executed: int):
        super().__init__(message)
        self.reason = reason
        self.executed = executed


class _Lost(Exception):
    """The port failed (device vanished, socket closed)."""


class _Undecided(Exception):
    """The stopped position does not tell which line was executing: the operator must say (--from-line)."""


def _checked_identity(identity: dict[str, str] | None) -> dict[str, str] | None:
    """A run identity as the journal keeps it: names and values are text; an empty one is none."""
    if identity is None or identity == {}:
        return None
    if not isinstance(identity, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in identity.items()):
        raise FablineError(f"a run identity maps names to text, such as {{'job': 'pavilion', 'run': '3'}}; got {identity!r}")
    return dict(identity)


def _override_byte(name: str) -> bytes:
    """The real-time byte of the override `name` (`OVERRIDES`: 'feed +10%', ...); an unknown name is refused."""
    if name not in OVERRIDES:
        raise FablineError(f"unknown override {name!r} (use one of: {', '.join(OVERRIDES)})")
    return OVERRIDES[name]


def _where(position) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in position) + ")"


def _describe(identity: dict[str, str] | None) -> str:
    return "no named run" if identity is None else "run " + ", ".join(f"{k}={v}" for k, v in sorted(identity.items()))


JOG_WAIT = 60.0
"""Seconds a console line waits for an earlier jog to end (Grbl refuses G-code while it jogs: error:9)."""
HOMING_WAIT = 120.0
"""Seconds a console `$H` waits for its ok: Grbl answers when the homing cycle is over."""


class Streamer:
    """A GRBL 1.1 host on one port (`/dev/ttyUSB0`, `socket://host:port`, `rfc2217://...`, `sim://grbl`, ...)."""

    def __init__(self, port: str, *, baud: int = 115200, mode: str = "counting", status_interval: float = 0.2,
                 connect_timeout: float = 5.0, settle_timeout: float = 600.0, reconnect_timeout: float = 0.0,
                 silence_timeout: float = 10.0, stop_timeout: float = 30.0,
                 exchange_log: str | os.PathLike | None = None):
        if mode not in MODES:
            raise FablineError(f"unknown streaming mode {mode!r}; use one of {', '.join(MODES)}")
        self.url = port
        self.baud = baud
        self.mode = mode
        self.status_interval = status_interval
        self.connect_timeout = connect_timeout
        self.settle_timeout = settle_timeout
        """s to wait for a controller left running by an interrupted job to finish its buffered moves."""
        self.stop_timeout = stop_timeout
        """s to wait for the machine to stand still after a feed hold (deceleration takes well under one)."""
        self.reconnect_timeout = reconnect_timeout
        self.silence_timeout = silence_timeout
        self._last_heard = time.monotonic()
        self.exchange_log_path = exchange_log
        self.build = STOCK_BUILD
        self.rx_buffer = STOCK_BUILD.rx_buffer
        self.settings: dict[int, float] = {}
        self.version: str | None = None
        self.status: StatusReport | None = None
        self._wco: tuple[float, ...] | None = None
        self._port = None
        self._log = None
        self._counter: CharacterCounter | None = None
        self._errors: list[tuple[int | None, int | None]] = []
        self._status_after_last_ok = False
        self.bytes_sent = 0
        self._splitter = LineSplitter()
        self._realtime: list[bytes] = []
        self._abort = threading.Event()
        self._control = threading.RLock()  # taken by signal handlers too (SIGUSR1 resume), in the thread they interrupt
        self._paused = False
        self._pauses: list[int] = []  # acknowledged M0 lines whose pause has not been reported yet
        self.message: str | None = None
        self._timeline, self._timeline_for = None, None
        self.started = time.monotonic()
        self.held, self._held_since = 0.0, None  # wall seconds held waiting for the operator in this run
        self._machine_start = 0.0

    # ----- control from any thread -----------------------------------------------------------------
    def pause(self) -> None:
        """Feed hold: the machine decelerates to a stop; streaming continues into the buffers."""
        with self._control:
            self._realtime.append(FEED_HOLD)
            self._paused = True
            if self._held_since is None:
                self._held_since = time.monotonic()

    def resume(self) -> None:
        """Cycle start after a pause."""
        with self._control:
            self._realtime.append(CYCLE_START)
            self._paused = False
            self.message = None
            if self._held_since is not None:
                self.held += time.monotonic() - self._held_since
                self._held_since = None

    def abort(self) -> None:
        """Stop the job safely (feed hold, then reset); the journal allows a later resume."""
        self._abort.set()

    def override(self, name: str) -> None:
        """A real-time override while a program streams (`OVERRIDES`: 'feed +10%', 'power -1%', ...): the byte
        goes out with the next real-time commands."""
        byte = _override_byte(name)
        with self._control:
            self._realtime.append(byte)

    def console(self, lines: list[str], realtime: list[str] = ()) -> list[tuple[str, list[str]]]:
        """An operator's commands to a controller that is not running a program: `realtime` overrides by name,
        then each line (a `$` setting, `$X`, `$H`, a `$J=` jog, `G10 L20 P1 X0 Y0` ...) sent alone and answered
        before the next. Returns (line, the controller's answer lines, ending in `ok` or `error:N (meaning)`)
        per line; an `error` answer does not stop the rest. Refused while the controller runs, jogs or holds."""
        overrides = [_override_byte(name) for name in realtime]
        with contextlib.ExitStack() as locks:
            self._lock_port(locks)
            self._open()
            try:
                for byte in overrides:
                    self._write(byte)
                state = self._query_status().state if lines else "Idle"
                deadline = time.monotonic() + JOG_WAIT
                while state == "Jog" and time.monotonic() < deadline:  # an earlier jog still moving: let it end
                    time.sleep(0.05)
                    state = self._query_status().state
                if state not in ("Idle", "Alarm"):
                    raise FablineError(f"{self.url}: the controller is {state}; wait until it is idle")
                return [(line, self._answer(line)) for line in lines]
            finally:
                self._close()

    def _lock_port(self, locks: contextlib.ExitStack) -> None:
        """Hold this port's locks in `locks`: one per device or address, whatever URL names it (`port_endpoints`),
        so a console and a stream, or two URLs of one machine, never talk to it at once."""
        for endpoint in port_endpoints(self.url):
            locks.enter_context(exclusive_lock(lock_path(endpoint), f"port {self.url}"))

    def _answer(self, line: str) -> list[str]:
        """Send one console line; its feedback lines and the final `ok` or `error:N (meaning)`."""
        self._write(line.encode("ascii") + b"\n")
        wait = HOMING_WAIT if line.startswith("$H") else max(self.connect_timeout, 2.0)  # ok comes when homed
        answer, deadline = [], time.monotonic() + wait
        while time.monotonic() < deadline:
            for response in self._read(0.02):
                if response.kind == "ok":
                    return answer + ["ok"]
                if response.kind == "error":
                    return answer + [explain_error(response.code)]
                if response.kind != "status":
                    answer.append(response.text if response.kind != "alarm" else explain_alarm(response.code))
        raise FablineError(f"{self.url}: no answer to {line!r} within {wait:g} s")

    @property
    def paused(self) -> bool:
        """Whether a pause is in effect."""
        return self._paused

    # ----- the job -----------------------------------------------------------------------------------
    def run(self, program: Program | str | os.PathLike, *, on_progress: Callable[[Progress], None] | None = None,
            journal: str | os.PathLike | None = None, resume: bool = False, check: bool = False,
            unlock: bool = False, start_line: int | None = None, restart: bool = False,
            identity: dict[str, str] | None = None, machine: str | None = None,
            force: bool = False) -> StreamResult:
        """Stream `program`; `resume` continues an interrupted job from its journal; `check` runs GRBL check
        mode ($C) over the whole program first; `unlock` clears an alarm ($X) left by an interrupted job;
        `start_line` (a file line, with `resume`) is the operator's choice of where to restart, used instead of
        what the journal and the controller tell. A new run refuses to start over an interrupted one of the
        same program and identity unless `restart` says so. `identity` (e.g. job and run ids) is written to the
        journal; a resume must give the same. `machine` (a profile name or path) overrides the profile the
        program's header names; `force` streams despite controller conflicts (logged in journal and log)."""
        if resume and restart:
            raise FablineError("--resume and --restart contradict each other: give --resume to continue the "
                               "interrupted run, or --restart to start it over")
        if not isinstance(program, Program):
            path = Path(program)
            program = load_program(path, build=ANY_BUILD)  # the controller's own build is checked once it answers
            journal = journal if journal is not None else default_journal_path(path)
        if journal is None:
            raise FablineError("a journal path is needed to stream a program that was not read from a file")
        if start_line is not None and not resume:
            raise FablineError("--from-line needs --resume")
        identity = _checked_identity(identity)
        outputs = (Path(journal), *([self.exchange_log_path] if self.exchange_log_path is not None else []))
        check_port(self.url, inputs=(program.name,), outputs=outputs)  # before pyserial parses (spy's file=)
        self.program, self.journal_path, self.force = program, Path(journal), force
        self.profile = program_machine(program, machine)
        with contextlib.ExitStack() as locks:
            self._lock_port(locks)
            locks.enter_context(exclusive_lock(lock_path(str(self.journal_path)), f"journal {self.journal_path}"))
            previous = self._previous_job(resume, restart, identity)
            self.on_progress = on_progress
            self._open()
            try:
                if check:
                    self._check_mode()
                return self._job(previous, unlock, start_line, identity)
            finally:
                self._close()
                self._abort.clear()  # an abort asked for before or during this run stopped it; the next starts afresh

    def _previous_job(self, resume: bool, restart: bool, identity: dict[str, str] | None) -> JournalState | None:
        """The journal of the job being resumed, checked against the program and identity; None for a new job,
        whose journal starts afresh (an interrupted run of this program and identity is not overwritten by
        accident; --restart never reads the old journal, so a damaged one cannot block it)."""
        path, program = self.journal_path, self.program
        if not resume:
            if restart or not path.is_file() or path.stat().st_size == 0:
                return None
            state = read_journal(path)
            if state.sha256 == program.sha256 and not state.finished and state.identity == identity:
                raise FablineError(
                    f"{path}: an earlier run of {program.name} stopped after file line "
                    f"{self._file_line(state.done - 1) if state.done else 'none'} without finishing; "
                    "continue it with --resume, or start the sheet over with --restart")
            return None
        state = read_journal(path)
        if state.sha256 != program.sha256:
            raise FablineError(f"{path}: journal belongs to a different program (the G-code file changed)")
        if state.finished:
            raise FablineError(f"{path}: the job is already finished; nothing to resume")
        if state.identity != identity:
            raise FablineError(f"{path}: the interrupted run belongs to {_describe(state.identity)}, not "
                               f"{_describe(identity)}; resume it as that run, or start over with --restart")
        if state.total != len(program.lines) or max(state.acked, state.done, state.sent) > len(program.lines):
            raise FablineError(f"{path}: journal counts more lines than {program.name} has; the journal is damaged: "
                               "start the sheet over with --restart, or resume with --from-line")
        if any(block.modal.distance == "G91" for block in program.plan(ModalState(), (0.0, 0.0, 0.0))):
            raise FablineError(f"{program.name}: programs that use relative distances (G91) cannot be resumed safely")
        return state

    def _job(self, previous: JournalState | None, unlock: bool, start_line: int | None,
             identity: dict[str, str] | None) -> StreamResult:
        """Start or resume the job (checked against the controller first), then stream it, reconnecting and
        recovering after a lost connection."""
        program = self.program
        self.bytes_sent = 0
        self.acked = self.done = self.sent = 0
        if previous is None:
            self._fresh_start(unlock)
            self.origin = self._work_position()
        else:
            self.origin = previous.origin
            if self.origin is None and start_line is None:
                raise FablineError(f"{self.journal_path}: the journal does not say where the run started (an older "
                                   "fabline wrote it); resume with --from-line")
            if self.origin is None:
                self.origin = self._work_position()
        self.blocks = program.plan(ModalState(), self.origin, ANY_BUILD)
        problems = self._check_controller() if self.settings else None  # known unless found busy or in alarm
        if previous is None:
            executed = 0
        elif start_line is not None:  # the operator's choice overrides anything the journal would infer
            executed = self._index_of_file_line(start_line)
            self._stop_where_it_is(unlock)
        else:
            self.acked, self.done, self.sent = previous.acked, previous.done, previous.sent
            try:
                executed = self._recover(previous, unlock)
            except _Undecided as exc:
                raise StreamInterrupted(str(exc), "undecided", previous.done) from None
        if problems is None:  # read now that the controller stands still (a held one was first let finish)
            problems = self._check_controller()
        if self.on_progress is not None:
            self.timeline()  # before anything moves: computing it must not delay the stream loop's first answers
        self.journal = Journal(self.journal_path, sync_interval=COMMIT_INTERVAL).open(fresh=previous is None)
        try:
            return self._journaled_job(previous, executed, identity, problems)
        finally:
            self.journal.close()

    def _journaled_job(self, previous: JournalState | None, executed: int, identity: dict[str, str] | None,
                       forced: list[str]) -> StreamResult:
        """Stream with the journal open, from `executed` lines on; recover in place from a lost connection."""
        program = self.program
        self.journal.record("start", program=program.name, sha256=program.sha256, lines=len(program.lines),
                            mode=self.mode, origin=list(self.origin), identity=identity)
        if forced:
            self.journal.record("forced", problems=forced)
            self._exchange("#", "--force: streaming despite: " + "; ".join(forced))
        if previous is not None:
            self.journal.record("resume", count=executed)
        try:
            self.journal.commit()
        except JournalError as exc:
            if previous is None:  # a journal begun here holds nothing worth keeping
                self.journal.close()
                self.journal_path.unlink(missing_ok=True)
            raise JournalError(f"{exc}; nothing was sent") from None
        preamble = self._preamble(executed) if previous is not None else []
        self.acked = self.done = self.sent = self.first_index = executed
        self.started = time.monotonic()  # elapsed counts streaming, not the handshake
        with self._control:
            self.held, self._held_since = 0.0, (self.started if self._paused else None)
        self._machine_start = self._machine_clock()
        while True:
            try:
                return self._stream(preamble)
            except JournalError as exc:
                self._stop_unrecorded(exc)
            except _Lost as exc:
                self._counter = None  # whatever was in flight is settled by the recovery, not by stray answers
                self.journal.record("stopped", reason=f"connection lost: {exc}")
                self.journal.commit()
                if not self._reconnect():
                    raise StreamInterrupted(
                        f"{self.url}: connection lost ({exc}) after file line {self._file_line(self.acked - 1)}; "
                        "run again with --resume", "connection", self.done) from None
                state = JournalState(acked=self.acked, done=self.done, sent=self.sent, stopped="connection lost")
                try:
                    executed = self._recover(state, unlock=False)
                except _Undecided as exc:
                    self._stop_undecided(exc)
                preamble = self._preamble(executed)
                self.acked = self.done = self.sent = executed
                self.journal.record("resume", count=executed)
                self.journal.commit()

    def _check_controller(self) -> list[str]:
        """Refuse a controller whose build or settings conflict with the program or its profile (one line naming the
        setting and the fix), unless `force`; return the problems forced past."""
        if not self.settings:  # not read when the controller was found in alarm or busy
            self._read_build_info()
        problems = controller_problems(self.program, self.blocks, self.origin, self.settings, self.build,
                                       self.profile, self._wco)
        if problems and not self.force:
            more = f" (and {len(problems) - 1} more conflict{'s' if len(problems) > 2 else ''})" if len(problems) > 1 else ""
            raise FablineError(f"{problems[0]}{more}; nothing was sent (--force streams anyway)")
        return problems

    def _stream(self, preamble: list[bytes]) -> StreamResult:
        """Send everything from `self.done` on; return when the machine has executed the last line."""
        lines = self.program.lines
        outgoing = [(None, wire) for wire in preamble] + [(line.index, line.wire) for line in lines[self.done:]]
        counter = CharacterCounter(self.rx_buffer, max_lines=1 if self.mode == "send-response" else None)
        self._counter, self._errors, self._pauses = counter, [], []
        self._status_after_last_ok = False
        position, next_poll, next_report = 0, 0.0, 0.0
        self._last_heard = time.monotonic()
        while True:
            if self._abort.is_set():
                return self._stop_on_abort(counter)
            self._send_realtime()
            batch = []
            while position < len(outgoing) and counter.fits(len(outgoing[position][1])):
                index, wire = outgoing[position]
                counter.sent(index, len(wire))
                if index is not None:
                    self.journal.record("sent", n=index, line=lines[index].file_line)
                    self.sent = index + 1
                batch.append(wire)
                position += 1
            if batch:
                self.journal.flush()  # a line the controller received is always journaled as sent
                self._write(b"".join(batch))
            now = time.monotonic()
            if now >= next_poll:
                self._write(STATUS_QUERY)
                next_poll = now + self.status_interval
            if now - self._last_heard > self.silence_timeout:
                raise _Lost(f"the controller sent nothing for {self.silence_timeout:g} s, not even status reports")
            for response in self._read(0.01):
                if response.kind == "alarm":
                    self._stop_on_alarm(response.code)
                elif response.kind == "banner":
                    self.journal.record("stopped", reason="controller reset")
                    self.journal.commit()
                    raise StreamInterrupted(f"{self.url}: the controller reset itself during the job (power or "
                                            "USB problem?); check the machine, then run again with --resume --unlock",
                                            "reset", self.done)
            if self._errors:
                self._stop_on_error(*self._errors[0])
            if position == len(outgoing) and counter.in_flight == 0 and self.status is not None \
                    and self.status.state == "Idle" and self._status_after_last_ok:
                self.done = len(lines)
                self.journal.record("done", count=self.done)
                self.journal.record("finished")
                self.journal.commit()
                self._report()
                return StreamResult(True, self.done, len(lines), None, time.monotonic() - self.started, self.bytes_sent,
                                    self._machine_elapsed(), self._held_now())
            if time.monotonic() >= next_report:
                self._report()
                next_report = time.monotonic() + 0.1

    def _answered(self, response: Response) -> None:
        """Match an ok or error:N to the oldest line in flight; errors are queued for the stream loop."""
        index = self._counter.answered()
        self._status_after_last_ok = False
        if response.kind == "ok":
            if index is not None:
                self.journal.record("ok", n=index, line=self.program.lines[index].file_line)
                self.acked = index + 1
                if self.blocks[index].pause:
                    self._pauses.append(index)
            return
        if index is not None:
            self.journal.record("error", n=index, line=self.program.lines[index].file_line, code=response.code)
        self._errors.append((index, response.code))

    def _stop_on_error(self, index: int | None, code: int | None) -> None:
        """The controller rejected a line: halt it, journal how far it got, and raise."""
        if index is None:
            raise StreamInterrupted(f"{self.url}: controller refused a resume command: {explain_error(code)}",
                                    "error", self.done)
        line = self.program.lines[index]
        self.journal.commit()
        executed = self._halt(rejected=index)
        self.journal.record("done", count=executed)
        self.journal.record("stopped", reason=f"error:{code} at file line {line.file_line}")
        self.journal.commit()
        raise StreamInterrupted(f"{self.program.name}:{line.file_line}: controller answered "
                                f"{explain_error(code)}: {line.source.strip()}; stopped with "
                                f"{executed} lines executed", "error", executed)

    def _track_status(self, status: StatusReport, counter: CharacterCounter) -> None:
        """Advance the count of executed lines from `Ln:` (or Idle with nothing in flight)."""
        self._status_after_last_ok = True
        if self._errors:
            return  # after a rejected line only the halt decides what ran
        if self._pauses and status.state == "Hold" and status.substate == 0:
            self._program_paused(self._pauses.pop(0))
        executed = self.done
        if status.line_number is not None and status.state in ("Run", "Hold"):
            index = self._index_of_file_line(status.line_number, strict=False)
            if index is not None and index >= self.done:
                executed = index
        elif status.state == "Idle" and counter.in_flight == 0:
            executed = self.acked
        if executed > self.done:
            self.done = executed
            self.journal.record("done", count=executed)

    def _program_paused(self, index: int) -> None:
        """An M0 stopped the machine: say so (progress, journal, log) and wait for the operator's cycle start."""
        line = self.program.lines[index].file_line
        with self._control:
            self._paused = True
            self.message = f"program paused (M0) at file line {line}: resume to continue"
            if self._held_since is None:
                self._held_since = time.monotonic()
        self.journal.record("paused", line=line)
        self._exchange("#", self.message)
        self._report()

    # ----- stopping -------------------------------------------------------------------------------------
    def _stop_on_alarm(self, code: int | None) -> None:
        """An alarm flushed the controller: find the interrupted line from the stopped position, then stop."""
        self.journal.record("alarm", code=code)
        self.journal.commit()
        status = self._query_status()
        try:
            executed = self._executed_from_position(status, planner_empty=False)
        except _Undecided as exc:
            self._stop_undecided(exc, f"ALARM:{code}: ")
        self.done = executed
        self.journal.record("done", count=executed)
        self.journal.record("stopped", reason=f"ALARM:{code}")
        self.journal.commit()
        raise StreamInterrupted(f"{self.url}: {explain_alarm(code)} during file line {self._file_line(executed)}; "
                                "check the machine, then run again with --resume --unlock", "alarm", executed)

    def _stop_on_abort(self, counter: CharacterCounter) -> StreamResult:
        try:
            executed = self._halt(rejected=None)
        except _Undecided as exc:
            self._stop_undecided(exc, "aborted: ")
        self.journal.record("done", count=executed)
        self.journal.record("stopped", reason="aborted")
        self.journal.commit()
        self._report()
        return StreamResult(False, executed, len(self.program.lines), "aborted", time.monotonic() - self.started,
                            self.bytes_sent, self._machine_elapsed(), self._held_now())

    def _stop_unrecorded(self, failure: JournalError) -> None:
        """The journal cannot be written: stop the machine so that no line runs unrecorded, and name the line to
        resume from, which the journal can no longer tell."""
        if self.journal.failed:
            self.journal.abandon()
        try:
            executed = self._halt(rejected=None)
        except _Undecided as exc:
            self._stop_undecided(exc, f"{failure}; the machine was stopped, but ")
        self.journal.record("done", count=executed)  # dropped when the journal is what failed
        self.journal.record("stopped", reason=f"log failed: {failure}")
        self.journal.commit()
        where = (f"after file line {self._file_line(executed - 1)}" if executed else "before the first line")
        if executed == len(self.program.lines):
            hint = "every line had run"
        elif self.journal.failed:  # the journal no longer knows where the machine stopped: the operator says it
            hint = f"run again with --resume --from-line {self._file_line(executed)}"
        else:
            hint = "run again with --resume"
        raise StreamInterrupted(f"{failure}; the machine was stopped {where}: make room, then {hint}", "journal",
                                executed) from None

    def _stop_undecided(self, exc: _Undecided, cause: str = "") -> None:
        """Journal that the stopped position did not tell the line (a resume must then be told, --from-line)."""
        self.journal.record("stopped", reason=f"undecided: {exc}")
        self.journal.commit()
        raise StreamInterrupted(f"{cause}{exc}", "undecided", self.done) from None

    def _halt(self, rejected: int | None) -> int:
        """Feed hold until the machine stands still, reset to flush its buffers, unlock; return lines executed."""
        status = self._query_status()
        if status.state == "Idle" and not (self._counter and self._counter.in_flight):
            self._soft_reset()  # nothing left that could start: every acknowledged line is done
            return self._executed_from_position(status, True, rejected)
        deadline = time.monotonic() + self.stop_timeout
        while True:
            self._write(FEED_HOLD)  # again each time: a hold asked for while a line was parsing may not have taken
            status = self._query_status()
            if status.state == "Hold" and status.substate == 0:
                status = self._query_status()  # answers the controller sent before this report are read by now
                break
            if status.state in ("Idle", "Alarm", "Check") and not (self._counter and self._counter.in_flight):
                break
            if time.monotonic() > deadline:
                self._soft_reset()
                raise StreamInterrupted(f"{self.url}: the machine did not stop within {self.stop_timeout:g} s of a feed "
                                        f"hold (it reported {status.state}), so it was reset; check the part and "
                                        "resume with --from-line", "error", self.done)
            time.sleep(0.02)
        self._soft_reset()  # first, so the machine is never left in a hold whatever the verdict
        return self._executed_from_position(status, status.state == "Idle", rejected)

    def _executed_from_position(self, status: StatusReport, planner_empty: bool, rejected: int | None = None) -> int:
        """Lines executed when the machine stopped at `status` with its planner flushed: the executing line is one
        of the window of lines that can still have been in the planner (`_window`), the one whose path holds
        the stopped position; `Ln:` names it where the build reports it. Raises _Undecided when no line or
        several lines of the window fit the position."""
        acked = self.acked
        if planner_empty:
            return rejected if rejected is not None else acked
        if status.line_number is not None and status.state in ("Run", "Hold"):
            index = self._index_of_file_line(status.line_number, strict=False)
            if index is not None and self.done <= index <= self.sent:
                return index if rejected is None else min(index, rejected)
        position = status.work_position(self._wco)
        counts = self._counts_at(position)
        if rejected is not None:
            beyond = sorted(count for count in counts if count > rejected)
            if beyond:
                raise _Undecided(f"{self.url}: the controller ran file line {self._file_line(beyond[0])}, past the "
                                 f"rejected line {self.program.lines[rejected].file_line}; check the part and resume "
                                 "with --from-line")
            if not counts:
                return rejected
        if len(counts) == 1:
            return counts.pop()
        where = ", ".join(f"{v:.3f}" for v in position)
        if not counts:
            raise _Undecided(f"{self.url}: cannot tell which line the machine stopped in (work position {where}, "
                             f"none of file lines {self._file_line(self._window()[0])}.."
                             f"{self._file_line(self.sent - 1)} passes there); check the part and resume with "
                             "--from-line")
        lines = [str(self._file_line(count)) if count < len(self.program.lines) else "the end" for count in sorted(counts)]
        raise _Undecided(f"{self.program.name}: the machine stopped at {where}, where the path passes more than once "
                         f"(file lines {', '.join(lines)} can have been cutting); look at the part and resume with "
                         f"--resume --from-line N, N the first line not yet cut (one of {', '.join(lines)})")

    def _window(self) -> tuple[int, int]:
        """The lines that can have been executing: back from the last acknowledged line by at most the planner's
        size plus the stepper's segment buffer in motion lines (a motion takes at least one planner block, and
        leaves the planner once prepared into segments, before it has run), up to the last line sent."""
        rejected = {index for index, _ in self._errors}
        low, motions, room = self.acked, 0, self.build.planner_blocks + SEGMENT_BUFFER
        while low > self.done:
            if self.blocks[low - 1].segment is not None and low - 1 not in rejected:
                if motions == room:
                    break
                motions += 1
            low -= 1
        return low, min(max(self.sent, self.acked), len(self.blocks))

    def _counts_at(self, position: Vector) -> set[int]:
        """Every count of executed lines the stopped `position` fits: strictly inside motion line m (m lines done), or
        at rest between motion lines p and q (p + 1 done, and the lines between them that were acknowledged)."""
        low, high = self._window()
        motions = [index for index in range(low, high) if self._moves(index)]
        before = next((index for index in range(low - 1, -1, -1) if self._moves(index)), None)
        counts = set()
        rest = self.origin if before is None else self.blocks[before].segment.end
        following = motions + [len(self.blocks)]
        if math.dist(position, rest) <= POSITION_TOLERANCE:
            counts.add(min(max(self.acked, (before if before is not None else -1) + 1), following[0]))
        for number, index in enumerate(motions):
            segment = self.blocks[index].segment
            if math.dist(position, segment.end) <= POSITION_TOLERANCE:
                counts.add(min(max(self.acked, index + 1), following[number + 1]))
            elif (math.dist(position, segment.start) > POSITION_TOLERANCE
                  and segment.contains(position, POSITION_TOLERANCE)):
                counts.add(index)
        return {count for count in counts if count >= self.done}

    def _moves(self, index: int) -> bool:
        segment = self.blocks[index].segment
        return segment is not None and segment.length > POSITION_TOLERANCE

    # ----- resuming -------------------------------------------------------------------------------------
    def _recover(self, previous: JournalState, unlock: bool) -> int:
        """Bring a controller left by an interrupted job to Idle and return how many lines it executed."""
        status = self._settle()
        if status.state == "Alarm" and not unlock:
            raise FablineError(f"{self.url}: the controller is in alarm; check the machine, then resume with --unlock")
        stopped = previous.stopped or ""
        if stopped.startswith("undecided"):
            raise _Undecided(f"{self.journal_path}: the last run stopped where fabline could not tell the line "
                             f"({stopped[len('undecided: '):]})")
        if stopped.startswith(("error", "aborted", "ALARM", "log failed")):  # the host that stopped it judged what ran
            executed = previous.done
        elif status.state == "Hold" and not stopped.startswith("controller reset"):
            # held when its host went away: let it finish what it holds (the operator asked to resume), then ask $G
            self._exchange("#", "cycle start: the controller was held by an interrupted run")
            self._write(CYCLE_START)
            deadline = time.monotonic() + max(self.connect_timeout, 2.0)
            while self._query_status().state == "Hold" and time.monotonic() < deadline:
                time.sleep(0.02)
            status = self._settle()
            if status.state == "Idle":
                return self._parsed_count(previous)
            executed = self._executed_from_position(status, planner_empty=False)
        elif status.state in ("Alarm", "Hold") or stopped.startswith("controller reset"):
            executed = self._executed_from_position(status, planner_empty=False)
        elif status.state == "Idle":
            return self._parsed_count(previous)
        else:
            raise FablineError(f"{self.url}: the controller is in state {status.state}; it must be Idle to resume")
        if status.state in ("Alarm", "Hold"):
            self._soft_reset(unlock=True)
        return executed

    def _parsed_count(self, previous: JournalState) -> int:
        """Lines executed by an Idle controller that finished everything it parsed: its `$G` tag names the last
        line parsed, looked up only among the lines the journal shows sent after its last `ok` (sent records reach
        the disk before their line reaches the port, so no other line can have been parsed), and the controller
        must stand where the program is after that line. Anything else means the journal lost records (or the
        machine was moved): refused, naming what the journal knows, for the operator's --from-line."""
        self._flush_partial_line()
        modes = self._command(b"$G\n")
        status = self._settle()  # lines still in its receive buffer when it looked idle were parsed before `#`
        tag = next((int(match.group(1)) for text in modes if (match := _TAG.search(text))), None)
        low = previous.acked - 1
        high = max(min(previous.sent, low + TAG_CYCLE, len(self.program.lines)), previous.acked)
        count = next((index + 1 for index in range(low, high) if line_tag(index) == tag), None)
        if count is None:
            sent = f"file line {self._file_line(previous.sent - 1)}" if previous.sent else "no line"
            self._refuse_unproven(previous, "its parser tag is T0 (it was reset, or a line without a tag was sent to it)" if tag == 0 else
                                  f"its parser tag T{tag} names no line the journal shows sent (the last one sent: "
                                  f"{sent}; records lost from the journal's end?)")
        here = status.work_position(self._wco)
        if here is not None and not any(block.stored_reference for block in self.blocks[:count]):
            there = self._position_after(count)
            if math.dist(here[:3], there) > POSITION_TOLERANCE:
                self._refuse_unproven(previous, f"its parser tag T{tag} fits file line {self._file_line(count - 1)}, "
                                                f"but it stands at {_where(here[:3])}, not at {_where(there)} where the "
                                                "program is after that line (records lost from the journal, or the "
                                                "machine was moved)")
        return count

    def _refuse_unproven(self, previous: JournalState, why: str) -> None:
        """The journal cannot prove where the controller stopped: one line naming the last line it knows executed."""
        known = f"file line {self._file_line(previous.done - 1)}" if previous.done else "no line"
        raise FablineError(f"{self.journal_path}: cannot tell how far the controller got: {why}; the journal knows "
                           f"{known} executed: check the part and continue by hand with --resume --from-line N, N the "
                           "first line not yet cut")

    def _stop_where_it_is(self, unlock: bool) -> None:
        """For an operator's --from-line: wait for the controller to finish or stand still, then drop whatever it
        holds (a hold or an alarm is reset), so only the chosen line and what follows run."""
        status = self._settle()
        if status.state == "Alarm" and not unlock:
            raise FablineError(f"{self.url}: the controller is in alarm; check the machine, then resume with --unlock")
        if status.state in ("Alarm", "Hold"):
            self._soft_reset(unlock=True)
        elif status.state == "Idle":
            self._flush_partial_line()
        else:
            raise FablineError(f"{self.url}: the controller is in state {status.state}; it must be Idle to resume")

    def _preamble(self, executed: int) -> list[bytes]:
        """Commands that restore the modal state after `executed` lines and move safely to the restart point."""
        if executed >= len(self.program.lines):
            return []
        self._refuse_stored_references(executed)
        modal = self.blocks[executed - 1].modal if executed else ModalState()
        target = self._position_after(executed)
        lines = ["G21G90G17G94M5", f"{modal.coord}"]
        status = self._query_status()
        here = status.work_position(self._wco) or target
        if not all(math.isclose(a, b, abs_tol=1e-4) for a, b in zip(here, target)):
            top = max(here[2], target[2])
            lines += [f"G0Z{top:.4f}"] if top > here[2] else []
            lines += [f"G0X{target[0]:.4f}Y{target[1]:.4f}"]
            lines += [f"G0Z{target[2]:.4f}"] if top > target[2] else []
        lines += [f"{modal.plane}{modal.units}{modal.distance}{modal.feed_mode}{modal.coolant}",
                  f"F{modal.feed:g}S{modal.speed:g}{modal.spindle}"]
        if modal.motion == "G0" or (modal.motion == "G1" and modal.feed > 0):
            lines.append(modal.motion)
        elif modal.motion in ("G2", "G3"):
            self._refuse_modal_arc(executed, modal.motion)
        lines.append(f"T{line_tag(executed - 1)}")
        return [f"{line}\n".encode("ascii") for line in lines]

    def _refuse_stored_references(self, executed: int) -> None:
        """Positions after a work offset change (G10, G92, G43.1) or a move to a stored or machine position (G28,
        G30, G53, G38.x) depend on what the controller stores: refuse a restart after such a line."""
        for index, block in enumerate(self.blocks[:executed]):
            if block.stored_reference:
                raise FablineError(
                    f"{self.program.name}:{self.program.lines[index].file_line}: cannot resume after this line: "
                    f"{block.stored_reference} depends on offsets or positions stored in the controller, which a "
                    "resume cannot re-establish; start the sheet over with --restart")

    def _refuse_modal_arc(self, executed: int, motion: str) -> None:
        """An arc mode cannot be restored without a target: refuse if the next move relies on it."""
        for line in self.program.lines[executed:]:
            if _MOTION_WORD.search(line.command):
                return
            if re.search(r"[XYZ]", line.command):
                raise FablineError(f"{self.program.name}:{line.file_line}: cannot restart before this line: it relies on "
                                   f"modal {motion}; resume with --from-line at a line with its own G word")

    def _position_after(self, executed: int) -> Vector:
        for block in reversed(self.blocks[:executed]):
            if block.segment is not None:
                return block.segment.end
        return self.origin

    # ----- connection -------------------------------------------------------------------------------------
    def _open(self) -> None:
        """Open the port and make sure a GRBL 1.1 controller answers; only then start the exchange log."""
        self._connect_port()
        self._detect()
        if self.exchange_log_path is not None:
            new_log = not Path(self.exchange_log_path).exists()
            try:
                self._log = open_append(self.exchange_log_path, "exchange log", errors="replace")
                self._exchange("#", f"connected to {self.url}: Grbl {self.version or '1.1'}, rx buffer {self.rx_buffer}")
            except FablineError:
                self._close_port()
                if new_log and self._log is None:  # created here and not even its first record went in
                    Path(self.exchange_log_path).unlink(missing_ok=True)
                raise

    def _connect_port(self) -> None:
        try:
            port = serial.serial_for_url(self.url, do_not_open=True, baudrate=self.baud, timeout=0.01,
                                         write_timeout=10)
            if "://" not in self.url:
                port.exclusive = True
            port.open()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise FablineError(f"port {self.url}: cannot open: {exc}") from None
        self._port = port
        self._splitter.clear()
        self._exchange("#", f"opened {self.url}")

    def _detect(self) -> None:
        """Wake the controller and wait for a banner or a status report; read its build options and settings."""
        deadline = time.monotonic() + self.connect_timeout
        self.status = None
        while self.status is None:
            if time.monotonic() > deadline:
                raise FablineError(f"port {self.url}: no GRBL answer within {self.connect_timeout:g} s "
                                   "(not a GRBL controller, wrong port or wrong baud rate?)")
            self._write(STATUS_QUERY)
            end = time.monotonic() + 0.25
            while time.monotonic() < end and self.status is None:
                for response in self._read(0.05):
                    if response.kind == "banner":
                        self.version = response.text
                    elif response.kind == "status":
                        self.status = response.status
        if self.status.state == "Check":  # left by a host that died during --check: nothing ran, leave it
            self._flush_partial_line()
            self._command(b"$C\n", until_banner=True)
            self.status = self._query_status()
        if self.status.state == "Idle":  # a critical alarm ignores everything but a reset
            self._flush_partial_line()
            self._read_build_info()

    def _read_build_info(self) -> None:
        """The build from `$I` (buffer sizes, `Ln:` or not, M7 or not) and the settings from `$$`."""
        feedback = self._command(b"$I\n")
        self.build = BuildInfo.parse(feedback)
        if not any(text.startswith("OPT:") for text in feedback):
            self._exchange("#", "no [OPT:...] in $I: assuming a stock build")
        if not self.build.version.startswith("1.1"):
            raise FablineError(f"port {self.url}: GRBL {self.build.version} found; fabline streams to GRBL 1.1")
        self.rx_buffer = self.build.rx_buffer
        for text in self._command(b"$$\n"):
            key, _, value = text.partition("=")
            try:
                self.settings[int(key[1:])] = float(value)
            except ValueError:
                continue

    def _reconnect(self) -> bool:
        """Try to reopen the port for `reconnect_timeout` seconds (a USB cable plugged back in)."""
        self._close_port()
        deadline = time.monotonic() + self.reconnect_timeout
        while time.monotonic() < deadline:
            try:
                self._connect_port()
                self._detect()
                self._exchange("#", "reconnected")
                return True
            except FablineError:
                self._close_port()
                time.sleep(0.2)
        return False

    def _close_port(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None

    def _close(self) -> None:
        self._close_port()
        if self._log is not None:
            self._log.close()
            self._log = None

    def _fresh_start(self, unlock: bool) -> None:
        """A new job needs an idle controller; a soft reset clears any half-received line and the tag."""
        status = self._query_status()
        if status.state not in ("Idle", "Alarm"):
            raise FablineError(f"{self.url}: the controller is busy ({status.state}); wait for it or reset it")
        if status.state == "Alarm" and not unlock:
            raise FablineError(f"{self.url}: the controller is in alarm; home it or unlock it (--unlock) first")
        self._soft_reset(unlock=unlock)

    def _check_mode(self) -> None:
        """Run the whole program through GRBL check mode ($C) and list every line the controller refuses."""
        self._command(b"$C\n")
        counter = CharacterCounter(self.rx_buffer)
        lines, position, answered, failures = self.program.lines, 0, 0, []
        self._last_heard = time.monotonic()
        while counter.in_flight or position < len(lines):
            batch = []
            while position < len(lines) and counter.fits(len(lines[position].wire)):
                counter.sent(position, len(lines[position].wire))
                batch.append(lines[position].wire)
                position += 1
            if batch:
                self._write(b"".join(batch))
            for response in self._read(0.01):
                if response.kind in ("ok", "error"):
                    index = counter.answered()
                    answered += 1
                    if response.kind == "error":
                        failures.append((index, response.code))
            if time.monotonic() - self._last_heard > self.silence_timeout:
                raise FablineError(f"{self.url}: check mode: no answer for {self.silence_timeout:g} s after "
                                   f"{answered} of {len(lines)} lines")
        self._command(b"$C\n", until_banner=True)
        problems = [f"{self.program.name}:{lines[index].file_line}: check mode: {explain_error(code)}: "
                    f"{lines[index].source.strip()}" for index, code in failures]
        if problems:
            raise FablineError(listing(problems, f"check mode: the controller refuses {len(problems)} lines"))

    # ----- low-level exchange ----------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise _Lost(str(exc)) from None
        self.bytes_sent += len(data)
        if data != STATUS_QUERY:
            self._exchange(">>>", data.decode("ascii", errors="replace").replace("\x18", "<ctrl-x>").rstrip("\n")
                           .replace("\n", "\n>>> "))

    def _read(self, timeout: float) -> list[Response]:
        """Classified lines that arrived within about `timeout` seconds."""
        try:
            if self._port.timeout != timeout:  # setting it reconfigures a real tty: only when it changes
                self._port.timeout = timeout
            data = self._port.read(max(1, self._port.in_waiting))
            if self._port.in_waiting:
                data += self._port.read(self._port.in_waiting)
        except (serial.SerialException, OSError) as exc:
            raise _Lost(str(exc)) from None
        if data:
            self._last_heard = time.monotonic()
        responses = []
        for text in self._splitter.feed(data):
            response = classify(text)
            if response.kind != "status":
                self._exchange("<<<", text)
            counter = self._counter
            if response.kind in ("ok", "error") and counter is not None and counter.in_flight:
                self._answered(response)
            elif response.kind == "status":
                self.status = response.status
                if response.status.wco is not None:
                    self._wco = response.status.wco
                if counter is not None:
                    self._track_status(response.status, counter)
            responses.append(response)
        return responses

    def _send_realtime(self) -> None:
        with self._control:
            pending, self._realtime = self._realtime, []
        for byte in pending:
            self._write(byte)

    def _flush_partial_line(self) -> None:
        """Discard a line a lost connection left half-received: with `#` appended no line parses, so the
        controller answers exactly one error and executes nothing (stray oks of older lines are skipped)."""
        self._read(0.05)
        self._command(_FLUSH_LINE, expect_error=True)

    def _command(self, line: bytes, expect_error: bool = False, until_banner: bool = False) -> list[str]:
        """Send one line with nothing else in flight; return the feedback lines before its ok
        (or, with `expect_error`, before its error). A `$` query refused because the controller is running
        (error:8: lines a lost connection left in its buffer, found idle a moment before) is asked again once
        the controller stands still."""
        self._write(line)
        feedback, answered, waited = [], False, False
        deadline = time.monotonic() + max(self.connect_timeout, 2.0)
        while time.monotonic() < deadline:
            for response in self._read(0.02):
                if response.kind in ("feedback", "setting", "message"):
                    feedback.append(response.text)
                elif response.kind == ("error" if expect_error else "ok"):
                    answered = True
                elif response.kind == "error" and response.code == 8 and line.startswith(b"$") and not waited:
                    self._settle()  # bounded by settle_timeout, with its own message
                    waited, feedback = True, []
                    self._write(line)
                    deadline = time.monotonic() + max(self.connect_timeout, 2.0)
                elif response.kind == "error":
                    raise FablineError(f"{self.url}: {line.decode().strip()!r} answered {explain_error(response.code)}")
                elif response.kind == "banner" and until_banner and answered:
                    return feedback
            if answered and not until_banner:
                return feedback
        raise FablineError(f"{self.url}: no answer to {line.decode().strip()!r} within {max(self.connect_timeout, 2.0):g} s")

    def _query_status(self) -> StatusReport:
        """Ask for one status report and wait for it."""
        deadline = time.monotonic() + max(self.connect_timeout, 2.0)
        while time.monotonic() < deadline:
            self._write(STATUS_QUERY)
            end = time.monotonic() + 0.25
            while time.monotonic() < end:
                for response in self._read(0.02):
                    if response.kind == "status":
                        return response.status
        raise FablineError(f"{self.url}: the controller stopped answering status queries")

    def _settle(self) -> StatusReport:
        """Wait until the controller has finished what it was given (Idle, Alarm or a stop), its work position known."""
        deadline = time.monotonic() + self.settle_timeout
        while True:
            status = self._query_status()
            settled = status.state in ("Idle", "Alarm", "Check") or (status.state == "Hold" and status.substate == 0)
            if settled and (self._wco is not None or status.wpos is not None):
                return status
            if time.monotonic() > deadline:
                raise FablineError(f"{self.url}: the controller is still {status.state} after {self.settle_timeout:g} s "
                                   "of waiting for it to finish its buffered moves; stop it (reset), check the part "
                                   "and resume with --from-line")
            time.sleep(self.status_interval if not settled else 0.02)

    def _work_position(self) -> Vector:
        """The controller's work position now: where a new run's motion starts."""
        deadline = time.monotonic() + max(self.connect_timeout, 2.0)
        while time.monotonic() < deadline:
            status = self._query_status()
            position = status.work_position(self._wco) if (self._wco or status.wpos) else None
            if position is not None and len(position) >= 3:
                return tuple(float(v) for v in position[:3])
            time.sleep(0.02)
        raise FablineError(f"{self.url}: the controller reports no work position (no WCO in its status reports)")

    def _soft_reset(self, unlock: bool = True) -> None:
        """Ctrl-X: flush buffers and parser state; unlock the ALARM:3 a reset during a hold causes."""
        self._write(SOFT_RESET)
        if self._counter is not None:
            self._counter.clear()
            self._counter = None
        alarm, deadline = None, time.monotonic() + max(self.connect_timeout, 2.0)
        banner = False
        while not banner:
            if time.monotonic() > deadline:
                raise FablineError(f"{self.url}: no banner after a soft reset")
            for response in self._read(0.05):
                if response.kind == "banner":
                    banner = True
                elif response.kind == "alarm":
                    alarm = response.code
        time.sleep(0.05)
        self._read(0.02)
        status = self._query_status()
        if status.state == "Alarm" and unlock:
            self._command(b"$X\n")
            self._exchange("#", f"unlocked after {explain_alarm(alarm) if alarm else 'alarm'}")

    # ----- reporting ----------------------------------------------------------------------------------
    def _held_now(self) -> float:
        """Wall seconds held waiting for the operator so far in this run, a hold in progress included."""
        with self._control:
            since = self._held_since
            return self.held + (time.monotonic() - since if since is not None else 0.0)

    def _machine_clock(self) -> float | None:
        """The controller's own clock (seconds), where the port has one (`sim://`); None for a real machine."""
        clock = getattr(self._port, "machine_time", None)
        return float(clock) if isinstance(clock, (int, float)) else None

    def _machine_elapsed(self) -> float:
        """Machine time of this run so far: the controller's clock since the stream began, or for a real machine
        (no clock of its own) the wall time less the time held."""
        clock = self._machine_clock()
        if clock is not None and self._machine_start is not None:
            return max(clock - self._machine_start, 0.0)
        return max(time.monotonic() - self.started - self._held_now(), 0.0)

    def _report(self) -> None:
        """Tell `on_progress` where the job stands (the stream loop decides how often)."""
        if self.on_progress is None:
            return
        total = len(self.program.lines)
        elapsed = time.monotonic() - self.started - self._held_now()  # waiting for the operator is not work
        timeline = self.timeline()
        planned = timeline[-1] - self._planned_at(self.first_index)
        eta = estimate(planned, self._planned_at(self.acked) - self._planned_at(self.first_index), elapsed)
        remaining = eta.remaining
        status = self.status
        whole = float(timeline[-1]) if len(timeline) else 0.0
        percent = 100.0 * (self._planned_at(self.acked) / whole if whole > 0 else self.acked / total)
        self.on_progress(Progress(
            acked=self.acked, total=total, percent=percent, state=status.state if status else "?",
            position=status.work_position(self._wco) if status else None, elapsed=elapsed,
            remaining=remaining, file_line=self._file_line(self.acked - 1) if self.acked else None,
            message=self.message, eta=eta))

    def timeline(self):
        """Planned seconds (on this machine: a simulator's time scale applied) from the start of the program to the
        end of each line, from the controller's own settings; computed once per run."""
        if self._timeline_for is not self.blocks:
            from fabline.machine.motion import line_timeline
            from fabline.link.simulator import DEFAULT_SETTINGS

            settings = {**DEFAULT_SETTINGS, **self.settings}
            self._timeline = line_timeline(self.blocks, settings, self.build.planner_blocks) / simulated_speedup(self.url)
            self._timeline_for = self.blocks
        return self._timeline

    def _planned_at(self, count: int) -> float:
        """Planned seconds to the end of the first `count` lines."""
        return float(self._timeline[count - 1]) if count > 0 else 0.0

    def _exchange(self, direction: str, text: str) -> None:
        """Append to the exchange log; a log that cannot be written is closed and raised as a JournalError."""
        if self._log is not None:
            try:
                self._log.write(f"{time.time():.3f} {direction} {text}\n")
                self._log.flush()
            except OSError as exc:
                log, self._log = self._log, None
                try:
                    log.close()
                except OSError:
                    pass  # its buffer cannot be written either
                raise JournalError(f"{self.exchange_log_path}: cannot write the exchange log: "
                                   f"{exc.strerror or exc}") from None

    def _file_line(self, index: int) -> int | None:
        lines = self.program.lines
        return lines[min(max(index, 0), len(lines) - 1)].file_line if lines else None

    def _index_of_file_line(self, file_line: int, strict: bool = True) -> int | None:
        for line in self.program.lines:
            if line.file_line >= file_line:
                if line.file_line == file_line or not strict:
                    return line.index
                break
        if strict:
            raise FablineError(f"{self.program.name}:{file_line}: no G-code command on that line to restart from")
        return None
