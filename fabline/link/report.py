"""What a stream tells its caller: progress as it goes (`Progress`, with the planned timeline and its ETA), how
it ended (`StreamResult`, `StreamInterrupted`), and the machine time it took."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from fabline.errors import FablineError
from fabline.link.connection import Connection
from fabline.link.controller import Grbl
from fabline.link.controls import Controls
from fabline.link.ledger import Ledger
from fabline.progress import Eta, estimate, simulated_speedup


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


class Reporter:
    """Progress and results of one run of `ledger`'s program, timed from `start()` (streaming, not the handshake)."""

    def __init__(self, connection: Connection, controller: Grbl, ledger: Ledger, controls: Controls,
                 on_progress: Callable[[Progress], None] | None):
        self.connection, self.controller, self.ledger, self.controls = connection, controller, ledger, controls
        self.on_progress = on_progress
        self.started = time.monotonic()
        self._machine_start = 0.0
        self._timeline, self._timeline_for = None, None

    def start(self) -> None:
        self.started = time.monotonic()
        self.controls.start(self.started)
        self._machine_start = self.connection.machine_clock()

    def machine_elapsed(self) -> float:
        """Machine time of this run so far: the controller's clock since the stream began, or for a real machine
        (no clock of its own) the wall time less the time held."""
        clock = self.connection.machine_clock()
        if clock is not None and self._machine_start is not None:
            return max(clock - self._machine_start, 0.0)
        return max(time.monotonic() - self.started - self.controls.held_now(), 0.0)

    def result(self, completed: bool, executed: int, reason: str | None) -> StreamResult:
        return StreamResult(completed, executed, len(self.ledger.program.lines), reason,
                            time.monotonic() - self.started, self.connection.bytes_sent, self.machine_elapsed(),
                            self.controls.held_now())

    def report(self) -> None:
        """Tell `on_progress` where the job stands (the stream loop decides how often)."""
        if self.on_progress is None:
            return
        ledger = self.ledger
        total = len(ledger.program.lines)
        elapsed = time.monotonic() - self.started - self.controls.held_now()  # waiting for the operator is not work
        timeline = self.timeline()
        planned = timeline[-1] - self._planned_at(ledger.first_index)
        eta = estimate(planned, self._planned_at(ledger.acked) - self._planned_at(ledger.first_index), elapsed)
        status = self.connection.status
        whole = float(timeline[-1]) if len(timeline) else 0.0
        percent = 100.0 * (self._planned_at(ledger.acked) / whole if whole > 0 else ledger.acked / total)
        self.on_progress(Progress(
            acked=ledger.acked, total=total, percent=percent, state=status.state if status else "?",
            position=status.work_position(self.connection.wco) if status else None, elapsed=elapsed,
            remaining=eta.remaining, file_line=ledger.file_line(ledger.acked - 1) if ledger.acked else None,
            message=self.controls.message, eta=eta))

    def timeline(self):
        """Planned seconds (on this machine: a simulator's time scale applied) from the start of the program to the
        end of each line, from the controller's own settings; computed once per run."""
        blocks = self.ledger.blocks
        if self._timeline_for is not blocks:
            from fabline.link.simulator import DEFAULT_SETTINGS
            from fabline.machine.motion import line_timeline

            settings = {**DEFAULT_SETTINGS, **self.controller.settings}
            self._timeline = (line_timeline(blocks, settings, self.controller.build.planner_blocks)
                              / simulated_speedup(self.connection.url))
            self._timeline_for = blocks
        return self._timeline

    def _planned_at(self, count: int) -> float:
        """Planned seconds to the end of the first `count` lines."""
        return float(self._timeline[count - 1]) if count > 0 else 0.0
