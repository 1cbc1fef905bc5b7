"""Flow control: lines sent as the controller's receive buffer has room (character counting) or one at a time
(send-response), status polled, real-time bytes passed on, until the machine executed the last line; and the
same over check mode ($C), where nothing moves."""

from __future__ import annotations

import re
import time

from fabline.errors import FablineError
from fabline.link.connection import Connection, Lost
from fabline.link.controller import Grbl
from fabline.link.controls import Controls
from fabline.link.ledger import Ledger
from fabline.link.protocol import STATUS_QUERY, CharacterCounter
from fabline.link.report import Reporter, StreamResult
from fabline.link.stopping import Stopper
from fabline.machine.codes import explain_error, listing
from fabline.machine.program import Program

MODES = ("counting", "send-response")
_AXIS = re.compile(rb"[XYZ]")


class Sender:
    """Streams `ledger`'s program over `connection`, stopping through `stopper`, reporting through `reporter`."""

    def __init__(self, connection: Connection, controller: Grbl, ledger: Ledger, controls: Controls,
                 reporter: Reporter, stopper: Stopper, *, mode: str, status_interval: float, silence_timeout: float):
        self.connection, self.controller, self.ledger, self.controls = connection, controller, ledger, controls
        self.reporter, self.stopper = reporter, stopper
        self.mode, self.status_interval, self.silence_timeout = mode, status_interval, silence_timeout
        ledger.on_pause = self.program_paused

    def program_paused(self, index: int) -> None:
        """An M0 stopped the machine: say so (progress, journal, log) and wait for the operator's cycle start."""
        line = self.ledger.program.lines[index].file_line
        self.controls.program_paused(f"program paused (M0) at file line {line}: resume to continue")
        self.ledger.journal.record("paused", line=line)
        self.connection.exchange("#", self.controls.message)
        self.reporter.report()

    def stream(self, preamble: list[bytes], first: bytes | None = None) -> StreamResult:
        """Send `preamble`, then every line from `ledger.done` on (the first as `first` where given: the rest of a
        line a stop cut short); return when the machine has executed the last."""
        link, ledger, journal = self.connection, self.ledger, self.ledger.journal
        lines = ledger.program.lines
        outgoing = [(None, wire) for wire in preamble] + [(line.index, line.wire) for line in lines[ledger.done:]]
        if first is not None and len(outgoing) > len(preamble):
            outgoing[len(preamble)] = (ledger.done, first)
        counter = CharacterCounter(self.controller.rx_buffer, max_lines=1 if self.mode == "send-response" else None)
        ledger.begin(counter, watch=not any(_AXIS.search(wire) for wire in preamble))  # a travel: not the program's
        position, next_poll, next_report = 0, 0.0, 0.0
        link.last_heard = time.monotonic()
        while True:
            if self.controls.aborting.is_set():
                return self.stopper.on_abort()
            for byte in self.controls.take():
                link.write(byte)
            batch = []
            while position < len(outgoing) and counter.fits(len(outgoing[position][1])):
                index, wire = outgoing[position]
                counter.sent(index, len(wire))
                if index is not None:
                    ledger.sending(index)
                batch.append(wire)
                position += 1
            if batch:
                journal.flush()  # a line the controller received is always journaled as sent
                link.write(b"".join(batch))
            now = time.monotonic()
            if now >= next_poll:
                link.write(STATUS_QUERY)
                next_poll = now + self.status_interval
            if now - link.last_heard > self.silence_timeout:
                raise Lost(f"the controller sent nothing for {self.silence_timeout:g} s, not even status reports")
            for response in link.read(0.01):
                if response.kind == "alarm":
                    self.stopper.on_alarm(response.code)
                elif response.kind == "banner":
                    self.stopper.on_reset()
            if ledger.errors:
                self.stopper.on_error(*ledger.errors[0])
            if position == len(outgoing) and counter.in_flight == 0 and link.status is not None \
                    and link.status.state == "Idle" and ledger.status_after_last_ok:
                ledger.done = len(lines)
                journal.record("done", count=ledger.done)
                journal.record("finished")
                journal.commit()
                self.reporter.report()
                return self.reporter.result(True, ledger.done, None)
            if time.monotonic() >= next_report:
                self.reporter.report()
                next_report = time.monotonic() + 0.1


def check_mode(connection: Connection, controller: Grbl, program: Program, silence_timeout: float) -> None:
    """Run the whole program through GRBL check mode ($C) and list every line the controller refuses."""
    controller.enter_check()
    counter = CharacterCounter(controller.rx_buffer)
    lines, position, answered, failures = program.lines, 0, 0, []
    connection.last_heard = time.monotonic()
    while counter.in_flight or position < len(lines):
        batch = []
        while position < len(lines) and counter.fits(len(lines[position].wire)):
            counter.sent(position, len(lines[position].wire))
            batch.append(lines[position].wire)
            position += 1
        if batch:
            connection.write(b"".join(batch))
        for response in connection.read(0.01):
            if response.kind in ("ok", "error"):
                index = counter.answered()
                answered += 1
                if response.kind == "error":
                    failures.append((index, response.code))
        if time.monotonic() - connection.last_heard > silence_timeout:
            raise FablineError(f"{connection.url}: check mode: no answer for {silence_timeout:g} s after "
                               f"{answered} of {len(lines)} lines")
    controller.leave_check()
    problems = [f"{program.name}:{lines[index].file_line}: check mode: {explain_error(code)}: "
                f"{lines[index].source.strip()}" for index, code in failures]
    if problems:
        raise FablineError(listing(problems, f"check mode: the controller refuses {len(problems)} lines"))
