"""Resuming an interrupted job: which journal it continues, how many lines the controller it left behind executed,
and the commands that restore the modal state and move safely to the restart point.

After a lost connection or a killed host the controller is let finish, a half-received line is discarded and
`$G`'s tag names the last line parsed among those the journal shows sent after its last `ok`; the controller must
stand where the program is after that line. After an alarm or a halt the stopped position decides (`Ledger`).
"""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

from fabline.errors import FablineError
from fabline.link.connection import Connection
from fabline.link.controller import Grbl
from fabline.link.journal import JournalState, read_journal
from fabline.link.ledger import POSITION_TOLERANCE, Ledger, Undecided, file_line
from fabline.machine.gcode import ModalState, Vector
from fabline.machine.program import TAG_CYCLE, Program, line_tag

_MOTION_WORD = re.compile(r"G0*[0-3](?![0-9.])")
_ARC_MOTION = re.compile(r"G0*[23](?![0-9.])")
_ARC_WORDS = re.compile(r"[IJKR][-+]?[0-9.]+")


def _where(position) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in position) + ")"


def _describe(identity: dict[str, str] | None) -> str:
    return "no named run" if identity is None else "run " + ", ".join(f"{k}={v}" for k, v in sorted(identity.items()))


def previous_job(path: Path, program: Program, resume: bool, restart: bool,
                 identity: dict[str, str] | None) -> JournalState | None:
    """The journal of the job being resumed, checked against the program and identity; None for a new job,
    whose journal starts afresh (an interrupted run of this program and identity is not overwritten by
    accident; --restart never reads the old journal, so a damaged one cannot block it)."""
    if not resume:
        if restart or not path.is_file() or path.stat().st_size == 0:
            return None
        state = read_journal(path)
        if state.sha256 == program.sha256 and not state.finished and state.identity == identity:
            raise FablineError(
                f"{path}: an earlier run of {program.name} stopped after file line "
                f"{file_line(program, state.done - 1) if state.done else 'none'} without finishing; "
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


class Recovery:
    """Brings the controller a job left behind to a known state and tells how far the job got."""

    def __init__(self, connection: Connection, controller: Grbl, ledger: Ledger, journal_path: Path):
        self.connection, self.controller, self.ledger, self.journal_path = connection, controller, ledger, journal_path
        self.first_line: bytes | None = None
        """The first program line as the last `preamble` has it re-sent (its rest from where the machine stopped)."""

    @property
    def url(self) -> str:
        return self.connection.url

    def recover(self, previous: JournalState, unlock: bool) -> int:
        """Bring a controller left by an interrupted job to Idle and return how many lines it executed."""
        link, ledger = self.connection, self.ledger
        status = link.settle()
        if status.state == "Alarm" and not unlock:
            raise FablineError(f"{self.url}: the controller is in alarm; check the machine, then resume with --unlock")
        stopped = previous.stopped or ""
        if stopped.startswith("undecided"):
            raise Undecided(f"{self.journal_path}: the last run stopped where fabline could not tell the line "
                            f"({stopped[len('undecided: '):]})")
        if stopped.startswith(("error", "aborted", "ALARM", "log failed")):  # the host that stopped it judged what ran
            executed = previous.done
        elif status.state == "Hold" and not stopped.startswith("controller reset"):
            # held when its host went away: let it finish what it holds (the operator asked to resume), then ask $G
            link.exchange("#", "cycle start: the controller was held by an interrupted run")
            self.controller.cycle_start()
            deadline = time.monotonic() + link.answer_wait
            while link.query_status().state == "Hold" and time.monotonic() < deadline:
                time.sleep(0.02)
            status = link.settle()
            if status.state == "Idle":
                return self.parsed_count(previous)
            executed = ledger.executed_from_position(status, link.wco, planner_empty=False)
        elif status.state in ("Alarm", "Hold") or stopped.startswith("controller reset"):
            executed = ledger.executed_from_position(status, link.wco, planner_empty=False)
        elif status.state == "Idle":
            return self.parsed_count(previous)
        else:
            raise FablineError(f"{self.url}: the controller is in state {status.state}; it must be Idle to resume")
        if status.state in ("Alarm", "Hold"):
            self.controller.soft_reset(unlock=True)
        return executed

    def parsed_count(self, previous: JournalState) -> int:
        """Lines executed by an Idle controller that finished everything it parsed: its `$G` tag names the last
        line parsed, looked up only among the lines the journal shows sent after its last `ok` (sent records reach
        the disk before their line reaches the port, so no other line can have been parsed), and the controller
        must stand where the program is after that line. Anything else means the journal lost records (or the
        machine was moved): refused, naming what the journal knows, for the operator's --from-line."""
        ledger = self.ledger
        self.controller.flush_partial_line()
        tag = self.controller.parser_tag()
        status = self.connection.settle()  # lines still in its receive buffer when it looked idle were parsed before `#`
        low = previous.acked - 1
        high = max(min(previous.sent, low + TAG_CYCLE, len(ledger.program.lines)), previous.acked)
        count = next((index + 1 for index in range(low, high) if line_tag(index) == tag), None)
        if count is None:
            sent = f"file line {ledger.file_line(previous.sent - 1)}" if previous.sent else "no line"
            self._refuse_unproven(previous, "its parser tag is T0 (it was reset, or a line without a tag was sent to it)" if tag == 0 else
                                  f"its parser tag T{tag} names no line the journal shows sent (the last one sent: "
                                  f"{sent}; records lost from the journal's end?)")
        here = status.work_position(self.connection.wco)
        if here is not None and not any(block.stored_reference for block in ledger.blocks[:count]):
            there = ledger.position_after(count)
            if math.dist(here[:3], there) > POSITION_TOLERANCE:
                self._refuse_unproven(previous, f"its parser tag T{tag} fits file line {ledger.file_line(count - 1)}, "
                                                f"but it stands at {_where(here[:3])}, not at {_where(there)} where the "
                                                "program is after that line (records lost from the journal, or the "
                                                "machine was moved)")
        return count

    def _refuse_unproven(self, previous: JournalState, why: str) -> None:
        """The journal cannot prove where the controller stopped: one line naming the last line it knows executed."""
        known = f"file line {self.ledger.file_line(previous.done - 1)}" if previous.done else "no line"
        raise FablineError(f"{self.journal_path}: cannot tell how far the controller got: {why}; the journal knows "
                           f"{known} executed: check the part and continue by hand with --resume --from-line N, N the "
                           "first line not yet cut")

    def stop_where_it_is(self, unlock: bool) -> None:
        """For an operator's --from-line: wait for the controller to finish or stand still, then drop whatever it
        holds (a hold or an alarm is reset), so only the chosen line and what follows run."""
        status = self.connection.settle()
        if status.state == "Alarm" and not unlock:
            raise FablineError(f"{self.url}: the controller is in alarm; check the machine, then resume with --unlock")
        if status.state in ("Alarm", "Hold"):
            self.controller.soft_reset(unlock=True)
        elif status.state == "Idle":
            self.controller.flush_partial_line()
        else:
            raise FablineError(f"{self.url}: the controller is in state {status.state}; it must be Idle to resume")

    def preamble(self, executed: int) -> list[bytes]:
        """Commands that restore the modal state after `executed` lines and move safely to the restart point."""
        ledger = self.ledger
        if executed >= len(ledger.program.lines):
            return []
        self._refuse_stored_references(executed)
        modal = ledger.blocks[executed - 1].modal if executed else ModalState()
        target: Vector = ledger.position_after(executed)
        lines = ["G21G90G17G94M5", f"{modal.coord}"]
        status = self.connection.query_status()
        here = status.work_position(self.connection.wco) or target
        self.first_line = self._rest_of_line(executed, here)
        if self.first_line is None and not all(math.isclose(a, b, abs_tol=1e-4) for a, b in zip(here, target)):
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

    def _rest_of_line(self, index: int, here: Vector) -> bytes | None:
        """Line `index` re-sent from `here`, a point on its path past its start (a stop cut it short): an absolute
        straight move as it is, cutting only the rest; an arc with its centre offsets from `here` (I, J, K are
        relative to the start), or, with less than the tolerance left, a straight move to its end (an arc whose
        start is its end would be a full circle). None when the machine does not stand on the line's path."""
        block, line = self.ledger.blocks[index], self.ledger.program.lines[index]
        segment = block.segment
        if segment is None or math.dist(here, segment.start) <= POSITION_TOLERANCE or not segment.contains(here, POSITION_TOLERANCE):
            return None
        if segment.center is None:
            return line.wire
        command = _ARC_WORDS.sub("", line.command)
        if math.dist(here, segment.end) <= POSITION_TOLERANCE:
            if not _ARC_MOTION.search(command):
                raise FablineError(f"{self.ledger.program.name}:{line.file_line}: the machine stopped microns short "
                                   "of the end of this arc, which relies on modal G2/G3: resume with --from-line at "
                                   "the next line")
            command = _ARC_MOTION.sub("G1", command)
        else:
            scale = 25.4 if block.modal.units == "G20" else 1.0
            command += "".join(f"{'IJK'[axis]}{(segment.center[axis] - here[axis]) / scale:.4f}"
                               for axis in segment.plane[:2])
        return f"N{line.file_line}{command}T{line_tag(index)}\n".encode("ascii")

    def _refuse_stored_references(self, executed: int) -> None:
        """Positions after a work offset change (G10, G92, G43.1) or a move to a stored or machine position (G28,
        G30, G53, G38.x) depend on what the controller stores: refuse a restart after such a line."""
        program = self.ledger.program
        for index, block in enumerate(self.ledger.blocks[:executed]):
            if block.stored_reference:
                raise FablineError(
                    f"{program.name}:{program.lines[index].file_line}: cannot resume after this line: "
                    f"{block.stored_reference} depends on offsets or positions stored in the controller, which a "
                    "resume cannot re-establish; start the sheet over with --restart")

    def _refuse_modal_arc(self, executed: int, motion: str) -> None:
        """An arc mode cannot be restored without a target: refuse if the next move relies on it."""
        program = self.ledger.program
        for line in program.lines[executed:]:
            if _MOTION_WORD.search(line.command):
                return
            if re.search(r"[XYZ]", line.command):
                raise FablineError(f"{program.name}:{line.file_line}: cannot restart before this line: it relies on "
                                   f"modal {motion}; resume with --from-line at a line with its own G word")
