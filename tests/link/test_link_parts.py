"""The streamer's parts on their own: the record of what ran (`Ledger`) fed answers by hand, and the transport
with the Grbl dialect (`Connection`, `Grbl`) against the simulator."""

import uuid

import pytest

from fabline.link.connection import Connection
from fabline.link.controller import Grbl
from fabline.link.ledger import Ledger, Undecided
from fabline.link.protocol import CharacterCounter, classify
from fabline.link.recovery import Recovery
from fabline.link.protocol_sim import close_simulator
from fabline.machine.gcode import ModalState
from fabline.machine.program import parse_program

SQUARE = b"G21 G90\nG1 X10 F600\nG1 X10 Y10\nG1 X0 Y10\nG1 X0 Y0\n"


class Recorder:
    """A journal that keeps its records in a list."""

    def __init__(self):
        self.records = []

    def record(self, event, **fields):
        self.records.append((event, fields))


def ledger_of(data: bytes) -> Ledger:
    program = parse_program(data, "square.gcode")
    ledger = Ledger(program, Grbl(Connection("sim://unopened")))
    ledger.origin = (0.0, 0.0, 0.0)
    ledger.blocks = program.plan(ModalState(), ledger.origin)
    ledger.journal = Recorder()
    return ledger


def send_all(ledger: Ledger) -> CharacterCounter:
    counter = CharacterCounter(128)
    ledger.begin(counter)
    for line in ledger.program.lines:
        counter.sent(line.index, len(line.wire))
        ledger.sending(line.index)
    return counter


def test_ledger_counts_oks_and_tells_the_line_from_a_stopped_position():
    ledger = ledger_of(SQUARE)
    send_all(ledger)
    for _ in range(4):
        ledger.heard(classify("ok"))
    assert (ledger.acked, ledger.sent, ledger.done) == (4, 5, 0)
    assert [fields["line"] for event, fields in ledger.journal.records if event == "ok"] == [1, 2, 3, 4]
    # stopped halfway along file line 3 (X10 Y0 -> X10 Y10): two lines done, the third was cutting
    stopped = classify("<Hold:0|WPos:10.000,5.000,0.000>").status
    assert ledger.executed_from_position(stopped, None, planner_empty=False) == 2
    # a position on no path of the window cannot be told
    with pytest.raises(Undecided, match="cannot tell which line"):
        ledger.executed_from_position(classify("<Hold:0|WPos:5.000,5.000,0.000>").status, None, planner_empty=False)


def test_ledger_idle_with_nothing_in_flight_means_every_acknowledged_line_ran():
    ledger = ledger_of(SQUARE)
    send_all(ledger)
    ledger.heard(classify("<Idle|WPos:0.000,0.000,0.000>"))
    assert ledger.done == 0  # lines still in flight: Idle says nothing yet
    for _ in range(5):
        ledger.heard(classify("ok"))
    ledger.heard(classify("<Idle|WPos:0.000,0.000,0.000>"))
    assert ledger.done == 5 and ledger.journal.records[-1] == ("done", {"count": 5})


def test_ledger_queues_a_rejected_line_and_stops_counting():
    ledger = ledger_of(SQUARE)
    send_all(ledger)
    ledger.heard(classify("ok"))
    ledger.heard(classify("error:20"))
    assert ledger.errors == [(1, 20)] and ledger.acked == 1
    ledger.heard(classify("<Idle|WPos:0.000,0.000,0.000>"))
    assert ledger.done == 0  # after a rejected line only the halt decides what ran


def test_connection_and_grbl_against_the_simulator(tmp_path):
    name = f"p{uuid.uuid4().hex[:8]}"
    connection = Connection(f"sim://{name}?time_scale=50&log={tmp_path / 'sim.log'}",
                            exchange_log=tmp_path / "exchange.log")
    grbl = Grbl(connection)
    try:
        grbl.open()
        assert grbl.build.version.startswith("1.1") and grbl.rx_buffer == 128 and 110 in grbl.settings
        assert connection.query_status().state == "Idle"
        grbl.soft_reset()
        assert grbl.parser_tag() == 0  # a reset clears the tag
        connection.close()
        log = (tmp_path / "exchange.log").read_text()
        assert "connected to sim://" in log and ">>> $G" in log
        assert "$I" not in log  # the log begins once a Grbl answered: its detection is not in it
    finally:
        connection.close()
        close_simulator(name)


def held(ledger: Ledger, report: str, acked: int) -> int:
    """Lines executed by the ledger's verdict on a finished feed hold after `acked` oks."""
    for _ in range(acked):
        ledger.heard(classify("ok"))
    return ledger.executed_from_position(classify(report).status, None, planner_empty=False, held=True)


def test_a_stop_within_the_tolerance_of_a_lines_end_counts_that_line_not_done():
    """Out and back (X10, then X0), or round a corner: a machine at rest 0.007 mm short of X10 may be at the end or
    microns short of it (a feed hold decelerating into a full stop ends there either way): the line is not done, it
    is re-sent and cuts what is left (the fault campaign's case 127: resuming after it left it unfinished). Only a
    position off its path and on the next one, beyond the reports' rounding, shows the machine past the corner."""
    out_and_back = ledger_of(b"G21 G90\nG1 X10 F600\nG1 X0\nG1 Y10\n")
    send_all(out_and_back)
    assert held(out_and_back, "<Hold:0|WPos:9.993,0.000,0.000>", 2) == 1
    corner = ledger_of(SQUARE)
    send_all(corner)
    assert held(corner, "<Hold:0|WPos:10.000,0.000,0.000>", 2) == 1
    assert corner.executed_from_position(classify("<Hold:0|WPos:9.995,0.000,0.000>").status, None, False) == 1
    # 5 microns up the move to X10 Y10 (file line 3, answered), 5 microns off the end of the first (beyond the
    # reports' 0.001 mm rounding): past the corner, the first move has ended
    corner.heard(classify("ok"))
    assert corner.executed_from_position(classify("<Hold:0|WPos:10.000,0.005,0.000>").status, None, False) == 2


STRAIGHT = b"G21 G90\n" + b"".join(f"G1 X{x} F600\n".encode() for x in range(1, 21))


def test_the_planners_fill_tells_whether_the_line_at_whose_end_the_machine_rests_was_discarded():
    """20 moves of 1 mm along X, 16 lines acknowledged (15 moves: a stock planner's 15 blocks), line 16 (G1 X16)
    waiting for room: the planner is full, so it holds the moves to X1 .. X15 and the held block is the move to X1
    (file line 2): at X1.000 it is not done. With `Bf:1` 14 blocks are in use, the moves to X2 .. X15: the move
    to X1 was discarded, the machine stands at the start of the move to X2 (file line 3), 2 lines done."""
    full = ledger_of(STRAIGHT)
    send_all(full)
    assert held(full, "<Hold:0|WPos:1.000,0.000,0.000>", 16) == 1
    reported = ledger_of(STRAIGHT)
    send_all(reported)
    assert held(reported, "<Hold:0|WPos:1.000,0.000,0.000|Bf:1,40>", 16) == 2
    idle_parser = ledger_of(STRAIGHT)  # everything answered, no Bf: nothing tells, the line is not done
    counter = send_all(idle_parser)
    assert held(idle_parser, "<Hold:0|WPos:1.000,0.000,0.000>", counter.in_flight) == 1


def test_a_full_planner_tells_which_pass_of_a_retraced_path_was_held():
    """Back and forth between X1 and X2 (after G0 X1): X1.500 lies on every move of the window. 16 lines
    acknowledged and the next move waiting: the planner holds lines 1..15 (0-based), so the held pass is line 1,
    1 -> 2 (file line 2); with `Bf:12` three blocks are in use, lines 13..15, held line 13 (1 -> 2: it fits).
    Without either the position alone cannot tell and the candidates are named."""
    zigzag = b"G21 G90 G0 X1\n" + b"".join(f"G1 X{2 - i % 2} F600\n".encode() for i in range(20))
    full = ledger_of(zigzag)
    send_all(full)
    assert held(full, "<Hold:0|WPos:1.500,0.000,0.000>", 16) == 1
    reported = ledger_of(zigzag)
    send_all(reported)
    assert held(reported, "<Hold:0|WPos:1.500,0.000,0.000|Bf:12,40>", 16) == 13
    unknown = ledger_of(zigzag)
    counter = send_all(unknown)
    with pytest.raises(Undecided, match=r"passes more than once"):
        held(unknown, "<Hold:0|WPos:1.500,0.000,0.000>", counter.in_flight)


def stopped_at(ledger: Ledger, report: str) -> int:
    return ledger.executed_from_position(classify(report).status, None, planner_empty=False)


def test_the_positions_reported_while_it_ran_bound_which_pass_a_stop_is_on():
    """0 -> 3 -> 0 twice in 1 mm moves (0-based lines 1..12: 1 is 0 -> 1, 6 is 1 -> 0, 7 is 0 -> 1 again), lines
    0..6 sent and acknowledged: a stop at X0.200 lies on lines 1 and 6. Reported on the way, X0.500 (the first line
    from 0 on whose path it is: 1), X2.500 (the first from 1 on: 3), X1.500 (the first from 3 on: 5): the machine
    was on line 5 before the stop, so it stopped in line 6 (file line 7), 6 lines done. Without them both are named."""
    data = b"G21 G90 G0 X0\n" + b"".join(f"G1 X{x} F600\n".encode() for _ in range(2) for x in (1, 2, 3, 2, 1, 0))
    tracked, blind = ledger_of(data), ledger_of(data)
    for ledger in (tracked, blind):
        ledger.begin(CharacterCounter(128))
        for line in ledger.program.lines[:7]:
            ledger.counter.sent(line.index, len(line.wire))
            ledger.sending(line.index)
            ledger.heard(classify("ok"))
    for x in ("0.500", "2.500", "1.500"):
        tracked.heard(classify(f"<Run|WPos:{x},0.000,0.000>"))
    assert stopped_at(tracked, "<Alarm|WPos:0.200,0.000,0.000>") == 6
    with pytest.raises(Undecided, match=r"one of 2, 7\)"):
        stopped_at(blind, "<Alarm|WPos:0.200,0.000,0.000>")


def test_a_stop_at_a_lines_end_with_the_dwell_after_it_answered_counts_the_line_done():
    """G4 waits for an empty planner before its ok: answered, the move before it has ended (line 1 done, and the
    dwell: 3 lines done); not answered, a machine at rest at X10 may be microns short of it (1 line done)."""
    data = b"G21 G90\nG1 X10 F600\nG4 P1\nG1 X20\n"
    answered, waiting = ledger_of(data), ledger_of(data)
    for ledger, oks in ((answered, 3), (waiting, 2)):
        send_all(ledger)
        for _ in range(oks):
            ledger.heard(classify("ok"))
    assert stopped_at(answered, "<Hold:0|WPos:10.000,0.000,0.000>") == 3
    assert stopped_at(waiting, "<Hold:0|WPos:10.000,0.000,0.000>") == 1


def test_a_line_a_stop_cut_short_is_re_sent_from_where_the_machine_stands():
    """G2 X10 Y0 I5 J0 from the origin: centre (5, 0), radius 5, clockwise over the top. Stopped at the top (5, 5),
    the rest is G2 X10 Y0 with I = 5 - 5 = 0, J = 0 - 5 = -5 (offsets from the new start); stopped 0.004 mm short
    of its end, a straight move to X10 Y0 (an arc from its end to its end would be a full circle); a straight move
    is re-sent as it is; off the path, None (the preamble travels to the line's start)."""
    ledger = ledger_of(b"G21 G90\nG2 X10 Y0 I5 J0 F600\nG1 X20\n")
    recovery = Recovery(None, None, ledger, None)
    assert recovery._rest_of_line(1, (5.0, 5.0, 0.0)) == b"N2G2X10Y0F600I0.0000J-5.0000T2\n"
    assert recovery._rest_of_line(1, (9.999998, 0.004, 0.0)) == b"N2G1X10Y0F600T2\n"
    assert recovery._rest_of_line(2, (15.0, 0.0, 0.0)) == ledger.program.lines[2].wire
    assert recovery._rest_of_line(2, (15.0, 1.0, 0.0)) is None and recovery._rest_of_line(1, (0.0, 0.0, 0.0)) is None
