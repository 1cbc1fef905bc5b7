"""The streamer's parts on their own: the record of what ran (`Ledger`) fed answers by hand, and the transport
with the Grbl dialect (`Connection`, `Grbl`) against the simulator."""

import uuid

import pytest

from fabline.link.connection import Connection
from fabline.link.controller import Grbl
from fabline.link.ledger import Ledger, Undecided
from fabline.link.protocol import CharacterCounter, classify
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


def test_a_stop_at_a_reversal_names_the_line_still_short_of_its_end():
    """Out and back (X10, then X0): Grbl plans a full stop where the path turns back, so a stop 0.007 mm short of X10
    (within the position tolerance of its end) may be the first line's last microns as well as its end: both are
    named, never the end alone (the fault campaign's case 127: resuming after line 2 left line 2 unfinished). At a
    plain corner the end is still taken."""
    ledger = ledger_of(b"G21 G90\nG1 X10 F600\nG1 X0\nG1 Y10\n")
    send_all(ledger)
    ledger.heard(classify("ok"))
    ledger.heard(classify("ok"))
    with pytest.raises(Undecided, match=r"one of 2, 3\)"):
        ledger.executed_from_position(classify("<Hold:0|WPos:9.993,0.000,0.000>").status, None, planner_empty=False)
    corner = ledger_of(SQUARE)
    send_all(corner)
    corner.heard(classify("ok"))
    corner.heard(classify("ok"))
    assert corner.executed_from_position(classify("<Hold:0|WPos:9.993,0.000,0.000>").status, None,
                                         planner_empty=False) == 2
