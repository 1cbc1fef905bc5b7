"""Stopping a stream safely: feed hold until still, reset, then journal how far it got (from the stopped position
where the planner was flushed) and raise or return what the caller needs to resume."""

from __future__ import annotations

import time

from fabline.link.connection import Connection
from fabline.link.controller import Grbl
from fabline.link.journal import JournalError
from fabline.link.ledger import Ledger, Undecided
from fabline.link.report import Reporter, StreamInterrupted, StreamResult


class Stopper:
    """Stops on an error, an alarm, an abort, a journal failure or an undecided position, for one run."""

    def __init__(self, connection: Connection, controller: Grbl, ledger: Ledger, reporter: Reporter,
                 stop_timeout: float):
        self.connection, self.controller, self.ledger, self.reporter = connection, controller, ledger, reporter
        self.stop_timeout = stop_timeout
        """s to wait for the machine to stand still after a feed hold (deceleration takes well under one)."""

    @property
    def url(self) -> str:
        return self.connection.url

    def on_error(self, index: int | None, code: int | None) -> None:
        """The controller rejected a line: halt it, journal how far it got, and raise."""
        ledger, journal, dialect = self.ledger, self.ledger.journal, self.controller.dialect
        if index is None:
            raise StreamInterrupted(f"{self.url}: controller refused a resume command: {dialect.explain_error(code)}",
                                    "error", ledger.done)
        line = ledger.program.lines[index]
        journal.commit()
        executed = self.halt(rejected=index)
        journal.record("done", count=executed)
        journal.record("stopped", reason=f"error:{code} at file line {line.file_line}")
        journal.commit()
        raise StreamInterrupted(f"{ledger.program.name}:{line.file_line}: controller answered "
                                f"{dialect.explain_error(code)}: {line.source.strip()}; stopped with "
                                f"{executed} lines executed", "error", executed)

    def on_alarm(self, code: int | None) -> None:
        """An alarm flushed the controller: find the interrupted line from the stopped position, then stop."""
        ledger, journal = self.ledger, self.ledger.journal
        journal.record("alarm", code=code)
        journal.commit()
        status = self.connection.query_status()
        try:
            executed = ledger.executed_from_position(status, self.connection.wco, planner_empty=False)
        except Undecided as exc:
            self.undecided(exc, f"ALARM:{code}: ")
        ledger.done = executed
        journal.record("done", count=executed)
        journal.record("stopped", reason=f"ALARM:{code}")
        journal.commit()
        raise StreamInterrupted(f"{self.url}: {self.controller.dialect.explain_alarm(code)} during file line "
                                f"{ledger.file_line(executed)}; check the machine, then run again with --resume --unlock",
                                "alarm", executed)

    def on_reset(self) -> None:
        """The controller reset itself mid-job (its banner came): journal it and raise."""
        self.ledger.journal.record("stopped", reason="controller reset")
        self.ledger.journal.commit()
        raise StreamInterrupted(f"{self.url}: the controller reset itself during the job (power or USB problem?); "
                                "check the machine, then run again with --resume --unlock", "reset", self.ledger.done)

    def on_abort(self) -> StreamResult:
        journal = self.ledger.journal
        try:
            executed = self.halt(rejected=None)
        except Undecided as exc:
            self.undecided(exc, "aborted: ")
        journal.record("done", count=executed)
        journal.record("stopped", reason="aborted")
        journal.commit()
        self.reporter.report()
        return self.reporter.result(False, executed, "aborted")

    def unrecorded(self, failure: JournalError) -> None:
        """The journal cannot be written: stop the machine so that no line runs unrecorded, and name the line to
        resume from, which the journal can no longer tell."""
        ledger, journal = self.ledger, self.ledger.journal
        if journal.failed:
            journal.abandon()
        try:
            executed = self.halt(rejected=None)
        except Undecided as exc:
            self.undecided(exc, f"{failure}; the machine was stopped, but ")
        journal.record("done", count=executed)  # dropped when the journal is what failed
        journal.record("stopped", reason=f"log failed: {failure}")
        journal.commit()
        where = (f"after file line {ledger.file_line(executed - 1)}" if executed else "before the first line")
        if executed == len(ledger.program.lines):
            hint = "every line had run"
        elif journal.failed:  # the journal no longer knows where the machine stopped: the operator says it
            hint = f"run again with --resume --from-line {ledger.file_line(executed)}"
        else:
            hint = "run again with --resume"
        raise StreamInterrupted(f"{failure}; the machine was stopped {where}: make room, then {hint}", "journal",
                                executed) from None

    def undecided(self, exc: Undecided, cause: str = "") -> None:
        """Journal that the stopped position did not tell the line (a resume must then be told, --from-line)."""
        self.ledger.journal.record("stopped", reason=f"undecided: {exc}")
        self.ledger.journal.commit()
        raise StreamInterrupted(f"{cause}{exc}", "undecided", self.ledger.done) from None

    def halt(self, rejected: int | None) -> int:
        """Feed hold until the machine stands still, reset to flush its buffers, unlock; return lines executed."""
        link, ledger = self.connection, self.ledger

        def in_flight() -> bool:
            return bool(ledger.counter and ledger.counter.in_flight)

        status = link.query_status()
        if status.state == "Idle" and not in_flight():
            self.controller.soft_reset()  # nothing left that could start: every acknowledged line is done
            return ledger.executed_from_position(status, link.wco, True, rejected)
        deadline = time.monotonic() + self.stop_timeout
        while True:
            self.controller.feed_hold()  # again each time: a hold asked for while a line was parsing may not have taken
            status = link.query_status()
            if status.state == "Hold" and status.substate == 0:
                status = self._settled(status)
                break
            if status.state in ("Idle", "Alarm", "Check") and not in_flight():
                break
            if time.monotonic() > deadline:
                self.controller.soft_reset()
                raise StreamInterrupted(f"{self.url}: the machine did not stop within {self.stop_timeout:g} s of a feed "
                                        f"hold (it reported {status.state}), so it was reset; check the part and "
                                        "resume with --from-line", "error", ledger.done)
            time.sleep(0.02)
        self.controller.soft_reset()  # first, so the machine is never left in a hold whatever the verdict
        return ledger.executed_from_position(status, link.wco, status.state == "Idle", rejected,
                                             held=status.state == "Hold")

    def _settled(self, status):
        """The status of a finished hold once the `ok`s of lines the parser was still planning have come: two
        reports in a row with no new `ok` (the planner's fill then tells the held line, `Ledger.planned_line`)."""
        quiet, deadline = 0, time.monotonic() + 1.0
        while quiet < 2 and time.monotonic() < deadline:
            before = self.ledger.acked
            time.sleep(0.02)
            status = self.connection.query_status()
            quiet = quiet + 1 if self.ledger.acked == before else 0
        return status
