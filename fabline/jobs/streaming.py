"""One sheet's program streamed through the link stage's Streamer, resumed from its journal when one is left.

The journal lives beside the program (`<program>.journal`); a sheet whose journal is unfinished is
resumed (nothing repeated, nothing skipped), one whose journal says finished is not sent again.
`pause`, `resume` and `cancel` may be called from another thread while `run` streams.
`stream_in_process` runs one sheet in a process of its own (the main job's machines stream in parallel).
"""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path
from typing import Callable

from fabline.errors import FablineError
from fabline.link import Progress, Streamer, default_journal_path, load_program, read_journal

OnProgress = Callable[[int, "tuple[float, ...] | None"], None]


class SheetStream:
    """Stream `program` to `port`; `on_progress(lines done, work position)` is called as lines complete."""

    def __init__(self, port: str, program: str | os.PathLike, on_progress: OnProgress):
        self.port = port
        self.program_path = Path(program)
        self.journal_path = default_journal_path(self.program_path)
        self.on_progress = on_progress
        self.streamer = Streamer(port)
        self.cancelled = False
        self.closed = threading.Event()
        self.executed = 0
        self.total = 0
        self.resumed_from: int | None = None

    def run(self) -> str:
        """Stream to the end: 'finished', or 'aborted' after `cancel()`/`stop()` (the journal resumes the rest).
        An error, alarm or lost connection raises the link stage's StreamInterrupted (a FablineError)."""
        program = load_program(self.program_path)
        self.total = len(program.lines)
        previous = read_journal(self.journal_path) if self.journal_path.is_file() else None
        if previous is not None and previous.sha256 == program.sha256 and previous.finished:
            self.executed = self.total
            self.on_progress(self.total, None)
            return "finished"
        resume = previous is not None and previous.sha256 == program.sha256 and previous.total > 0
        if previous is not None and not resume:
            self.journal_path.unlink()  # a journal of an earlier version of this file: start afresh
        self.resumed_from = previous.done if resume else None

        def progress(report: Progress) -> None:
            self.executed = report.acked
            self.on_progress(report.acked, report.position)

        result = self.streamer.run(program, on_progress=progress, journal=self.journal_path, resume=resume)
        self.executed = result.executed
        self.on_progress(result.executed, None)
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

    def stop(self) -> None:
        """Stop now because the runner stops; the sheet resumes from its journal on the next start."""
        self.streamer.abort()

    def summary(self) -> dict:
        """The streaming log's figures for the report."""
        return {"port": self.port, "lines": self.total, "executed": self.executed, "journal": str(self.journal_path),
                "resumed_from": self.resumed_from}


def stream_in_process(port: str, program: str, connection) -> None:
    """Process target: stream one sheet, stop it safely on SIGINT (Ctrl-C: feed hold, reset, journal kept)
    and send (outcome in words, summary) through `connection`."""
    stream = SheetStream(port, program, lambda done, position: None)
    signal.signal(signal.SIGINT, lambda signum, frame: stream.stop())
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the parent until the handler is in place
    try:
        outcome = stream.run()
    except FablineError as exc:
        outcome = f"stopped: {exc}"
    connection.send((outcome, stream.summary()))


def journal_summary(port: str, program: str | os.PathLike) -> dict:
    """A sheet's streaming summary as its journal tells it, for a link process that died before reporting."""
    journal = default_journal_path(Path(program))
    state = read_journal(journal) if journal.is_file() else None
    return {"port": port, "lines": state.total if state else 0, "executed": state.done if state else 0,
            "journal": str(journal), "resumed_from": state.resumed_at if state else None}
