"""The record of what ran: lines sent, acknowledged and known executed, journaled as the controller answers, and
the executing line told from a stopped position.

`ok` means parsed into the planner; a status report `Ln:N` means every line before N is done, and so does one
whose position lies on line N's path, N the first acknowledged line not known done that passes there; Idle with
nothing in flight means every acknowledged line is done. After a stop with the planner flushed the executing line
is one of the window of lines that can still have been in the planner, the one whose path holds the stopped
position. A line is done only once it has ended: a machine at rest within the tolerance of a line's end may be
microns short of it, so that line counts as not done (re-sent, it cuts the rest) unless other evidence says it
ended: the planner's fill, an answered line that waits for an empty planner, a position past the corner.
"""

from __future__ import annotations

import math
from typing import Callable

from fabline.errors import FablineError
from fabline.link.controller import Grbl
from fabline.link.protocol import CharacterCounter, Response, StatusReport
from fabline.machine.gcode import ModalState, Vector
from fabline.machine.program import Program

SEGMENT_BUFFER = 6
"""Grbl's stepper segment buffer (SEGMENT_BUFFER_SIZE): up to this many blocks may still run after leaving the planner."""
POSITION_TOLERANCE = 0.01
"""mm: status reports carry three decimals; a stopped position is matched to a path within this."""
ROUNDING = 0.001
"""mm: a reported position is within this of where the machine is (three decimals per axis)."""


def file_line(program: Program, index: int) -> int | None:
    """The file line of program line `index` (clamped to the program)."""
    lines = program.lines
    return lines[min(max(index, 0), len(lines) - 1)].file_line if lines else None


class Undecided(Exception):
    """The stopped position does not tell which line was executing: the operator must say (--from-line)."""


class Ledger:
    """What ran of `program` on one controller. `blocks` (the planned program) and `origin` are set once the start
    is known, `journal` once open; `counter` is the flow control's while lines are in flight, else None. The
    window is as deep as the `controller`'s build's planner."""

    def __init__(self, program: Program, controller: Grbl):
        self.program, self.controller = program, controller
        self.blocks = None
        self.origin: Vector | None = None
        self.journal = None
        self.counter: CharacterCounter | None = None
        self.acked = self.done = self.sent = self.first_index = 0
        self.errors: list[tuple[int | None, int | None]] = []
        self.pauses: list[int] = []  # acknowledged M0 lines whose pause has not been reported yet
        self.status_after_last_ok = False
        self.watch = False
        self.waiting_at_reset: int | None = None
        self.on_pause: Callable[[int], None] | None = None
        """Told the index of an M0 line when the machine stops there."""

    def at(self, executed: int) -> None:
        """Every count set to `executed` lines (a start or a resume)."""
        self.acked = self.done = self.sent = executed

    def begin(self, counter: CharacterCounter, watch: bool = True) -> None:
        """A stream starts with `counter` its flow control: nothing answered, rejected or paused yet. `watch`: the
        reported positions are the program's (not while a resume's travel may run before its first line)."""
        self.counter, self.errors, self.pauses, self.watch = counter, [], [], watch
        self.status_after_last_ok = False
        self.waiting_at_reset = None

    @property
    def url(self) -> str:
        return self.controller.url

    # ----- as the controller answers (a Connection's listener) ------------------------------------------------------
    def heard(self, response: Response) -> None:
        counter = self.counter
        if response.kind in ("ok", "error") and counter is not None and counter.in_flight:
            self.answered(response)
        elif response.kind == "status" and counter is not None:
            self.track(response.status)

    def reset(self) -> None:
        """The controller flushed its buffers: nothing is in flight any more."""
        if self.counter is not None:
            self.waiting_at_reset = self.waiting()
            self.counter.clear()
            self.counter = None

    def sending(self, index: int) -> None:
        """Line `index` goes to the controller (journaled before it reaches the port: the caller flushes first)."""
        self.journal.record("sent", n=index, line=self.program.lines[index].file_line)
        self.sent = index + 1

    def answered(self, response: Response) -> None:
        """Match an ok or error:N to the oldest line in flight; errors are queued for the stream loop."""
        index = self.counter.answered()
        self.status_after_last_ok = False
        if response.kind == "ok":
            if index is not None:
                self.acked = index + 1  # what the controller said, even when the journal fails to record it
                if self.blocks[index].pause:
                    self.pauses.append(index)
                self.journal.record("ok", n=index, line=self.program.lines[index].file_line)
            return
        if index is not None:
            self.journal.record("error", n=index, line=self.program.lines[index].file_line, code=response.code)
        self.errors.append((index, response.code))

    def track(self, status: StatusReport) -> None:
        """Advance the count of executed lines: from `Ln:`, Idle with nothing in flight, the machine seen on a line."""
        self.status_after_last_ok = True
        if self.errors:
            return  # after a rejected line only the halt decides what ran
        if self.pauses and status.state == "Hold" and status.substate == 0 and self.on_pause is not None:
            self.on_pause(self.pauses.pop(0))
        executed = self.done
        if status.line_number is not None and status.state in ("Run", "Hold"):
            index = self.index_of_file_line(status.line_number, strict=False)
            if index is not None and index >= self.done:
                executed = index
        elif status.state == "Idle" and self.counter.in_flight == 0:
            executed = self.acked
        elif (status.state in ("Run", "Hold") and self.watch
              and (position := status.work_position(self.controller.connection.wco))):
            executed = self.first_on_path(position) or executed  # the machine is seen on it: every line before ran
        if executed > self.done:
            self.done = executed
            self.journal.record("done", count=executed)

    # ----- where a stopped machine was ------------------------------------------------------------------------------
    def executed_from_position(self, status: StatusReport, wco, planner_empty: bool, rejected: int | None = None,
                               held: bool = False) -> int:
        """Lines executed when the machine stopped at `status` with its planner flushed: the executing line is one
        of the window of lines that can still have been in the planner (`window`), the one whose path holds
        the stopped position; `Ln:` names it where the build reports it; in a finished hold (`held`: the planner
        still holds the stopped line) a planner known to be full (`Bf:`, or a straight move waiting for room)
        names it too. Raises Undecided when no line or several lines of the window fit the position."""
        acked = self.acked
        if planner_empty:
            return rejected if rejected is not None else acked
        if status.line_number is not None and status.state in ("Run", "Hold"):
            index = self.index_of_file_line(status.line_number, strict=False)
            if index is not None and self.done <= index <= self.sent:
                return index if rejected is None else min(index, rejected)
        position = status.work_position(wco)
        counts, ended = self.counts_at(position)
        planned = self.planned_line(status) if held and rejected is None else None
        if planned is not None and self.fits(planned, position):
            return planned
        if rejected is not None:
            beyond = sorted(count for count in counts if count > rejected)
            if beyond:
                raise Undecided(f"{self.url}: the controller ran file line {self.file_line(beyond[0])}, past the "
                                f"rejected line {self.program.lines[rejected].file_line}; check the part and resume "
                                "with --from-line")
            if not counts:
                return rejected
        if len(counts) == 1:
            return counts.pop()
        where = ", ".join(f"{v:.3f}" for v in position)
        if not counts:
            raise Undecided(f"{self.url}: cannot tell which line the machine stopped in (work position {where}, "
                            f"none of file lines {self.file_line(self.window()[0])}.."
                            f"{self.file_line(self.sent - 1)} passes there); check the part and resume with "
                            "--from-line")
        lines = [str(self.file_line(count)) if count < len(self.program.lines) else "the end"
                 for count in sorted(counts | ended)]  # named: a line at whose end it rests may have ended too
        raise Undecided(f"{self.program.name}: the machine stopped at {where}, where the path passes more than once "
                        f"(file lines {', '.join(lines)} can have been cutting); look at the part and resume with "
                        f"--resume --from-line N, N the first line not yet cut (one of {', '.join(lines)})")

    def window(self) -> tuple[int, int]:
        """The lines that can have been executing: back from the last acknowledged line by at most the planner's
        size plus the stepper's segment buffer in motion lines (a motion takes at least one planner block, and
        leaves the planner once prepared into segments, before it has run), up to the last line sent."""
        rejected = {index for index, _ in self.errors}
        low, motions, room = self.acked, 0, self.controller.build.planner_blocks + SEGMENT_BUFFER
        while low > self.done:
            if self.blocks[low - 1].segment is not None and low - 1 not in rejected:
                if motions == room:
                    break
                motions += 1
            low -= 1
        return low, min(max(self.sent, self.acked), len(self.blocks))

    def counts_at(self, position: Vector) -> tuple[set[int], set[int]]:
        """Every count of executed lines the stopped `position` fits: inside motion line m or at rest at its end (m
        lines done: it is re-sent), past its end where something tells it ended (m + 1 done, and the lines up to
        the next motion that were acknowledged), or at rest at the window's start; and the counts had the lines
        at whose end it rests ended (to name, should it come to naming candidates)."""
        low, high = self.window()
        motions = [index for index in range(low, high) if self.moves(index)]
        before = next((index for index in range(low - 1, -1, -1) if self.moves(index)), None)
        counts, ended = set(), set()
        rest = self.origin if before is None else self.blocks[before].segment.end
        following = motions + [len(self.blocks)]
        if math.dist(position, rest) <= POSITION_TOLERANCE:
            counts.add(min(max(self.acked, (before if before is not None else -1) + 1), following[0]))
        for number, index in enumerate(motions):
            segment = self.blocks[index].segment
            if math.dist(position, segment.end) <= POSITION_TOLERANCE:
                # at rest at its end, or microns short of it: not ended, unless a line after it that waits for an
                # empty planner (a dwell, a spindle or coolant change) was answered, or the position lies on the
                # next motion (acknowledged) and off this one beyond the reports' rounding: a few microns past
                after = following[number + 1]
                if (any(self.synchronizes(later) for later in range(index + 1, min(after, self.acked)))
                        or after < self.acked and self.blocks[after].segment.contains(position, ROUNDING)
                        and not segment.contains(position, 2 * ROUNDING)):
                    counts.add(min(max(self.acked, index + 1), after))
                else:
                    counts.add(index)
                    ended.add(min(max(self.acked, index + 1), after))
            elif (math.dist(position, segment.start) > POSITION_TOLERANCE
                  and segment.contains(position, POSITION_TOLERANCE)):
                counts.add(index)
        return {count for count in counts if count >= self.done}, {count for count in ended if count >= self.done}

    def first_on_path(self, position: Vector) -> int | None:
        """The first line from `done` on, among those acknowledged, whose path holds `position`: a status report
        shows the machine on a line it acknowledged (a line executes once planned, and its ok comes first), and
        motion only goes on, so every line before that one has run (on a retraced path, earlier passes are ruled
        out as the machine is seen past them)."""
        for index in range(self.done, min(self.acked, len(self.blocks))):
            segment = self.blocks[index].segment
            if segment is not None and segment.length > 0 and segment.contains(position, POSITION_TOLERANCE):
                return index
        return None

    def synchronizes(self, index: int) -> bool:
        """Whether line `index` waits for an empty planner before its ok (Grbl: a dwell, M0, M2/M30, a spindle or
        coolant state change, even in laser mode)."""
        block = self.blocks[index]
        before = self.blocks[index - 1].modal if index else ModalState()
        return (block.dwell > 0 or block.pause or block.program_end or block.modal.spindle != before.spindle
                or block.modal.coolant != before.coolant)

    def planned_line(self, status: StatusReport) -> int | None:
        """The line the machine holds in a finished feed hold, told by how many planner blocks are in use: `Bf:`
        where reported, else all of them when the oldest line in flight is a straight move (the parser waits for
        room). Grbl keeps the held block in its planner and its segment buffer is empty by then, so the blocks
        in use are the newest planned ones, the held block the oldest of them. None when neither tells or an arc
        (a chord count of its own) is among them."""
        capacity = self.controller.build.planner_blocks
        waiting = self.waiting()
        if status.planner_free is not None and (waiting is None or self.blocks_of(waiting) is not None):
            used = capacity - status.planner_free
        elif waiting is not None and self.blocks_of(waiting) == 1:
            used = capacity
        else:
            return None
        counted = 0
        for index in range(self.acked - 1, self.done - 1, -1):
            blocks = self.blocks_of(index)
            if blocks is None:
                return None
            counted += blocks
            if counted >= used > 0:
                return index
        return None

    def waiting(self) -> int | None:
        """The oldest program line in flight (sent, not answered), if it is one."""
        if self.counter is None:
            return self.waiting_at_reset
        oldest = self.counter.oldest()
        return oldest if oldest is not None and oldest == self.acked else None

    def blocks_of(self, index: int) -> int | None:
        """Planner blocks line `index` takes: none without motion, one for a straight move, None for an arc."""
        segment = self.blocks[index].segment
        if segment is None or segment.length <= 0:
            return 0
        return 1 if segment.center is None else None

    def fits(self, index: int, position: Vector) -> bool:
        """Whether `position` lies on the path of line `index` (its ends within the tolerance included)."""
        segment = self.blocks[index].segment
        return segment is not None and segment.contains(position, POSITION_TOLERANCE)

    def moves(self, index: int) -> bool:
        segment = self.blocks[index].segment
        return segment is not None and segment.length > POSITION_TOLERANCE

    def position_after(self, executed: int) -> Vector:
        """Where the program is after its first `executed` lines."""
        for block in reversed(self.blocks[:executed]):
            if block.segment is not None:
                return block.segment.end
        return self.origin

    # ----- file lines -----------------------------------------------------------------------------------------------
    def file_line(self, index: int) -> int | None:
        return file_line(self.program, index)

    def index_of_file_line(self, file_line: int, strict: bool = True) -> int | None:
        for line in self.program.lines:
            if line.file_line >= file_line:
                if line.file_line == file_line or not strict:
                    return line.index
                break
        if strict:
            raise FablineError(f"{self.program.name}:{file_line}: no G-code command on that line to restart from")
        return None
