"""`gcode-check` accepts what Grbl 1.1h accepts, refuses what it refuses (with its error code), and measures the
moves of every accepted code as the firmware makes them.

Truth: the G-code set of gnea/grbl `doc/markdown/commands.md` ("Grbl v1.1 Commands", the modal-group table:
G0 G1 G2 G3 G38.2-G38.5 G80, G54-G59, G17-G19, G90 G91, G91.1, G93 G94, G20 G21, G40, G43.1 G49, M0 M1 M2 M30,
M3 M4 M5, M7 M8 M9, M56) and the non-modal commands of `grbl/gcode.c` (G4, G10 L2/L20, G28 G30 G28.1 G30.1, G53,
G92 G92.1); the error numbers of `gc_execute_line` in gcode.c, read case by case (noted per case); the captured
exchange tests/data/grbl-1.1h-transcript.txt where it covers a case; lengths and positions worked out by hand.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
from pathlib import Path

import pytest

from fabline.export import check_program
from fabline.link.simulator import GrblSimulator
from fabline.machine import load_machine
from fabline.machine.build import BuildInfo

LASER = load_machine("grbl-laser")
TRANSCRIPT = Path(__file__).parents[1] / "data" / "grbl-1.1h-transcript.txt"
START = "G21\nG90\nG0 X10 Y10\n"   # every case starts at machine (10, 10, 0), feed not yet set

DOCUMENTED = [  # (code, a minimal line using it, the build options it needs)
    ("G0", "G0 X20 Y20", "V"), ("G1", "G1 X20 Y20 F600", "V"),
    ("G2", "G2 X20 Y10 I5 J0 F600", "V"), ("G3", "G3 X20 Y10 I5 F600", "V"),
    ("G38.2", "G38.2 Z-5 F100", "V"), ("G38.3", "G38.3 Z-5 F100", "V"),
    ("G38.4", "G38.4 Z-5 F100", "V"), ("G38.5", "G38.5 Z-5 F100", "V"), ("G80", "G80", "V"),
    ("G54", "G54", "V"), ("G55", "G55", "V"), ("G56", "G56", "V"), ("G57", "G57", "V"), ("G58", "G58", "V"),
    ("G59", "G59", "V"), ("G17", "G17", "V"), ("G18", "G18", "V"), ("G19", "G19", "V"),
    ("G90", "G90", "V"), ("G91", "G91", "V"), ("G91.1", "G91.1", "V"), ("G93", "G93", "V"), ("G94", "G94", "V"),
    ("G20", "G20", "V"), ("G21", "G21", "V"), ("G40", "G40", "V"), ("G43.1", "G43.1 Z1", "V"), ("G49", "G49", "V"),
    ("M0", "M0", "V"), ("M1", "M1", "V"), ("M2", "M2", "V"), ("M30", "M30", "V"),
    ("M3", "M3 S100", "V"), ("M4", "M4 S100", "V"), ("M5", "M5", "V"),
    ("M7", "M7", "VM"), ("M8", "M8", "V"), ("M9", "M9", "V"), ("M56", "M56 P1", "VR"),
    ("G4", "G4 P0.5", "V"), ("G10 L2", "G10 L2 P1 X0 Y0", "V"), ("G10 L20", "G10 L20 P2 X0 Y0", "V"),
    ("G28", "G28", "V"), ("G30", "G30", "V"), ("G28.1", "G28.1", "V"), ("G30.1", "G30.1", "V"),
    ("G53", "G53 G0 X0 Y0", "V"), ("G92", "G92 X0 Y0", "V"), ("G92.1", "G92.1", "V"),
    # the value words F I J K L N P R S T X Y Z (F I J L P S X Y Z above)
    ("K", "G18 G2 X20 Z0 I5 K0 F600", "V"), ("N", "N10 G1 X20 F600", "V"), ("R", "G2 X20 Y10 R5 F600", "V"),
    ("T", "T1", "V"),
]


@pytest.mark.parametrize("code, line, options", DOCUMENTED, ids=[case[0] for case in DOCUMENTED])
def test_every_documented_grbl_code_passes(code, line, options):
    report = check_program(START + line + "\n", LASER, build=BuildInfo(options=options))
    assert report.problems == []
    named = code.split()[0]
    if named[0] in "GM" and named not in LASER.words:      # accepted, but not a code the laser exporter writes
        assert any(w.startswith(f"{named} (line 4): the controller accepts it") for w in report.warnings)


REFUSED = [  # (line, Grbl's error, where gcode.c (or the transcript) says so)
    ("G41", 20, "G41/G42 fall to the default case: unsupported G command"),
    ("G42", 20, "as G41"),
    ("G43 Z1", 20, "case 43 without mantissa 10: unsupported G43.x"),
    ("G61.1", 20, "case 61 with a mantissa: G61.1 not supported"),
    ("G64", 20, "default case"),
    ("G81 X1 Y1 Z-1 R1 F100", 20, "canned cycles: default case"),
    ("M6", 20, "M switch default: unsupported M command"),
    ("M7", 20, "case 7 only with ENABLE_M7, off in a stock build"),
    ("M56", 20, "case 56 only with ENABLE_PARKING_OVERRIDE_CONTROL"),
    ("G59.1", 23, "case 59 is a coordinate system; the mantissa left over: value not integer"),
    ("G1.5 X1", 23, "case 1, mantissa 50 left over"),
    ("M3.5", 23, "no Mxx.x commands"),
    ("G4.1 P1", 23, "case 4 keeps its mantissa"),
    ("G90.1", 20, "G90.1 not supported"),
    ("G91.2", 20, "mantissa other than 10"),
    ("G38.1 Z-1 F100", 20, "G38 mantissa not 20, 30, 40, 50"),
    ("G28.2", 20, "G28 mantissa not 0 or 10"),
    ("G17 G18", 21, "modal group violation"),
    ("M3 M5", 21, "modal group violation"),
    ("G0 G1 X20", 24, "a second motion command is an axis command conflict, checked before the group"),
    ("G92 G0 X1", 24, "G92 then G0: axis command conflict"),
    ("X1 X2", 25, "transcript: repeated axis word"),
    ("G1 X20 F600 F700", 25, "repeated F"),
    ("G1 X20 F-600", 4, "negative F"),
    ("T256", 38, "tool number above 255"),
    ("N10000001 G0 X20", 27, "line number above 10,000,000"),
    ("G1 X20", 22, "no feed rate yet"),
    ("G93 G1 X20 F600\nG1 X30", 22, "G93: every feed move needs its F"),
    ("G92", 26, "G92 without axis words"),
    ("G10 L2 P1", 26, "G10 without axis words"),
    ("G10 X0", 28, "G10 without P and L"),
    ("G10 L3 P1 X0", 20, "unsupported L"),
    ("G10 L2 P7 X0", 29, "P above the six coordinate systems"),
    ("G10 L2 P1 R1 X0", 20, "G10 L2 R not supported"),
    ("G4", 28, "dwell without P"),
    ("G53 G2 X20 I5 F600", 30, "G53 needs G0 or G1"),
    ("G80 X20", 31, "axis words with G80"),
    ("G18 G2 Y20 I5 F600", 32, "G18 arc without X or Z"),
    ("G18 G2 X20 J5 F600", 35, "G18 arc with X but only a J offset (not in the ZX plane)"),
    ("G2 X10 F600", 35, "transcript: arc without radius or offset"),
    ("G2 X20 Y10 I4 F600", 33, "radius to the target differs by 2 mm: invalid target"),
    ("G2 X40 Y10 R5 F600", 34, "radius smaller than half the chord"),
    ("G1 X20 F600 I5", 36, "unused I"),
    ("G43.1 X1", 37, "G43.1 on an axis other than Z"),
    ("G1 X10 Q5", 20, "transcript: unsupported word Q"),
    ("G99", 20, "transcript: unsupported command"),
    ("FOO", 2, "transcript: bad letter (O without a value)"),
    ("E1 NONSENSE", 20, "word by word: E is unsupported before the malformed O is reached"),
    ("G1 X10 $1", 1, "'$' where a word letter is expected"),
    ("G1 X10 Y10 Z", 2, "transcript: value missing"),
    ("G1 X" + "1" * 80, 11, "transcript: line over 80 characters (there X and 80 ones)"),
]


@pytest.mark.parametrize("line, error, why", REFUSED, ids=[case[0].replace("\n", " ")[:24] for case in REFUSED])
def test_codes_grbl_refuses_are_problems_with_its_error_code(line, error, why):
    report = check_program(START + line + "\n", LASER)
    number = 3 + line.count("\n") + 1
    assert [p.split(" (")[0] for p in report.problems] == [f"line {number}: error:{error}"], why


def test_the_checker_answers_the_transcripts_gcode_lines_as_the_real_firmware_did():
    """Every G-code line sent to the real Grbl 1.1h, in order, and its answer (`ok` or `error:N`; error:9, the
    alarm lock, is the machine's state, not the line's): the checker reads the same lines as one program."""
    sent, answers = [], []
    for raw in TRANSCRIPT.read_text(encoding="ascii").splitlines():
        if raw.startswith(">>> ") and not raw.startswith(">>> realtime"):
            sent.append(raw[4:].split("    #")[0])
        elif re.fullmatch(r"<<< (ok|error:\d+)", raw):
            answers.append(raw[4:])
    assert len(sent) == len(answers)
    lines = [(line, answer) for line, answer in zip(sent, answers) if not line.startswith("$") and answer != "error:9"]
    assert len(lines) == 15 and sum(answer != "ok" for _, answer in lines) == 8
    report = check_program("\n".join(line for line, _ in lines) + "\n", LASER)
    verdicts = [(int(p.split(":")[0][5:]), p.split(": ")[1].split(" (")[0]) for p in report.problems]
    assert verdicts == [(number, answer) for number, (_, answer) in enumerate(lines, start=1) if answer != "ok"]


def test_an_88_character_comment_passes_and_a_90_character_line_of_words_is_error_11():
    """Grbl strips spaces and comments before its 80-byte line buffer (protocol.c): only what is left counts."""
    comment = "G1 X20 Y20 F600 ; " + "x" * 70
    brackets = "G1 X30 Y30 (" + "y" * 70 + ") F600"
    words = "G1 X1." + "0" * 40 + " Y1." + "0" * 40      # 90 characters, 88 without the spaces
    assert (len(comment), len(brackets), len(words), len(words.replace(" ", ""))) == (88, 88, 90, 88)
    report = check_program(START + "\n".join([comment, brackets, words]) + "\n", LASER)
    assert report.problems == ["line 6: error:11 (max characters per line exceeded; line was not processed and "
                               "executed): 88 characters once spaces and comments are removed, Grbl's line buffer "
                               "holds 79"]
    at_limit = "G0X1." + "0" * 74                           # 79 characters: the most the buffer holds
    assert check_program(START + at_limit + "\n", LASER).problems == []
    assert check_program(START + at_limit + "0\n", LASER).problems[0].startswith("line 4: error:11")


def test_a_tighter_max_line_length_of_the_profile_applies_to_the_same_count():
    tight = dataclasses.replace(LASER, max_line_length=40)
    line = "G1 X1." + "0" * 20 + " Y1." + "0" * 20 + " F600 ; a comment that does not count"
    assert check_program(START + line + "\n", tight).problems == [
        "line 4: 52 characters once spaces and comments are removed, over the profile's max_line_length of 40"]
    assert check_program(START + line + "\n", LASER).problems == []


def test_simulator_and_checker_agree_with_the_firmware_on_comments_and_the_line_buffer():
    """The simulator's line buffer drops `;` comments and `/` as Grbl's protocol loop does: the 88-character
    comment line is ok, 80 characters of words are error:11 (transcript: `G1 X111...` over 80)."""
    lines = ["G1 X20 Y20 F600 ; " + "x" * 70, "G1 X21 ; (" + "z" * 80, "/G1 X22", "G0X1." + "0" * 74,
             "G0X1." + "0" * 75]
    simulator = GrblSimulator(time_scale=1.0)
    try:
        simulator.attach()
        answers = []
        for line in ["$C"] + lines:
            simulator.receive(line.encode("ascii") + b"\n")
            answers += _answers(simulator)
    finally:
        simulator.close()
    assert answers == ["[MSG:Enabled]", "ok", "ok", "ok", "ok", "ok", "error:11"]
    report = check_program("G21\nG90\n" + "\n".join(lines) + "\n", LASER)
    assert [p.split(" (")[0] for p in report.problems] == ["line 7: error:11"]


def _answers(simulator: GrblSimulator) -> list[str]:
    """The answer lines of one sent line, up to its ok or error."""
    text, deadline = b"", time.monotonic() + 5
    while not text.endswith((b"ok\r\n",)) and b"error:" not in text and time.monotonic() < deadline:
        text += simulator.read(256, 0.05)
    while b"error:" in text and not text.endswith(b"\r\n"):
        text += simulator.read(256, 0.05)
    return text.decode("ascii").split("\r\n")[:-1]


def _lengths(program: str, profile=LASER) -> tuple:
    report = check_program(program, profile)
    s = report.summary
    return report.problems, round(s.cut_length, 3), round(s.travel, 3), s.time


def test_g92_offsets_moves_and_g92_1_clears_them():
    # G0 to (100, 100); G92 makes it work (0, 0); G1 X-50 is machine (50, 100): 50 mm, inside the bed.
    # G92.1 clears the offset: G1 X10 Y10 is machine (10, 10), hypot(40, 90) = 98.489 mm further.
    problems, cut, travel, _ = _lengths("G21\nG90\nM4 S500\nG0 X100 Y100\nG92 X0 Y0\nG1 X-50 Y0 F600\n"
                                        "G92.1\nG1 X10 Y10\nM5\n")
    assert problems == [] and cut == pytest.approx(50 + math.hypot(40, 90), abs=1e-3)
    assert travel == pytest.approx(math.hypot(100, 100), abs=1e-3)


def test_g53_moves_in_machine_coordinates_for_one_move():
    # G92 puts work (0, 0) at machine (100, 100); G53 G0 X50 Y50 goes to machine (50, 50): hypot(50, 50);
    # the next G1 X10 Y0 is work (10, 0) again, machine (110, 100): hypot(60, 50) of cut.
    problems, cut, travel, _ = _lengths("G21\nG90\nG0 X100 Y100\nG92 X0 Y0\nM4 S500\nG53 G0 X50 Y50\n"
                                        "G1 X10 Y0 F600\nM5\n")
    assert problems == [] and cut == pytest.approx(math.hypot(60, 50), abs=1e-3)
    assert travel == pytest.approx(math.hypot(100, 100) + math.hypot(50, 50), abs=1e-3)


def test_g10_work_offsets_l20_and_l2():
    # At machine (200, 100), G10 L20 P1 X0 Y0 makes it G54's origin: G1 X-100 Y0 is machine (100, 100), 100 mm.
    # G10 L2 P1 X50 Y0 sets the origin to machine (50, 0): G0 X0 Y0 goes there, hypot(50, 100) of travel.
    problems, cut, travel, _ = _lengths("G21\nG90\nG0 X200 Y100\nG10 L20 P1 X0 Y0\nM4 S500\nG1 X-100 Y0 F600\n"
                                        "G10 L2 P1 X50 Y0\nG0 X0 Y0\nM5\n")
    assert problems == [] and cut == pytest.approx(100, abs=1e-3)
    assert travel == pytest.approx(math.hypot(200, 100) + math.hypot(50, 100), abs=1e-3)


def test_g28_and_g30_go_to_the_stored_position_through_the_intermediate_point():
    # From (100, 100): G28 X150 goes to (150, 100), then home on X only (stored 0, 0, 0): (0, 100): 50 + 150.
    # G30 alone goes straight to its stored (0, 0): 100. G28.1 at (300, 200) stores it; from (0, 0) G28 goes
    # there: hypot(300, 200). Travel in all: 141.421 + 200 + 100 + 360.555 (to 300, 200) + 360.555 + 360.555.
    problems, cut, travel, _ = _lengths("G21\nG90\nG0 X100 Y100\nG28 X150\nG30\nG0 X300 Y200\nG28.1\n"
                                        "G0 X0 Y0\nG28\n")
    assert problems == [] and cut == 0
    assert travel == pytest.approx(math.hypot(100, 100) + 200 + 100 + 3 * math.hypot(300, 200), abs=1e-3)


def test_g28_with_the_laser_on_in_feed_mode_is_travel_with_the_tool_on():
    """Grbl's laser mode disables the laser only when the motion mode is not G1-G3; G28 keeps the mode."""
    problems, _, _, _ = _lengths("G21\nG90\nM4 S500\nG1 X100 Y100 F600\nG28\nG1 X50 Y50\nG30 X20\nM5\n")
    assert problems == ["line 5: travel move (G28) with the tool on", "line 7: travel move (G30) with the tool on"]
    problems, _, _, _ = _lengths("G21\nG90\nM4 S500\nG1 X100 Y100 F600\nG0 X50\nG28\nM5\n")
    assert problems == []                                        # in G0 mode the laser is off, G28 too


def test_g93_inverse_time_feed_takes_1_over_f_minutes_per_move():
    # G93 F2: 20 mm in 1/2 minute = 30 s (at 40 mm/min the 800 mm/s^2 ramps take microseconds).
    # Then G94 F600: 20 mm more at 600 mm/min = 2 s.
    _, cut, _, seconds = _lengths("G21\nG90\nM4 S500\nG93\nG1 X20 F2\nG94\nG1 X40 F600\nM5\n")
    assert cut == pytest.approx(40, abs=1e-3) and seconds == pytest.approx(32.0, abs=0.02)


def test_g20_inches_scale_positions_and_feeds():
    # G20: X1 is 25.4 mm, F10 is 254 mm/min: 6 s.
    _, cut, _, seconds = _lengths("G20\nG90\nM4 S500\nG1 X1 F10\nM5\n")
    assert cut == pytest.approx(25.4, abs=1e-3) and seconds == pytest.approx(6.0, abs=0.02)


def test_g91_1_arcs_and_an_arc_in_the_zx_plane():
    # G91.1 (IJK incremental, Grbl's only mode): from (10, 10) G2 X20 Y10 I5 is a half circle of radius 5 over
    # the top (y up to 15): 5 pi. G18 G2 X30 Z0 I5 K0 from (20, 10, 0): a half circle in the ZX plane whose XY
    # shadow is the 10 mm along X.
    problems, cut, _, _ = _lengths(START + "M4 S500\nG91.1\nG2 X20 Y10 I5 F600\nG18\nG2 X30 Z0 I5 K0\nM5\n")
    assert problems == [] and cut == pytest.approx(5 * math.pi + 10, abs=2e-3)
    problems, _, _, _ = _lengths("G21\nG90\nG0 X10 Y2\nM4 S500\nG3 X20 Y2 I5 F600\n")   # G3: under the centre, to y -3
    assert problems == ["line 5: move reaches x 10.000..20.000, y -3.000..2.000 mm, outside the bed "
                        "(0..4100 x 0..2100 mm)"]


def test_g43_1_tool_length_offset_moves_z_for_a_mill():
    """A Grbl mill cuts below work Z 0: with G43.1 Z10, machine Z 5 (G53) is work Z -5."""
    mill = dataclasses.replace(LASER, mode="mill", laser_mode=False)
    _, cut, travel, _ = _lengths("G21\nG90\nG0 Z5\nG43.1 Z10\nG53 G1 X50 Z5 F600\nG49\nG1 X100\n", mill)
    assert cut == pytest.approx(50, abs=1e-3)     # G49 clears the offset: Z 5 is above the work again
    assert travel == pytest.approx(50, abs=1e-3)


def test_g40_g61_g49_pass_and_change_nothing():
    base = "G21\nG90\nM4 S500\nG1 X30 Y40 F600\nM5\n"
    assert _lengths("G40\nG49\nG61\n" + base) == _lengths(base)
    problems, cut, _, _ = _lengths(base)
    assert problems == [] and cut == pytest.approx(50, abs=1e-3)


def test_the_warning_names_each_unexpected_code_once_with_its_first_lines():
    program = START + "G40\nG1 X20 F600\n" * 15 + "G61\n"
    report = check_program(program, LASER)
    assert report.problems == []
    assert report.warnings == [
        "G40 (lines 4, 6, 8 and 12 more): the controller accepts it, but grbl-laser's exporter never writes it "
        "(not in the profile's words)",
        "G61 (line 34): the controller accepts it, but grbl-laser's exporter never writes it (not in the profile's "
        "words)"]


def test_gcode_check_warns_on_stderr_and_exits_0_for_codes_it_accepts(cli, tmp_path):
    path = tmp_path / "header.gcode"
    path.write_text("G21 G90 G40 G49 G61 G91.1 G94 G54\nG0 X10 Y10\nM4 S500\nG1 X20 F600\nM5\nM2\n")
    code, out, err = cli("gcode-check", path, "--machine", "grbl-laser")
    assert code == 0 and out.strip().endswith(": ok")
    assert [line.split(" (")[0] for line in err.splitlines()] == [
        f"fabline gcode-check: warning: {path}: {c}" for c in ("G40", "G49", "G61", "G91.1", "G54")]
