"""G-code programs: Grbl line limits and words, fixed precision, header, determinism, machine profiles, timing."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from fabline.export import ToolpathOptions, check_program, export_job
from fabline.export import samplejob
from fabline.export.gcode import round_half_even
from fabline.machine import MoveLog, estimate_time, load_machine

from export_helpers import every_kind_nesting, every_kind_partset, gcodeparser, read_toolpaths

NUMBER = re.compile(r"[XYIJ](-?\d+\.\d+)")


def _export(machine="grbl-laser", kerf=0.2, **options):
    nesting, partset = every_kind_nesting(), every_kind_partset()
    profile = load_machine(machine)
    return export_job(nesting, {p.id: p for p in partset.parts}, profile, ToolpathOptions(kerf=kerf, **options),
                      name="job"), profile


@pytest.mark.parametrize("machine", ["grbl-laser", "grbl-plotter", "rs274-mill"])
def test_one_command_per_line_within_limits_and_only_profile_words(machine):
    result, profile = _export(machine)
    text = result.sheets[0].gcode
    lines = text.splitlines()
    assert text.endswith("\n") and text.isascii()
    assert max(len(line) for line in lines) <= profile.max_line_length <= 80
    used = set()
    for line in gcodeparser.parse_gcode_lines(text):
        letter, number = line.command
        assert letter in "GM"
        used.add(f"{letter}{number}")
    assert used <= profile.words
    for line in lines:
        if not line.startswith(";"):
            assert len(re.findall(r"\b[GM]\d+", line)) == 1, line          # one command per line
            for value in NUMBER.findall(line):
                assert len(value.split(".")[1]) == 3, line                    # fixed 0.001 mm precision


def test_laser_program_uses_m4_dynamic_power_within_the_s_range_and_says_it_needs_laser_mode():
    result, profile = _export("grbl-laser")
    text = result.sheets[0].gcode
    header = [line for line in text.splitlines() if line.startswith(";")][:8]
    assert any("$32=1" in line for line in header)
    assert any("job job" in line and "sheet S1" in line for line in header)
    assert any("A B C W K J" in line for line in header)
    powers = [float(m) for m in re.findall(r"^G[123] .*S(\d+\.?\d*)", text, re.M)]
    assert powers and all(profile.s_min <= s <= profile.s_max for s in powers)
    assert "M3" not in text
    runs = read_toolpaths(text)
    assert {r["power"] for r in runs if r["comment"].startswith("engrave")} == {250.0}
    assert {r["power"] for r in runs if r["comment"].startswith("cut")} == {1000.0}


def test_laser_mode_arms_the_laser_once_and_carries_the_power_on_cutting_moves():
    """Grbl syncs the planner on every M3/M4/M5, so a laser-mode program has one M4 S0 and one M5, cuts with S."""
    result, profile = _export("grbl-laser")
    lines = [line for line in result.sheets[0].gcode.splitlines() if not line.startswith(";")]
    assert [line for line in lines if line.startswith("M")] == ["M4 S0.000", "M5", "M2"]
    assert lines[:5] == ["G21", "G90", "G17", "G94", "M4 S0.000"]
    assert lines[-3:] == ["M5", "G0 X0 Y0", "M2"]
    assert not any(line.startswith("G0") and "S" in line for line in lines)
    speeds = [float(m) for line in lines for m in re.findall(r" S(\d+\.\d+)", line) if line.startswith("G")]
    assert all(a != b for a, b in zip(speeds, speeds[1:]))              # S written only when it changes
    assert set(speeds) == {250.0, 1000.0}
    report = check_program(result.sheets[0].gcode, profile)
    assert report.problems == []
    assert report.summary.time == pytest.approx(result.sheets[0].summary.time, rel=1e-9)


def test_laser_mode_estimate_has_no_stop_per_contour():
    """The same toolpaths with M4/M5 around each contour (laser mode off) take longer: a stop at every switch."""
    synced = dataclasses.replace(load_machine("grbl-laser"), laser_mode=False)
    nesting, partset = every_kind_nesting(), every_kind_partset()
    parts = {p.id: p for p in partset.parts}
    fast = export_job(nesting, parts, load_machine("grbl-laser"), ToolpathOptions(kerf=0.2)).sheets[0]
    slow = export_job(nesting, parts, synced, ToolpathOptions(kerf=0.2)).sheets[0]
    switches = slow.gcode.count("\nM5\n")
    assert switches > 20 and fast.gcode.count("\nM5\n") == 1
    assert fast.summary.cut_length == pytest.approx(slow.summary.cut_length)
    assert fast.summary.time < slow.summary.time
    report = check_program(slow.gcode, synced)                            # without laser mode G0 must be tool-off
    assert report.problems == []


def test_laser_on_travel_is_still_caught_in_a_hand_made_laser_mode_program():
    result, profile = _export("grbl-laser")
    lines = result.sheets[0].gcode.splitlines()
    comments = [k for k, line in enumerate(lines) if line.startswith("; cut-inner")]
    travel = comments[1] + 1
    assert lines[travel].startswith("G0 ")
    lines[travel] = "G1" + lines[travel][2:]                             # a G1 used as travel, laser at S1000
    report = check_program("\n".join(lines) + "\n", profile)
    assert len(report.problems) == 1
    assert report.problems[0].startswith(f"line {travel + 1}: travel with the laser on")
    synced = dataclasses.replace(profile, laser_mode=False)
    unsafe = check_program(result.sheets[0].gcode, synced).problems   # the same program on a Grbl without $32=1
    assert unsafe and all("travel move (G0) with the tool on" in p for p in unsafe)


def test_plotter_lifts_the_pen_between_paths_and_mill_plunges_per_pass():
    result, profile = _export("grbl-plotter", kerf=0.0)
    lines = result.sheets[0].gcode.splitlines()
    for k, line in enumerate(lines):
        if line.startswith("G0 ") and k > 0:
            pen = next(x for x in reversed(lines[:k]) if x.startswith("M3"))
            assert pen == "M3 S30.000", (k, line)
    result, profile = _export("rs274-mill", kerf=2.0)
    text = result.sheets[0].gcode
    assert "G1 Z-0.850 F300.000" in text and "G1 Z-1.700 F300.000" in text     # two passes to 1.7 mm
    assert text.count("G0 Z5.000") >= text.count("G1 Z-1.700 F300.000")


def test_same_input_gives_the_same_bytes(tmp_path):
    first, _ = _export()
    second, _ = _export()
    assert first.sheets[0].gcode == second.sheets[0].gcode


def test_estimated_time_matches_the_trapezoid_closed_form():
    """One 1000 mm move at 6000 mm/min, 800 mm/s^2 from rest to rest: L/v + v/a, and Grbl's $1 = 25 ms stepper
    lock each time the machine comes to rest."""
    lock = 0.025
    log = MoveLog()
    log.add((0.0, 0.0), (1000.0, 0.0), 6000.0, False, True, stop_before=True)
    assert estimate_time(log.table(), 800.0, 0.01) == pytest.approx(1000 / 100 + 100 / 800 + lock)
    assert estimate_time(log.table(), 800.0, 0.01, idle_lock=0.0) == pytest.approx(1000 / 100 + 100 / 800)
    short = MoveLog()                                   # too short to reach speed: a triangle profile
    short.add((0.0, 0.0), (4.0, 0.0), 6000.0, False, True)
    assert estimate_time(short.table(), 800.0, 0.01) == pytest.approx(2 * np.sqrt(4.0 / 800) + lock)
    corner = MoveLog()                                  # a 90 degree corner: the machine stops only where the rule says
    corner.add((0.0, 0.0), (500.0, 0.0), 6000.0, False, True)
    corner.add((500.0, 0.0), (500.0, 500.0), 6000.0, False, True)
    stop = MoveLog()
    stop.add((0.0, 0.0), (500.0, 0.0), 6000.0, False, True)
    stop.add((500.0, 0.0), (500.0, 500.0), 6000.0, False, True, stop_before=True)
    assert estimate_time(corner.table(), 800.0, 0.01) < estimate_time(stop.table(), 800.0, 0.01)
    assert estimate_time(stop.table(), 800.0, 0.01) == pytest.approx(2 * (5 + 100 / 800 + lock))


def test_the_stepper_lock_is_in_a_grbl_profiles_time_only():
    """gcode-check's time: Grbl holds its steppers $1 = 25 ms each time the machine comes to rest (before the M5's
    sync and at the end: 2 rests here); an RS-274/NGC controller has no such setting."""
    mill = load_machine("rs274-mill")
    text = "G21\nG90\nG1 X10 F600\nM5\nG1 X20\nM2\n"
    plain = check_program(text, mill).summary.time
    grbl = check_program(text, dataclasses.replace(mill, controller="Grbl 1.1")).summary.time
    assert grbl - plain == pytest.approx(2 * 0.025)
    assert plain == pytest.approx(2 * (10 / 10 + 10 / 500.0))


def test_marks_and_cuts_are_summarised_apart():
    result, _ = _export(kerf=0.0)
    summary = result.sheets[0].summary
    partset = every_kind_partset()
    marks = sum(np.hypot(*np.diff(m[:, :2], axis=0).T).sum() for p in partset.parts for m in p.marks + p.text)
    assert summary.mark_length == pytest.approx(marks, abs=1e-3)
    assert summary.cut_length > 0 and summary.travel > 0 and summary.time > 0


def test_pavilion_sample_job_has_the_asked_for_size():
    nesting, partset = samplejob.pavilion_job()
    kinds = [p.kind for p in partset.parts]
    assert kinds.count("strip") == 700 and kinds.count("washer") == 1400 and kinds.count("clamp") == 350
    lengths = [np.ptp(p.outline[:, 0]) for p in partset.parts if p.kind == "strip"]
    assert 500 <= min(lengths) and max(lengths) <= 3900
    assert 14 <= len(nesting.sheets) <= 22
    placed = [pl.part for s in nesting.sheets for pl in s.placements]
    assert sorted(placed) == sorted(p.id for p in partset.parts)


def test_whole_array_rounding_is_pythons_round():
    """Coordinates are rounded a sheet at a time; every value must read back as Python's round() makes it, also
    the halves that numpy's scaled rounding puts on the other side (628.3065 is 628.30650000000002...)."""
    rng = np.random.default_rng(7)
    values = np.concatenate([rng.uniform(-5000, 5000, 20000), np.round(rng.uniform(0, 4000, 5000), 4),
                             [628.3065, 0.0625, -0.0005, -0.0004, 2.675, 1.0005, -0.0]])
    expected = [round(v, 3) + 0.0 for v in values.tolist()]
    ours = round_half_even(values, 3).tolist()
    assert ours == expected
    assert [math.copysign(1.0, v) for v in ours] == [math.copysign(1.0, v) for v in expected]    # no -0.0
    assert (np.round(values, 3) != expected).any()                    # the case numpy alone gets wrong is covered


def test_junction_speeds_match_a_move_by_move_planner():
    """The planner's backward and forward passes, written the plain way (one junction at a time, as Grbl
    does), against the cumulative-minimum form estimate_time uses: random limits with stops, long and short moves."""
    from fabline.machine.motion import _reachable

    rng = np.random.default_rng(3)
    for moves in (1, 2, 50, 3000):
        limit = rng.uniform(0, 1e4, moves + 1) * (rng.random(moves + 1) > 0.1)  # squared speeds, some stops
        limit[0] = limit[-1] = 0.0
        gain = rng.exponential(2e3, moves) * (rng.random(moves) > 0.05)        # 2 a L, some zero-length moves
        speeds = limit.tolist()
        for i in range(moves - 1, -1, -1):
            speeds[i] = min(speeds[i], speeds[i + 1] + gain[i])
        for i in range(moves):
            speeds[i + 1] = min(speeds[i + 1], speeds[i] + gain[i])
        assert _reachable(limit, gain) == pytest.approx(speeds, rel=1e-9, abs=1e-6)
