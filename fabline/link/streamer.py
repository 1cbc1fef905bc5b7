"""Stream a G-code program to a GRBL 1.1 controller over any pyserial URL, journaled so nothing is lost.

`Streamer(port).run(program, on_progress=..., journal=...)` is the one entry point the CLI and the job
runner use. It detects the controller, streams with character counting (or send-response), polls
status, stops safely on `error:N`, alarms, an abort or a lost connection, and resumes from the last
line known to be executed after re-establishing the modal state. How it knows what was executed:
  * `ok` means parsed into the planner; a status report `Ln:N` means every line before N is done, and so
    does one whose position is on the first acknowledged line not known done that passes there; Idle with
    nothing in flight means every acknowledged line is done. A line is done only once it has ended.
  * after a lost connection or a killed host it waits for the controller to finish, discards any
    half-received line (`#` + newline always fails to parse) and reads `$G`: its T word is the tag of
    the last line parsed, looked up among the lines the journal shows sent after its last `ok` (a batch's
    `sent` records are flushed before it goes to the port), so lines whose `ok` never arrived (or never
    reached the disk) are settled by the controller itself; its position must be where the program is after
    that line. A tag beyond the journaled sends or a position elsewhere (the journal lost records) is refused.
  * after an alarm or a halt (feed hold + reset) the planner is flushed; the interrupted line is found
    from the stopped position within the window of lines that can still have been in the planner (the
    acknowledged lines back to `planner_blocks` motion lines, or the `Ln:` of builds that report it), and
    it is re-sent from where the machine stands (an arc with its centre offsets from there). In a finished
    hold a full planner (`Bf:`, or a straight move waiting for room) names the held line. A position that
    still fits several lines of the window (a retraced path) is refused, naming the candidate file lines, for
    the operator to choose with --from-line.
  * a host that died during a feed hold: the settings its journal kept are checked, then cycle start lets the
    controller finish what it holds, then `$G`.
Motion is planned from the controller's work position at the start of the run (kept in the journal).
Before the first move the controller's build (`$I`) and settings (`$$`) are checked against the program and
its machine profile (`fabline.link.compat`); the port and the journal are locked for the whole run.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path
from typing import Callable

from fabline.errors import FablineError
from fabline.link.compat import controller_problems, feed_problems, program_machine
from fabline.link.connection import Connection, Lost
from fabline.link.controller import Grbl
from fabline.link.controls import Controls, override_byte
from fabline.link.journal import Journal, JournalError, JournalState, default_journal_path
from fabline.link.ledger import Ledger, Undecided
from fabline.link.ports import check_port
from fabline.link.recovery import Recovery, previous_job
from fabline.link.report import Progress, Reporter, StreamInterrupted, StreamResult
from fabline.link.sender import MODES, Sender, check_mode
from fabline.link.stopping import Stopper
from fabline.locks import exclusive_lock, lock_path
from fabline.machine.build import ANY_BUILD, BuildInfo
from fabline.machine.gcode import ModalState
from fabline.machine.program import Program, load_program

__all__ = ["MODES", "STOP_SIGNALS", "Progress", "StreamInterrupted", "StreamResult", "Streamer"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Ctrl-C, `kill` (a service stop) and a closed terminal: each stops a stream safely (feed hold, reset, journal)."""
COMMIT_INTERVAL = 0.05
"""s between background journal fsyncs while streaming (stops commit at once): at 460 lines/s the journal
lags the controller by far fewer than the 255 lines a `$G` tag can tell apart."""
JOG_WAIT = 60.0
"""Seconds a console line waits for an earlier jog to end (Grbl refuses G-code while it jogs: error:9)."""
HOMING_WAIT = 120.0
"""Seconds a console `$H` waits for its ok: Grbl answers when the homing cycle is over."""


def _checked_identity(identity: dict[str, str] | None) -> dict[str, str] | None:
    """A run identity as the journal keeps it: names and values are text; an empty one is none."""
    if identity is None or identity == {}:
        return None
    if not isinstance(identity, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in identity.items()):
        raise FablineError(f"a run identity maps names to text, such as {{'job': 'pavilion', 'run': '3'}}; got {identity!r}")
    return dict(identity)


class Streamer:
    """A GRBL 1.1 host on one port (`/dev/ttyUSB0`, `socket://host:port`, `rfc2217://...`, `sim://grbl`, ...):
    a `Connection`, the `Grbl` dialect over it, and per run the record of what ran, the sender and the recovery."""

    def __init__(self, port: str, *, baud: int = 115200, mode: str = "counting", status_interval: float = 0.2,
                 connect_timeout: float = 5.0, settle_timeout: float = 600.0, reconnect_timeout: float = 0.0,
                 silence_timeout: float = 10.0, stop_timeout: float = 30.0,
                 exchange_log: str | os.PathLike | None = None):
        if mode not in MODES:
            raise FablineError(f"unknown streaming mode {mode!r}; use one of {', '.join(MODES)}")
        self.url, self.mode = port, mode
        self.status_interval, self.silence_timeout = status_interval, silence_timeout
        self.stop_timeout = stop_timeout
        """s to wait for the machine to stand still after a feed hold (deceleration takes well under one)."""
        self.reconnect_timeout = reconnect_timeout
        self.exchange_log_path = exchange_log
        self.connection = Connection(port, baud=baud, connect_timeout=connect_timeout, settle_timeout=settle_timeout,
                                     status_interval=status_interval, exchange_log=exchange_log)
        self.controller = Grbl(self.connection)
        self.controls = Controls()
        self.ledger: Ledger | None = None
        self.reporter: Reporter | None = None

    # ----- control from any thread -----------------------------------------------------------------
    def pause(self) -> None:
        """Feed hold: the machine decelerates to a stop; streaming continues into the buffers."""
        self.controls.pause()

    def resume(self) -> None:
        """Cycle start after a pause."""
        self.controls.resume()

    def abort(self) -> None:
        """Stop the job safely (feed hold, then reset); the journal allows a later resume."""
        self.controls.aborting.set()

    def override(self, name: str) -> None:
        """A real-time override while a program streams (`OVERRIDES`: 'feed +10%', 'power -1%', ...): the byte
        goes out with the next real-time commands."""
        self.controls.override(name)

    @property
    def paused(self) -> bool:
        """Whether a pause is in effect."""
        return self.controls.paused

    def console(self, lines: list[str], realtime: list[str] = ()) -> list[tuple[str, list[str]]]:
        """An operator's commands to a controller that is not running a program: `realtime` overrides by name,
        then each line (a `$` setting, `$X`, `$H`, a `$J=` jog, `G10 L20 P1 X0 Y0` ...) sent alone and answered
        before the next. Returns (line, the controller's answer lines, ending in `ok` or `error:N (meaning)`)
        per line; an `error` answer does not stop the rest. Refused while the controller runs, jogs or holds."""
        overrides = [override_byte(name) for name in realtime]
        link = self.connection
        with contextlib.ExitStack() as locks:
            link.lock(locks)
            self.controller.open()
            try:
                for byte in overrides:
                    link.write(byte)
                state = link.query_status().state if lines else "Idle"
                deadline = time.monotonic() + JOG_WAIT
                while state == "Jog" and time.monotonic() < deadline:  # an earlier jog still moving: let it end
                    time.sleep(0.05)
                    state = link.query_status().state
                if state not in ("Idle", "Alarm"):
                    raise FablineError(f"{self.url}: the controller is {state}; wait until it is idle")
                return [(line, self._answer(line)) for line in lines]
            finally:
                link.close()

    def _answer(self, line: str) -> list[str]:
        """Send one console line; its feedback lines and the final `ok` or `error:N (meaning)`."""
        link = self.connection
        link.write(line.encode("ascii") + b"\n")
        wait = HOMING_WAIT if line.startswith("$H") else link.answer_wait  # ok comes when homed
        answer, deadline = [], time.monotonic() + wait
        while time.monotonic() < deadline:
            for response in link.read(0.02):
                if response.kind == "ok":
                    return answer + ["ok"]
                if response.kind == "error":
                    return answer + [self.controller.dialect.explain_error(response.code)]
                if response.kind != "status":
                    answer.append(response.text if response.kind != "alarm"
                                  else self.controller.dialect.explain_alarm(response.code))
        raise FablineError(f"{self.url}: no answer to {line!r} within {wait:g} s")

    # ----- what the controller and the last run tell ---------------------------------------------------
    @property
    def build(self):
        return self.controller.build

    @property
    def rx_buffer(self) -> int:
        return self.controller.rx_buffer

    @property
    def blocks(self):
        """The planned program of the last run (None before one)."""
        return self.ledger.blocks if self.ledger is not None else None

    def timeline(self):
        """Planned seconds from the start of the program to the end of each line (`Reporter.timeline`)."""
        return self.reporter.timeline()

    # the transport's own steps, for tests that drive a controller by hand
    def _open(self) -> None:
        self.controller.open()

    def _close(self) -> None:
        self.connection.close()

    def _write(self, data: bytes) -> None:
        self.connection.write(data)

    def _command(self, line: bytes, **kwargs) -> list[str]:
        return self.connection.command(line, **kwargs)

    def _query_status(self):
        return self.connection.query_status()

    @property
    def _log(self):
        return self.connection.log

    @_log.setter
    def _log(self, log) -> None:
        self.connection.log = log

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
        link = self.connection
        with contextlib.ExitStack() as locks:
            link.lock(locks)
            locks.enter_context(exclusive_lock(lock_path(str(self.journal_path)), f"journal {self.journal_path}"))
            previous = previous_job(self.journal_path, program, resume, restart, identity)
            self._parts(program, on_progress)
            self.controller.open()
            try:
                if check:
                    check_mode(link, self.controller, program, self.silence_timeout)
                return self._job(previous, unlock, start_line, identity)
            finally:
                link.close()
                link.listener = None
                self.controls.aborting.clear()  # an abort asked for before or during this run stopped it

    def _parts(self, program: Program, on_progress: Callable[[Progress], None] | None) -> None:
        """This run's record of what ran (listening to the connection), reporter, stopper, sender and recovery."""
        link, controller = self.connection, self.controller
        self.ledger = ledger = Ledger(program, controller)
        link.listener = ledger
        self.reporter = Reporter(link, controller, ledger, self.controls, on_progress)
        self.stopper = Stopper(link, controller, ledger, self.reporter, self.stop_timeout)
        self.sender = Sender(link, controller, ledger, self.controls, self.reporter, self.stopper, mode=self.mode,
                             status_interval=self.status_interval, silence_timeout=self.silence_timeout)
        self.recovery = Recovery(link, controller, ledger, self.journal_path)

    def _job(self, previous: JournalState | None, unlock: bool, start_line: int | None,
             identity: dict[str, str] | None) -> StreamResult:
        """Start or resume the job (checked against the controller first), then stream it, reconnecting and
        recovering after a lost connection."""
        link, ledger = self.connection, self.ledger
        link.bytes_sent = 0
        if previous is None:
            self.controller.ready(unlock)
            origin = link.work_position()
        else:
            origin = previous.origin
            if origin is None and start_line is None:
                raise FablineError(f"{self.journal_path}: the journal does not say where the run started (an older "
                                   "fabline wrote it); resume with --from-line")
            if origin is None:
                origin = link.work_position()
        ledger.origin = origin
        ledger.blocks = self.program.plan(ModalState(), origin, ANY_BUILD)
        problems = self._check_controller() if self.controller.settings else None  # unless found busy or in alarm
        if problems is None and previous is not None and start_line is None:
            self._check_held(previous)
        if previous is None:
            executed = 0
        elif start_line is not None:  # the operator's choice overrides anything the journal would infer
            executed = ledger.index_of_file_line(start_line)
            self.recovery.stop_where_it_is(unlock)
        else:
            ledger.acked, ledger.done, ledger.sent = previous.acked, previous.done, previous.sent
            try:
                executed = self.recovery.recover(previous, unlock)
            except Undecided as exc:
                raise StreamInterrupted(str(exc), "undecided", previous.done) from None
        if problems is None:  # read now that the controller stands still (a held one was first let finish)
            problems = self._check_controller()
        if self.reporter.on_progress is not None:
            self.reporter.timeline()  # before anything moves: it must not delay the stream loop's first answers
        ledger.journal = Journal(self.journal_path, sync_interval=COMMIT_INTERVAL).open(fresh=previous is None)
        try:
            return self._journaled_job(previous, executed, identity, problems)
        finally:
            ledger.journal.close()

    def _journaled_job(self, previous: JournalState | None, executed: int, identity: dict[str, str] | None,
                       forced: list[str]) -> StreamResult:
        """Stream with the journal open, from `executed` lines on; recover in place from a lost connection."""
        program, ledger, journal = self.program, self.ledger, self.ledger.journal
        journal.record("start", program=program.name, sha256=program.sha256, lines=len(program.lines),
                       mode=self.mode, origin=list(ledger.origin), identity=identity,
                       settings={str(number): value for number, value in self.controller.settings.items()},
                       build=self.controller.build.lines())
        if forced:
            journal.record("forced", problems=forced)
            self.connection.exchange("#", "--force: streaming despite: " + "; ".join(forced))
        if previous is not None:
            journal.record("resume", count=executed)
        try:
            journal.commit()
        except JournalError as exc:
            if previous is None:  # a journal begun here holds nothing worth keeping
                journal.close()
                self.journal_path.unlink(missing_ok=True)
            raise JournalError(f"{exc}; nothing was sent") from None
        preamble = self.recovery.preamble(executed) if previous is not None else []
        ledger.at(executed)
        ledger.first_index = executed
        self.reporter.start()  # elapsed counts streaming, not the handshake
        while True:
            try:
                return self.sender.stream(preamble, self.recovery.first_line if preamble else None)
            except JournalError as exc:
                self.stopper.unrecorded(exc)
            except Lost as exc:
                ledger.counter = None  # whatever was in flight is settled by the recovery, not by stray answers
                journal.record("stopped", reason=f"connection lost: {exc}")
                journal.commit()
                if not self.controller.reconnect(self.reconnect_timeout):
                    raise StreamInterrupted(
                        f"{self.url}: connection lost ({exc}) after file line {ledger.file_line(ledger.acked - 1)}; "
                        "run again with --resume", "connection", ledger.done) from None
                state = JournalState(acked=ledger.acked, done=ledger.done, sent=ledger.sent, stopped="connection lost")
                try:
                    executed = self.recovery.recover(state, unlock=False)
                except Undecided as exc:
                    self.stopper.undecided(exc)
                preamble = self.recovery.preamble(executed)
                ledger.at(executed)
                journal.record("resume", count=executed)
                journal.commit()

    def _check_held(self, previous: JournalState) -> None:
        """Before a resume lets a held controller go on: check the settings and build the interrupted run journaled
        (a held Grbl refuses `$$`, and nothing can change them while it holds); refuse when it journaled none."""
        if self.connection.status is None or self.connection.status.state != "Hold":
            return
        if previous.settings:
            self._check_controller(previous.settings, BuildInfo.parse(previous.build or []))
        else:
            raise FablineError(f"{self.url}: the controller is held by the interrupted run, and its settings can be "
                               "checked neither now (Grbl answers $$ only when idle) nor from the journal (an older "
                               "fabline wrote it): check the part, then resume with --resume --from-line N")

    def _check_controller(self, settings: dict[int, float] | None = None, build: BuildInfo | None = None) -> list[str]:
        """Refuse a controller whose build or settings conflict with the program or its profile (one line naming the
        setting and the fix), unless `force`; return the problems forced past. Capped feeds that only run slower
        are noted in the exchange log."""
        controller = self.controller
        if settings is None and not controller.settings:  # not read when the controller was found in alarm or busy
            controller.read_build_info()
        settings, build = settings or controller.settings, build or controller.build
        problems = controller_problems(self.program, self.ledger.blocks, self.ledger.origin, settings, build,
                                       self.profile, self.connection.wco, controller.dialect)
        for note in feed_problems(self.program, self.ledger.blocks, settings)[1]:
            self.connection.exchange("#", f"note: {note}")
        if problems and not self.force:
            more = f" (and {len(problems) - 1} more conflict{'s' if len(problems) > 2 else ''})" if len(problems) > 1 else ""
            raise FablineError(f"{problems[0]}{more}; nothing was sent (--force streams anyway)")
        return problems
