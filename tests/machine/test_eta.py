"""Machine time: the planner's estimate and the simulator's motion against hand-computed trapezoids, and the ETA
rule (planned time corrected by the pace made) that the stream bar, `fabline run`, the report and the runner use."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fabline.link.simulator import DEFAULT_SETTINGS, timed_run
from fabline.machine.gcode import ModalState
from fabline.machine.motion import MoveLog, estimate_time, line_timeline
from fabline.machine.program import parse_program
from fabline.progress import estimate, simulated_speedup
from fabline.units import duration

A = 800.0          # mm/s^2, $120 = $121
DEVIATION = 0.01   # mm, $11
RATE = 6000.0      # mm/min, $110 = $111
SETTINGS = {120: A, 121: A, 110: RATE, 111: RATE, 11: DEVIATION}


def planned(lines: list[str], planner_blocks: int = 15) -> float:
    """The estimate for a program's lines, read back through the firmware's interpreter."""
    program = parse_program(("\n".join(lines) + "\n").encode("ascii"), "test.gcode")
    timeline = line_timeline(program.plan(ModalState(), (0.0, 0.0, 0.0)), {**DEFAULT_SETTINGS, **SETTINGS}, planner_blocks)
    return float(timeline[-1])


def simulated(lines: list[str]) -> float:
    return timed_run(lines, settings=SETTINGS)[-1][1]


def corner_time() -> float:
    """Two 50 mm legs at 10 mm/s around a right angle, by hand: Grbl limits the junction's acceleration per axis
    along the turn (-1, 1)/sqrt 2, so a_j = a sqrt 2; v_j^2 = a_j delta sin(theta/2) / (1 - sin(theta/2))."""
    v, a_j, s = 10.0, A * math.sqrt(2), math.sin(math.pi / 4)
    vj2 = a_j * DEVIATION * s / (1 - s)
    leg = 50.0 - v * v / (2 * A) - (v * v - vj2) / (2 * A)   # cruise of one leg
    return 2 * (v / A + (v - math.sqrt(vj2)) / A + leg / v)


HAND = [
    (["G1X100F600"], 100 / 10 + 10 / A),                       # reaches 10 mm/s: L/v + v/a
    (["G1X1F6000"], 2 * math.sqrt(1 / A)),                     # 1 mm cannot reach 100 mm/s: a triangle
    (["G1X50F600", "G1Y50"], corner_time()),
    (["G1X100Y100F6000"], math.hypot(100, 100) / 100 + 100 / (A * math.sqrt(2))),  # diagonal: a sqrt 2 per axis limit
    (["G4P1.5", "G1X100F600"], 1.5 + 100 / 10 + 10 / A),
    (["G0X100Y100"], 1.0 + 100 / A),   # a diagonal rapid: 100 mm/s per axis is 141 mm/s along it, a sqrt 2 too
]


@pytest.mark.parametrize("lines,seconds", HAND)
def test_the_estimate_matches_hand_computed_trapezoids(lines, seconds):
    assert planned(lines) == pytest.approx(seconds, rel=1e-9)


@pytest.mark.parametrize("lines,seconds", HAND)
def test_the_simulator_takes_the_hand_computed_time(lines, seconds):
    assert simulated(lines) == pytest.approx(seconds, rel=1e-6)


def test_the_corner_is_slower_than_straight_on_and_faster_than_a_stop():
    straight = 100 / 10 + 10 / A
    stop = 2 * (50 / 10 + 10 / A)
    assert straight < corner_time() < stop


def test_a_planner_of_15_blocks_limits_the_speed_of_short_moves():
    """1000 chords of 0.1 mm straight on at F6000: with 15 blocks in the planner the machine must be able to stop
    within the 14 after the one it runs: every junction at sqrt(2 a 1.4 mm) = 47.3 mm/s, not 100 mm/s; within a
    chord it speeds up to sqrt(v^2 + a L) and back; the ramps at either end add v / a."""
    lines = [f"G1X{(i + 1) * 0.1:.1f}F6000" for i in range(1000)]
    junction = math.sqrt(2 * A * 14 * 0.1)
    per_chord = 2 * (math.sqrt(junction ** 2 + A * 0.1) - junction) / A
    by_hand = 1000 * per_chord + junction / A
    assert simulated(lines) == pytest.approx(by_hand, rel=0.002)
    assert planned(lines) == pytest.approx(simulated(lines), rel=1e-6)
    assert planned(lines, planner_blocks=10 ** 6) == pytest.approx(100 / 100 + 100 / A, rel=1e-6)


def test_arcs_run_as_chords_of_the_arc_tolerance():
    """A full circle of r = 5 mm at F600: floor(0.5 * 2 pi r / sqrt(tol (2 r - tol))) = 111 chords (Grbl's mc_arc);
    the junction rule lets them run at 10 mm/s, so the time is the chords' length at 10 mm/s plus the ramps."""
    lines = ["G0X10Y5", "G4P1", "G2X10Y5I-5J0F600"]  # the dwell stops the machine before the circle
    chords = math.floor(0.5 * 2 * math.pi * 5 / math.sqrt(0.002 * (10 - 0.002)))
    assert chords == 111
    chord = 2 * 5 * math.sin(math.pi / chords)
    simulated_circle = simulated(lines) - simulated(lines[:2])
    assert simulated_circle == pytest.approx(chords * chord / 10 + 10 / A, rel=1e-3)
    assert planned(lines) == pytest.approx(simulated(lines), rel=1e-6)


def test_the_move_table_estimate_agrees_with_the_program_timeline():
    log = MoveLog()
    log.add((0.0, 0.0), (50.0, 0.0), 600.0, False, True)
    log.add((50.0, 0.0), (50.0, 50.0), 600.0, False, True)
    lock = 0.025  # Grbl's $1: the steppers hold 25 ms when the machine comes to rest at the end
    assert estimate_time(log.table(), A, DEVIATION, max_rate=RATE) == pytest.approx(corner_time() + lock, rel=1e-9)


def test_the_timeline_maps_lines_to_planned_time():
    lines = ["G21", "G1X100F600", "G4P2", "G1X0"]
    program = parse_program(("\n".join(lines) + "\n").encode("ascii"), "t.gcode")
    timeline = line_timeline(program.plan(ModalState(), (0.0, 0.0, 0.0)), {**DEFAULT_SETTINGS, **SETTINGS})
    leg, lock = 100 / 10 + 10 / A, 0.025  # the dwell waits for the $1 stepper lock after the first leg
    assert timeline == pytest.approx([0.0, leg, leg + lock + 2, 2 * leg + lock + 2])
    completed = [seconds for _, seconds in timed_run(lines, settings=SETTINGS)]
    assert completed == pytest.approx(timeline.tolist())


def test_eta_is_the_planned_rest_at_the_planned_pace():
    assert estimate(100.0, 0.0, 0.0).remaining == pytest.approx(100.0)
    on_plan = estimate(100.0, 40.0, 40.0)
    assert on_plan.remaining == pytest.approx(60.0) and on_plan.total == pytest.approx(100.0)


def test_eta_follows_a_machine_slower_than_planned():
    """A machine that takes twice the planned time: the estimate moves towards twice the planned rest as work is done
    (the pace shrunk towards the plan by a 5 % prior), and is exact once most of the work is done."""
    early, late = estimate(1000.0, 100.0, 200.0), estimate(1000.0, 900.0, 1800.0)
    assert 900 * 2 > early.remaining > 900 * 1.5
    assert late.remaining == pytest.approx(100 * (1800 + 50) / (900 + 50))
    assert late.pace == pytest.approx(2.0, rel=0.03)


def test_eta_is_not_swung_by_a_start_up_delay():
    """Ten seconds of homing before the first planned second of a 10-hour job: the ETA moves by the prior's share,
    not by a factor of ten."""
    eta = estimate(36000.0, 1.0, 10.0)
    assert eta.remaining == pytest.approx(35999.0 * (10 + 1800) / (1 + 1800))
    assert eta.remaining < 36000 * 1.01


def test_duration_and_simulated_speedup():
    assert duration(161206) == "44:46:46" and duration(59.6) == "0:01:00" and duration(-0.4) == "0:00:00"
    assert simulated_speedup("sim://grbl-1?time_scale=2000&log=x") == 2000.0
    assert simulated_speedup("/dev/ttyUSB0") == 1.0 and simulated_speedup("sim://grbl") == 1.0
    assert np.isfinite(estimate(0.0, 0.0, 5.0).remaining)


def test_the_stream_progress_carries_the_planned_eta(tmp_path):
    """The streamer's progress reports time from the controller's own settings ($$) and the simulator's time scale:
    planned = the program's timeline / time scale; at the end everything planned is done."""
    from fabline.link import Streamer
    from fabline.link.protocol_sim import close_simulator
    from fabline.machine import load_program

    path = tmp_path / "square.gcode"
    path.write_text("G21\nG90\nM4 S0\n" + "".join(f"G1 X{x} Y{y} F3000 S500\n" for x, y in
                                                ((20, 0), (20, 20), (0, 20), (0, 0)) * 5) + "M5\n", encoding="ascii")
    reports = []
    url = "sim://eta-stream?time_scale=50&settings=32:1,120:200,121:200"
    try:
        Streamer(url, status_interval=0.02).run(path, on_progress=reports.append)
    finally:
        close_simulator("eta-stream")
    program = load_program(path)
    timeline = line_timeline(program.plan(ModalState(), (0.0, 0.0, 0.0)),
                             {**DEFAULT_SETTINGS, 32: 1, 120: 200.0, 121: 200.0})
    last = reports[-1].eta
    assert last.planned == pytest.approx(timeline[-1] / 50)
    assert last.planned_done == pytest.approx(last.planned) and last.remaining == pytest.approx(0.0)
    assert reports[-1].remaining == last.remaining


def test_the_runner_page_eta_of_a_job(tmp_path):
    """job_eta: the current sheet's elapsed and remaining and the job's, from each sheet's planned timeline and the
    pace so far, in the machine's time (the simulator's time scale applied)."""
    import time

    from fabline.jobs.queue import SheetRow
    from fabline.jobs.streaming import program_timeline
    from fabline.jobs.web import Timelines, job_eta

    programs = []
    for k in range(2):
        path = tmp_path / f"s{k}.gcode"
        path.write_text("".join(f"G1 X{10 * (i % 2)} Y{i} F600\n" for i in range(1, 30)), encoding="ascii")
        programs.append(str(path))
    now = time.time()
    rows = [SheetRow(1, 0, "s0", programs[0], "", 29, 29, "m1", now - 100.0, now - 40.0),
            SheetRow(1, 1, "s1", programs[1], "", 29, 10, "m1", now - 30.0, None)]

    class Queue:
        def sheets(self, job_id):
            return rows

    job = {"id": 1, "state": "cutting", "sheet": 1, "machine": "m1", "sheet_list": [{"k": 0}, {"k": 1}]}
    machines = [{"name": "m1", "port": "sim://m1?time_scale=2"}]
    timelines = Timelines()
    deadline = time.monotonic() + 60
    while (eta := job_eta(Queue(), job, machines, timelines)) is None and time.monotonic() < deadline:
        time.sleep(0.05)
    plan = [program_timeline(p) / 2 for p in programs]
    sheet = estimate(plan[1][-1], plan[1][9], 30.0)
    whole = estimate(plan[0][-1] + plan[1][-1], plan[0][-1] + plan[1][9], 90.0)
    assert eta["sheet"]["remaining_s"] == pytest.approx(sheet.remaining, abs=1.5)
    assert eta["sheet"]["elapsed_s"] == pytest.approx(30, abs=1.5)
    assert eta["job"]["remaining_s"] == pytest.approx(whole.remaining, abs=1.5)
    assert eta["job"]["finish_at"] == pytest.approx(now + whole.remaining, abs=2)
    assert job_eta(Queue(), {**job, "state": "queued"}, machines, timelines) is None


def test_the_stream_bar_shows_lines_elapsed_and_remaining_on_a_terminal(monkeypatch):
    """The bar `fabline stream` and each machine of `fabline run` show: lines done of all, the ETA, the status."""
    import io
    import sys

    from fabline.progress import StreamBar

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bar = StreamBar("grbl-1")
    bar.show(50, 200, estimate(400.0, 100.0, 130.0), "Run @ 1.00,2.00 line 57", desc="grbl-1 S003")
    bar.close()
    shown = terminal.getvalue().replace("\r", "\n").splitlines()
    last = [line for line in shown if line.strip()][-1]
    remaining = 300 * (130 + 20) / (100 + 20)  # planned rest x pace shrunk by a prior of 5 % of 400 s: 6:15
    assert last.startswith("grbl-1 S003:  25%") and remaining == 375
    assert last.endswith("| 50/200, elapsed 0:02:10, remaining 0:06:15; Run @ 1.00,2.00 line 57"), last
