"""The G-code interpreter against Grbl 1.1h: the real firmware's transcript, its command table and check order
(gnea/grbl gcode.c), closed-form positions under work offsets, and word splitting against pygcode."""

from __future__ import annotations

import math
import random
from pathlib import Path

import pytest
from pygcode.words import text2words

from fabline.machine.build import STOCK_BUILD, BuildInfo
from fabline.machine.gcode import GcodeError, ModalState, compact_line, execute, split_words

TRANSCRIPT = Path(__file__).parents[1] / "data" / "grbl-1.1h-transcript.txt"
START = (0.0, 0.0, 0.0)


def answer(line: str, modal: ModalState = ModalState(), position=START, build: BuildInfo = STOCK_BUILD) -> str:
    """What the firmware answers to one raw line from `modal` at `position`: ok or error:N."""
    try:
        execute(compact_line(line), modal, position, build=build)
    except GcodeError as exc:
        return f"error:{exc.code}"
    return "ok"


def run(lines: list[str], build: BuildInfo = STOCK_BUILD, position=START):
    """The blocks of a sequence of lines, each from the state the previous one left."""
    modal, blocks = ModalState(), []
    for line in lines:
        block = execute(compact_line(line), modal, position, build=build)
        modal, position = block.modal, block.position
        blocks.append(block)
    return blocks


def test_every_gcode_answer_of_the_real_firmware_transcript_is_reproduced():
    """Each host line gets exactly one ok or error:N, in order; the G-code lines' answers must match ours
    (error:9 is the alarm lock-out, not the parser; a soft reset or leaving check mode resets the parser)."""
    sent, answers = [], []
    for raw in TRANSCRIPT.read_text(encoding="ascii").splitlines():
        if raw.startswith(">>> "):
            sent.append(raw[4:].split("    #")[0])
        elif raw.startswith("<<< ") and (raw[4:] == "ok" or raw[4:].startswith("error:")):
            answers.append(raw[4:])
    assert len([line for line in sent if not line.startswith("realtime ")]) == len(answers)
    answer_of = iter(answers)
    modal, position, checking, checked = ModalState(), START, False, []
    for line in sent:
        if line.startswith("realtime "):
            modal = ModalState() if line == "realtime ctrl-x (soft reset)" else modal
            continue
        expected = next(answer_of)
        if line == "$C":
            modal = ModalState() if checking else modal
            checking = not checking
        if line.startswith("$") or expected == "error:9":
            continue
        try:
            block = execute(compact_line(line), modal, position)
            modal, position, got = block.modal, block.position, "ok"
        except GcodeError as exc:
            got = f"error:{exc.code}"
        checked.append(got)
        assert got == expected, line
    assert set(checked) >= {"ok", "error:20", "error:2", "error:25", "error:35", "error:11"}


@pytest.mark.parametrize("line", [
    "G0 X1", "G1 X1 F100", "G2 X2 Y0 I1 J0 F100", "G3 X2 Y0 R1 F100", "G4 P0.5", "G10 L2 P1 X0 Y0",
    "G10 L20 P0 X0", "G17", "G18", "G19", "G20", "G21", "G28", "G28 X0", "G28.1", "G30", "G30.1",
    "G38.2 Z-5 F100", "G38.3 Z-5 F100", "G38.4 Z-5 F100", "G38.5 Z-5 F100", "G40", "G43.1 Z2", "G49",
    "G53", "G53 G0 X1", "G53 G1 X1 F100", "G54", "G55", "G56", "G57", "G58", "G59", "G61", "G80", "G90", "G91",
    "G91.1", "G92 X0 Y0", "G92.1", "G93", "G94", "M0", "M1", "M2", "M30", "M3 S1000", "M4", "M5", "M8", "M9",
    "N10000000 G0 X1", "N0 G21", "T255", "T1.5", "G49.5",
])
def test_what_grbl_accepts_is_accepted(line):
    assert answer(line) == "ok"


@pytest.mark.parametrize("line, code", [
    ("G43 Z1", 20), ("G41", 20), ("G42", 20), ("G64", 20), ("G61.1", 20), ("G90.1", 20), ("G38.1 Z1 F1", 20),
    ("G28.2", 20), ("G92.2", 20), ("G81 X1", 20), ("G98", 20), ("M6", 20), ("M7", 20), ("M48", 20), ("M56", 20),
    ("G10 L3 P1 X0", 20), ("G10 P1 X0", 20), ("G10 L2 P1 R1 X0", 20), ("E1", 20), ("Q1", 20), ("A5", 20),
    ("G1.5", 23), ("G59.1", 23), ("M3.5", 23), ("G4.5 P1", 23), ("G0 G1 X1", 24), ("G92 G0 X1", 24),
    ("G43.1 G0 Z1", 24), ("G80 G0", 21), ("G17 G18", 21), ("M3 M5", 21), ("X1 X2", 25), ("F1 F2", 25),
    ("G1 X-1 F-5", 4), ("N-1", 4), ("S-2", 4), ("T-1", 4), ("G4 P-1", 4), ("T256", 38), ("N10000001", 27),
    ("N99999999", 27), ("G4", 28), ("G10 X1", 28), ("G10 L2 P7 X1", 29), ("G53 G2 X1 I1", 30),
    ("G80 X1", 31), ("G92", 26), ("G10 L2 P1", 26), ("G1 X1", 22), ("G2 X1 Y1", 22), ("G2 F100", 26),
    ("G17 G2 Z1 I1 F100", 32), ("G2 X0 Y0 R5 F100", 33), ("G2 X10 Y0 R2 F100", 34), ("G2 X2 Y0 K1 F100", 35),
    ("G2 X2 Y0 I3 F100", 33), ("G1 X1 R1 F100", 36), ("G0 X1 P1", 36), ("G38.2 X0 F100", 33), ("G43.1 X1", 37),
    ("G43.1 Z1 X1", 37), ("G1 X", 2), ("1X", 1), ("G0 X1 Y2 ; " + "x" * 100, "ok"), ("G1 X" + "1" * 80, 11),
])
def test_what_grbl_refuses_is_refused_with_its_error_code(line, code):
    assert answer(line) == (code if code == "ok" else f"error:{code}")


def test_mist_coolant_and_parking_override_follow_the_build_options():
    assert answer("M7") == "error:20" and answer("M56 P1") == "error:20"
    assert answer("M7", build=BuildInfo(options="VM")) == "ok"
    assert answer("M56 P0", build=BuildInfo(options="VR")) == "ok"
    blocks = run(["M8", "M7"], build=BuildInfo(options="VM"))
    assert blocks[-1].modal.coolant == "M7 M8" and "M7 M8" in blocks[-1].modal.report()
    assert run(["M7", "M9"], build=BuildInfo(options="VM"))[-1].modal.coolant == "M9"


def test_work_offsets_move_the_machine_like_the_firmware():
    """Machine = work + G54..G59 origin + G92 + tool length offset (Z); G53 is machine; L20 makes here = value."""
    start = (10.0, 20.0, 0.0)
    blocks = run(["G92 X0 Y0", "G0 X5 Y5", "G92.1", "G0 X5 Y5", "G10 L20 P1 X0 Y0", "G0 X1 Y1", "G53 G0 X1 Y1",
                  "G43.1 Z-2", "G0 Z0", "G49", "G0 Z0", "G10 L2 P2 X100 Y100", "G55 G0 X1 Y1", "G54 G0 X1 Y1"],
                 position=start)
    positions = [block.position for block in blocks]
    assert positions[1] == (15.0, 25.0, 0.0)           # G92 X0 Y0 at (10, 20): work 5 is machine 15
    assert positions[3] == (5.0, 5.0, 0.0)             # G92.1 clears the offset
    assert blocks[4].modal.systems[0] == (5.0, 5.0, 0.0) and positions[5] == (6.0, 6.0, 0.0)
    assert positions[6] == (1.0, 1.0, 0.0)             # G53: machine coordinates
    assert positions[8] == (1.0, 1.0, -2.0) and positions[10] == (1.0, 1.0, 0.0)
    assert positions[12] == (101.0, 101.0, 0.0) and positions[13] == (6.0, 6.0, 0.0)
    assert blocks[12].modal.work_offset == (100.0, 100.0, 0.0)
    assert [b.stored_reference for b in blocks] == ["G92", None, "G92.1", None, "G10", None, "G53", "G43.1", None,
                                                    "G49", None, "G10", None, None]


def test_g28_and_g30_go_through_the_intermediate_point_to_the_stored_position():
    blocks = run(["G0 X3 Y4", "G28.1", "G0 X1 Y1", "G28 X7", "G0 X9 Y9 Z1", "G28", "G91 G30 Z2"])
    assert blocks[1].modal.homes[0] == (3.0, 4.0, 0.0)
    g28 = blocks[3]
    assert g28.approach.end == (7.0, 1.0, 0.0) and g28.segment.end == (3.0, 1.0, 0.0) and g28.position == (3.0, 1.0, 0.0)
    assert blocks[5].approach is None and blocks[5].segment.end == (3.0, 4.0, 0.0)
    assert blocks[6].approach.end == (3.0, 4.0, 2.0) and blocks[6].position == (3.0, 4.0, 0.0)  # G30 stored at 0


def test_inverse_time_needs_f_on_every_feed_move_and_units_keep_the_feed():
    blocks = run(["G93 G1 X10 F2"])
    assert blocks[0].feed_rate == pytest.approx(20.0)      # 10 mm in 1/2 minute
    assert answer("G1 X20", blocks[0].modal, blocks[0].position) == "error:22"
    assert answer("G0 X20", blocks[0].modal, blocks[0].position) == "ok"
    assert answer("G94 G1 X20", blocks[0].modal, blocks[0].position) == "error:22"  # feed undefined after G93
    blocks = run(["G21 G1 X1 F1000", "G20 G1 X1"])
    assert blocks[1].feed_rate == pytest.approx(1000.0) and blocks[1].position == (25.4, 0.0, 0.0)
    assert blocks[1].modal.report().endswith("F1000 S0]")


def test_program_end_resets_the_modes_the_firmware_resets_and_m0_pauses():
    blocks = run(["G55 G91 G18 G93 M3 M8", "M30", "M0", "M1"])
    modal = blocks[1].modal
    assert (modal.motion, modal.coord, modal.plane, modal.distance, modal.feed_mode, modal.spindle, modal.coolant) == \
        ("G1", "G54", "G17", "G90", "G94", "M5", "M9")
    assert blocks[1].program_end and blocks[2].pause and not blocks[3].pause


def test_a_refused_line_and_a_tool_word_follow_the_firmware():
    blocks = run(["T7 G21", "G90"])
    assert blocks[0].modal.tool == 7 and blocks[1].modal.tool == 0   # gcode.c copies the block's T, 0 if none


def test_compact_line_keeps_what_the_firmware_keeps():
    assert compact_line("g1 x1 (a comment) y/2 ; tail (") == "G1X1Y2"
    assert compact_line("G1 X1 ! Y2 ?") == "G1X1Y2"         # real-time characters never reach the line
    assert len(compact_line("G1X" + "1" * 76)) == 79
    with pytest.raises(GcodeError, match="error:11"):
        compact_line("G1X" + "1" * 77)


def _number(rng: random.Random, letter: str) -> str:
    """A value in a form both Grbl and pygcode read: optional minus, digits, optional fraction (G and M: a code)."""
    if letter in "GM":
        return str(rng.randint(0, 99)) + rng.choice(["", "", ".1"])
    whole = str(rng.randint(0, 9999))
    if rng.random() < 0.5 and letter not in "NTL":   # pygcode reads N, T and L as integers
        whole += "." + str(rng.randint(0, 999)).zfill(rng.randint(1, 3))
    return ("-" if rng.random() < 0.3 and letter not in "NTL" else "") + whole


def test_word_splitting_agrees_with_pygcode():
    rng = random.Random(15)
    for _ in range(500):
        letters = [rng.choice("GMXYZIJKFSPRLNT") for _ in range(rng.randint(1, 8))]
        line = "".join(letter + _number(rng, letter) for letter in letters)
        expected = [(word.letter, float(word.value)) for word in text2words(line)]
        got = split_words(line)
        assert [w[0] for w in got] == [w[0] for w in expected], line
        assert all(math.isclose(a[1], b[1]) for a, b in zip(got, expected)), line


def test_a_point_on_an_arc_is_told_by_its_radius_sweep_and_rise():
    """Segment.contains for a helical quarter arc of radius 10 about (0, 0) from (10, 0, 0) to (0, 10, 5), counter-
    clockwise: points by the closed form (10 cos t, 10 sin t, 5 t / (pi/2)) are on it, and not off the radius, past
    the sweep (the other three quarters of the circle) or off the rise."""
    from fabline.machine.gcode import Segment

    arc = Segment((10.0, 0.0, 0.0), (0.0, 10.0, 5.0), rapid=False, center=(0.0, 0.0, 0.0))
    for t in (0.1, 0.7, 1.3):
        assert arc.contains((10 * math.cos(t), 10 * math.sin(t), 5 * t / (math.pi / 2)), 0.01)
        assert not arc.contains((10.02 * math.cos(t), 10.02 * math.sin(t), 5 * t / (math.pi / 2)), 0.01)
        assert not arc.contains((10 * math.cos(t), 10 * math.sin(t), 5 * t / (math.pi / 2) + 0.02), 0.01)
    for t in (2.0, 3.5, 5.5, -0.05):
        assert not arc.contains((10 * math.cos(t), 10 * math.sin(t), 0.0), 0.01)
    clockwise = Segment((10.0, 0.0, 0.0), (0.0, 10.0, 0.0), rapid=False, center=(0.0, 0.0, 0.0), clockwise=True)
    assert clockwise.contains((0.0, -10.0, 0.0), 0.01) and not clockwise.contains((7.071, 7.071, 0.0), 0.01)
