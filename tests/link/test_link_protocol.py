"""Pure protocol logic, program checks and the journal, tested without any port."""

from __future__ import annotations

import json
import re

import pytest

from fabline.errors import FablineError
from fabline.link import read_journal
from fabline.link.journal import Journal
from fabline.link.protocol import CharacterCounter, LineSplitter, classify, parse_status
from fabline.machine import explain_alarm, explain_error, parse_program
from fabline.machine.gcode import GcodeError, ModalState, execute
from fabline.machine.program import line_tag


def test_status_report_from_the_transcript_is_parsed():
    report = parse_status("<Run|MPos:4.864,4.864,0.000|Bf:14,128|FS:707,118|Ov:100,100,100|A:C>")
    assert report.state == "Run" and report.mpos == (4.864, 4.864, 0.0)
    assert (report.planner_free, report.rx_free, report.feed, report.speed) == (14, 128, 707, 118)
    assert report.overrides == (100, 100, 100) and report.accessories == "C"
    hold = parse_status("<Hold:1|WPos:1.000,2.000,3.000|Ln:42|F:500|WCO:0.500,0.000,-1.000>")
    assert (hold.state, hold.substate, hold.line_number, hold.feed) == ("Hold", 1, 42, 500)
    assert hold.machine_position(None) == (1.5, 2.0, 2.0)
    assert report.work_position((1.0, 1.0, 0.0)) == pytest.approx((3.864, 3.864, 0.0))


@pytest.mark.parametrize("line, kind, code", [
    ("ok", "ok", None), ("error:20", "error", 20), ("ALARM:3", "alarm", 3),
    ("Grbl 1.1h ['$' for help]", "banner", None), ("[MSG:'$H'|'$X' to unlock]", "message", None),
    ("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "feedback", None), ("$110=500.000", "setting", None),
    ("<Idle|MPos:0.000,0.000,0.000|FS:0,0>", "status", None), ("garbage", "other", None),
])
def test_controller_lines_are_classified(line, kind, code):
    response = classify(line)
    assert (response.kind, response.code) == (kind, code)


def test_line_splitter_reassembles_chunks_ending_in_crlf():
    splitter = LineSplitter()
    assert splitter.feed(b"o") == []
    assert splitter.feed(b"k\r\nerr") == ["ok"]
    assert splitter.feed(b"or:9\r\n\r\n<Idle>\r\n") == ["error:9", "<Idle>"]


def test_character_counter_keeps_the_receive_buffer_from_overflowing():
    counter = CharacterCounter(128)
    for tag in range(5):
        assert counter.fits(25)
        counter.sent(tag, 25)
    assert counter.used == 125 and not counter.fits(4) and counter.fits(3)
    assert counter.answered() == 0 and counter.fits(28)
    single = CharacterCounter(128, max_lines=1)
    single.sent("a", 5)
    assert not single.fits(1)


def test_codes_are_explained_in_words():
    assert explain_error(22) == "error:22 (feed rate has not yet been set or is undefined)"
    assert explain_alarm(1).startswith("ALARM:1 (hard limit triggered")
    assert "unknown" in explain_error(99)


def test_gcode_checks_follow_the_firmware_error_codes():
    for line, code in [("G1X10Q5", 20), ("G99", 20), ("FOO", 2), ("G1X10Y10Z", 2), ("X1X2", 25),
                       ("G1X10", 22), ("G80G0X1", 21), ("G4", 28), ("T300", 38)]:
        with pytest.raises(GcodeError) as error:
            execute(line, ModalState(), (0.0, 0.0, 0.0))
        assert error.value.code == code, line
    block = execute("G2X10Y0I5J0F100", ModalState(), (0.0, 0.0, 0.0))
    assert block.segment.length == pytest.approx(3.14159265 * 5)
    assert block.segment.point_at(0.5) == pytest.approx((5.0, 5.0, 0.0))  # clockwise from (0,0) around (5,0)


def test_program_strips_comments_and_keeps_file_lines():
    program = parse_program(b"%\n(header)\nG21 ; mm\n\ng1 x10 (cut) y5 F3000\nN99 M5\n", "job.gcode")
    assert [(line.file_line, line.command) for line in program.lines] == [(3, "G21"), (5, "G1X10Y5F3000"), (6, "M5")]
    assert program.lines[1].wire == b"N5G1X10Y5F3000T2\n"
    assert [line_tag(i) for i in (-1, 0, 254, 255)] == [0, 1, 255, 1]


@pytest.mark.parametrize("data, message", [
    (b"G21\nG1 X1 Y2 F100 (\xe9)\n", r"job.gcode:2:16: non-ASCII byte 0xe9"),
    (b"G21\nG1 X" + b"1" * 80 + b"\n", r"job.gcode:2: line too long for the controller: \d+ characters"),
    (b"G21\nG1 X1 F100\nM6\n", r"job.gcode:3: error:20"),
    (b"G21\nT2\n", r"job.gcode:2: T words are not supported"),
    (b"G21\nG1 X1 F100 ?\n", r"job.gcode:2:12: '\?' is a GRBL real-time"),
    (b"G21\nG1 X5\n", r"job.gcode:2: error:22 \(feed rate has not yet been set"),
    (b"(nothing)\n", r"job.gcode: no G-code commands"),
])
def test_bad_programs_are_refused_before_anything_moves(data, message):
    with pytest.raises(FablineError, match=message):
        parse_program(data, "job.gcode")


def test_journal_replays_and_ignores_a_torn_last_record(tmp_path):
    path = tmp_path / "job.journal"
    with Journal(path) as journal:
        journal.record("start", program="p", sha256="abc", lines=10, mode="counting")
        for n in range(4):
            journal.record("sent", n=n, line=n + 1)
        for n in range(3):
            journal.record("ok", n=n, line=n + 1)
        journal.record("done", count=2)
    with open(path, "a") as handle:
        handle.write('{"event":"ok","n":3')  # the host died mid-write
    state = read_journal(path)
    assert (state.sent, state.acked, state.done, state.total, state.finished) == (4, 3, 2, 10, False)
    lines = path.read_text().splitlines()
    assert all(json.loads(line)["event"] for line in lines[:-1])


def test_journal_errors_are_one_line_messages(tmp_path):
    with pytest.raises(FablineError, match="no journal to resume from"):
        read_journal(tmp_path / "missing.journal")
    bad = tmp_path / "bad.journal"
    bad.write_text('{"event":"start","sha256":"a","lines":1}\nnot json\n{"event":"finished"}\n')
    with pytest.raises(FablineError, match=r"bad.journal:2: malformed journal record"):
        read_journal(bad)


def test_plain_lines_are_stripped_as_the_character_loop_strips_them():
    """strip_line's one-step path for lines without comments or refused characters gives what its character loop
    gives (or the same error), over random lines of G-code letters, whitespace (Unicode's too), % and specials."""
    import random

    from fabline.machine import program

    def by_loop(text: str) -> str:
        saved, program._PLAIN = program._PLAIN, re.compile(r"(?!)")
        try:
            return program.strip_line(text, "w")
        finally:
            program._PLAIN = saved

    rng = random.Random(1)
    alphabet = "G0123456789XYZ. \t%-+nNfF\x7f\x0b\u00e9;()?$\u00a0\u2028"
    for _ in range(20000):
        text = "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 12)))
        outcomes = []
        for strip in (lambda t: program.strip_line(t, "w"), by_loop):
            try:
                outcomes.append(strip(text))
            except FablineError as exc:
                outcomes.append(f"error: {exc}")
        assert outcomes[0] == outcomes[1], repr(text)
