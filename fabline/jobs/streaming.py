"""One sheet's program streamed through the link stage's Streamer, with a journal of the run.

Where the journal lives and whether a run resumes it is the caller's decision, never the file system's:
`fabline run` keeps journals beside the programs and resumes only with `--resume`; the runner gives every
run of a sheet a journal of its own and resumes only when the operator chooses to. A resumed journal that
says the sheet is finished sends nothing. `pause`, `resume` and `cancel` may be called from another thread
while `run` streams. `stream_in_process` runs one sheet in a process of its own (the main job's machines
stream in parallel).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Callable

from fabline.errors import FablineError
from fabline.link import STOP_SIGNALS, Progress, Streamer, default_journal_path, read_journal
from fabline.machine import load_program
from fabline.progress import Eta, simulated_speedup

OnProgress = Callable[[int, "tuple[float, ...] | None", "str | None"], None]


class SheetStream:
    """Stream `program` to `port`; `on_progress(lines done, work position, message)` is called as lines complete
    (`message` is set while the program waits for the operator, e.g. after an M0). `identity` names the run
    in its journal (the link stage refuses to resume a journal of another run)."""

    def __init__(self, port: str, program: str | os.PathLike, on_progress: OnProgress,
                 journal: str | os.PathLike | None = None, resume: bool = False, from_line: int | None = None,
                 identity: dict[str, str] | None = None):
        self.port = port
        self.identity = identity
        self.program_path = Path(program)
        self.journal_path = Path(journal) if journal else default_journal_path(self.program_path)
        self.resume_journal = resume
        self.from_line = from_line
        self.on_progress = on_progress
        self.streamer = Streamer(port)
        self.cancelled = False
        self.closed = threading.Event()
        self.executed = 0
        self.total = 0
        self.resumed_from: int | None = None
        self.earlier = False
        """The journal says an earlier run finished the sheet: nothing was sent in this run."""
        self.result = None
        self.eta: Eta | None = None
        """The last progress report's time: elapsed, remaining, the planned seconds (see `fabline.progress`)."""

    def run(self) -> str:
        """Stream to the end: 'finished', or 'aborted' after `cancel()`/`stop()` (the journal resumes the rest).
        Without `resume` the sheet starts at its first line whatever journal is left; with it, the run continues
        its journal (from `from_line` if given; from the first line if the run never got as far as a journal).
        An error, alarm or lost connection raises the link stage's StreamInterrupted (a FablineError)."""
        program = load_program(self.program_path)
        self.total = len(program.lines)
        previous = read_journal(self.journal_path) if self.resume_journal and self.journal_path.is_file() else None
        if previous is not None and previous.sha256 == program.sha256 and previous.finished:
            self.executed, self.earlier = self.total, True
            self.on_progress(self.total, None, None)
            return "finished"
        resume = previous is not None
        if self.from_line is not None and not resume:
            raise FablineError(f"{self.program_path.name}: no journal of this run to resume from line {self.from_line}; "
                               "restart the sheet instead")
        self.resumed_from = previous.done if resume else None

        def progress(report: Progress) -> None:
            self.executed, self.eta = report.acked, report.eta or self.eta
            self.on_progress(report.acked, report.position, report.message)

        result = self.streamer.run(program, on_progress=progress, journal=self.journal_path, resume=resume,
                                   start_line=self.from_line, restart=not resume, identity=self.identity)
        self.executed, self.result = result.executed, result
        self.on_progress(result.executed, None, None)
        return "finished" if result.completed else "aborted"

    def pause(self) -> None:
        """Feed hold."""
        self.streamer.pause()

    def resume(self) -> None:
        """Cycle start after a pause."""
        self.streamer.resume()

    def cancel(self) -> None:
        """Stop the sheet for good (feed hold, reset)."""
        self.cancelled = True
        self.streamer.abort()

    def override(self, name: str) -> None:
        """A real-time override while the sheet streams ('feed +10%', 'power -10%': `fabline.link.protocol.OVERRIDES`)."""
        self.streamer.override(name)

    def stop(self) -> None:
        """Stop now because the runner stops; the sheet resumes from its journal on the next start."""
        self.streamer.abort()

    def summary(self) -> dict:
        """The streaming log's figures for the report: lines, and in machine seconds the planner's time for the program
        (`planned_s`), for the lines done (`planned_done_s`) and for those done before this run (`planned_before_s`),
        and `machine_s`, the machine time this run took by the controller's clock (see `StreamResult.machine`).
        `earlier`: an earlier run had finished the sheet, so this one sent nothing and took no time."""
        summary = {"port": self.port, "lines": self.total, "executed": self.executed, "journal": str(self.journal_path),
                   "resumed_from": self.resumed_from, "earlier": self.earlier}
        if self.result is not None and self.result.machine is not None:
            summary.update(machine_s=round(self.result.machine, 1), held_s=round(self.result.held, 1))
        timeline = self.streamer.timeline() if getattr(self.streamer, "blocks", None) is not None else None
        if timeline is not None and len(timeline):  # machine seconds (a simulator's time scale undone)
            speedup = simulated_speedup(self.port)

            def at(count: int) -> float:
                return round(float(timeline[count - 1]) * speedup, 1) if count else 0.0
            summary.update(planned_s=at(len(timeline)), planned_done_s=at(self.executed),
                           planned_before_s=at(self.resumed_from or 0))
        return summary


PROGRESS_INTERVAL = 0.2
"""Seconds between the progress messages a sheet's process sends to `fabline run`."""


class StopOnce:
    """A stop signal's handler that stops once: a stop comes twice (the process group's SIGTERM and `fabline run`'s
    SIGINT to each link), and a second handler run inside the first, while it holds the abort event's lock, waited on
    that lock for ever (seen: a link process hung after its sheet's abort line)."""

    def __init__(self, stop) -> None:
        self.stop, self.stopping = stop, False

    def __call__(self, signum=None, frame=None) -> None:
        if self.stopping:
            return
        self.stopping = True
        self.stop()


def stream_in_process(port: str, program: str, resume: bool, identity: dict[str, str], connection,
                      from_line: int | None = None) -> None:
    """Process target: stream one sheet (continuing its journal with `resume`, from file line `from_line` if
    given), stop it safely on any of
    STOP_SIGNALS (feed hold, reset, journal kept). Sends ("progress", lines done, lines, Eta or None) through
    `connection` at most every PROGRESS_INTERVAL s, then ("result", outcome in words, summary).
    A program pause (M0) is said on standard error; SIGUSR1 continues it (cycle start)."""
    shown: list[str | None] = [None]
    sent = [0.0]

    def progress(done: int, position, message: str | None) -> None:
        if message and message != shown[0]:
            print(f"{Path(program).name}: {message} (send SIGUSR1 to process {os.getpid()})", file=sys.stderr, flush=True)
        shown[0] = message
        now = time.monotonic()
        if now - sent[0] >= PROGRESS_INTERVAL:
            sent[0] = now
            connection.send(("progress", done, stream.total, stream.eta))

    stream = SheetStream(port, program, progress, resume=resume, from_line=from_line, identity=identity)
    stop = StopOnce(stream.stop)
    for number in STOP_SIGNALS:
        signal.signal(number, stop)
    signal.signal(signal.SIGUSR1, lambda signum, frame: stream.resume())
    signal.pthread_sigmask(signal.SIG_UNBLOCK, set(STOP_SIGNALS))  # blocked by the parent until the handlers are in place
    try:
        outcome = stream.run()
    except FablineError as exc:
        outcome = f"stopped: {exc}"
    connection.send(("result", outcome, stream.summary()))


def run_progress(program: str | os.PathLike, identity: dict[str, str]) -> tuple[bool, int] | None:
    """What the journal beside `program` says the run `identity` did with this very program: (finished, its
    command lines); None when the journal holds no run of that identity for it (a sheet this run has not begun,
    though an earlier run of the job may have cut it)."""
    journal = default_journal_path(Path(program))
    if not journal.is_file():
        return None
    try:
        state = read_journal(journal)
        if state.identity != identity:
            return None
        loaded = load_program(program)
    except FablineError:
        return None
    return (state.finished, len(loaded.lines)) if state.sha256 == loaded.sha256 else None


def journal_summary(port: str, program: str | os.PathLike) -> dict:
    """A sheet's streaming summary as its journal tells it, for a link process that died before reporting."""
    journal = default_journal_path(Path(program))
    state = read_journal(journal) if journal.is_file() else None
    return {"port": port, "lines": state.total if state else 0, "executed": state.done if state else 0,
            "journal": str(journal), "resumed_from": state.resumed_at if state else None}


def frame_program(program: str | os.PathLike) -> str:
    """G-code that traces the bounding box of a sheet program's cuts with the laser off (M5, G0 only) and returns
    to work zero, so the operator sees where the sheet is cut before confirming it is loaded right."""
    from fabline.machine.gcode import ModalState

    loaded, name = load_program(program), Path(program).name
    points = [segment.point_at(t) for block in loaded.plan(ModalState(), (0.0, 0.0, 0.0))
              if (segment := block.segment) is not None and not segment.rapid for t in (0.0, 0.25, 0.5, 0.75, 1.0)]
    if not points:
        raise FablineError(f"{name}: no cutting moves to frame")
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    corners = [(min(xs), min(ys)), (max(xs), min(ys)), (max(xs), max(ys)), (min(xs), max(ys)), (min(xs), min(ys))]
    moves = [f"G0 X{x:.3f} Y{y:.3f}" for x, y in corners]
    return "\n".join([f"(frame of {name}: laser off)", "G21 G90 G17 M5", *moves, "G0 X0 Y0", "M2"]) + "\n"


def frame_sheet(port: str, program: str | os.PathLike, folder: str | os.PathLike) -> None:
    """Trace a sheet's outline on the machine at `port` (see frame_program); the frame program and its journal
    are written to `folder`."""
    path = Path(folder) / f"frame-{Path(program).stem}.gcode"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(frame_program(program), encoding="ascii")
    Streamer(port).run(path, restart=True)


def checkpoint(program: str | os.PathLike, journal: str | os.PathLike | None, reason: str) -> dict:
    """Where a stopped sheet stands, for the operator: `reason`, lines known executed (`done`) of `lines` and
    the `file_line` of the last one, lines acknowledged (`acked`, `acked_file_line`), from the run's journal
    (none written yet: nothing was sent)."""
    entry: dict = {"reason": reason, "done": 0, "lines": 0, "file_line": None, "acked": 0, "acked_file_line": None}
    try:
        lines = load_program(program).lines
        entry["lines"] = len(lines)
        if journal and Path(journal).is_file():
            state = read_journal(journal)
            entry["done"], entry["acked"] = state.done, state.acked
            entry["file_line"] = lines[entry["done"] - 1].file_line if entry["done"] else None
            entry["acked_file_line"] = lines[entry["acked"] - 1].file_line if entry["acked"] else None
    except FablineError as exc:
        entry["reason"] = f"{reason}; {exc}"
    return entry


def program_timeline(program: str | os.PathLike):
    """Planned machine seconds from the start of a sheet program to the end of each of its lines, on the machine
    its header names (`; machine grbl-laser ...`; a stock Grbl 1.1h's default settings without one)."""
    from fabline.link.compat import program_machine
    from fabline.link.simulator import DEFAULT_SETTINGS
    from fabline.machine.gcode import ModalState
    from fabline.machine.motion import line_timeline

    loaded = load_program(program)
    profile = program_machine(loaded, None)
    settings = {**DEFAULT_SETTINGS, **(profile.controller_settings() if profile is not None else {})}
    return line_timeline(loaded.plan(ModalState(), (0.0, 0.0, 0.0)), settings)
