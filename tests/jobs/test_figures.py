"""Every figure a user reads is true: machine time by the controller's own clock (not wall time x time scale), no
wall times of parallel machines summed as one, a resume with nothing left says so and reports no time, progress by
planned machine time (not lines), an ETA beyond today carries its date, waiting for the operator is not remaining
work, the survey's four counts add up to its nodes, and lengths at the manual's precision (docs/index.md, Layout)."""

from __future__ import annotations

import datetime
import json
import math
import re
import time
from pathlib import Path

import pytest

from fabline.cli import main
from fabline.jobs.report_shop import stream_table, summary_block
from fabline.link import Streamer
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine import load_program
from fabline.progress import StreamBar, estimate

A = 800.0  # mm/s^2 on X and Y ($120, $121); the max rates ($110, $111) 6000 mm/min, above every feed


def test_the_simulators_machine_clock_is_its_planners_time_not_wall_time_times_scale(tmp_path):
    """A firmware that takes 20 ms of wall time to parse each line at time scale 20 000 (400 machine seconds per
    line) runs its planner dry between lines: each 100 mm move at 10 mm/s runs alone from rest to rest, 100/10 + 10/a
    by hand, and the steppers hold $1 = 25 ms after each. The simulator's clock, and the streamer's machine time read
    from it through the sim:// port, are that; the wall time x time scale is many times more."""
    path = tmp_path / "three.gcode"
    path.write_text("G21\nG90\nG1 X100 F600\nG1 X0\nG1 X100\n", encoding="ascii")
    url = "sim://machine-clock?time_scale=20000&line_time=0.02&settings=120:800,121:800,110:6000,111:6000"
    try:
        result = Streamer(url, status_interval=0.02).run(path)
        clock = get_simulator("machine-clock").machine_time
    finally:
        close_simulator("machine-clock")
    by_hand = 3 * (100 / 10 + 10 / A + 0.025)
    assert result.completed
    assert clock == pytest.approx(by_hand, rel=1e-6)
    assert result.machine == pytest.approx(by_hand, rel=1e-6)
    assert result.elapsed * 20000 > 5 * by_hand  # what "taken" used to be: wall time x scale


def test_the_controllers_answers_are_unchanged_by_its_clock():
    """The clock is a side channel of the port: the status report carries no extra field (the transcript's form)."""
    from fabline.link.simulator import GrblSimulator

    simulator = GrblSimulator(threaded=False)
    simulator.attach()
    simulator.read(1 << 16, None)
    simulator.receive(b"?")
    report = simulator.read(1 << 16, None).decode()
    simulator.close()
    assert re.fullmatch(r"<Idle\|MPos:0\.000,0\.000,0\.000\|FS:0,0\|WCO:0\.000,0\.000,0\.000>\r\n", report), report


def test_the_bar_follows_planned_machine_time_not_lines(tmp_path):
    """One 10-second cut, then 40 short moves of a few milliseconds each: while the long cut runs, the planner holds
    it and the next 14 lines, so a third of the lines are acknowledged but nearly all of the planned time. Every
    progress report's percentage is the planned time of the lines done over the program's."""
    path = tmp_path / "unequal.gcode"
    path.write_text("G21\nG90\nG1 X100 F600\n" + "".join(f"G1 X{100 + 0.1 * (i + 1):.1f} F6000\n" for i in range(40)),
                    encoding="ascii")
    reports = []
    url = "sim://bar-share?time_scale=10&settings=120:800,121:800,110:6000,111:6000"
    streamer = Streamer(url, status_interval=0.02)
    try:
        streamer.run(path, on_progress=reports.append)
    finally:
        close_simulator("bar-share")
    timeline = streamer.timeline()
    lines = len(load_program(path).lines)
    for report in reports:
        share = float(timeline[report.acked - 1] / timeline[-1]) if report.acked else 0.0
        assert report.percent == pytest.approx(100 * share)
        assert report.eta.fraction == pytest.approx(share, abs=1e-9)
    early = [r for r in reports if 0 < r.acked < lines / 2]
    assert early and all(r.percent > 90 for r in early), [(r.acked, r.percent) for r in early]


def test_the_terminal_bar_shows_the_share_of_planned_time(monkeypatch):
    """50 of 200 lines done, but 300 of 400 planned seconds: the bar says 75 %, and counts the lines beside it."""
    import io
    import sys

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bar = StreamBar("grbl-1")
    bar.show(50, 200, estimate(400.0, 300.0, 300.0), "Run", desc="grbl-1 S003")
    bar.close()
    last = [line for line in terminal.getvalue().replace("\r", "\n").splitlines() if line.strip()][-1]
    assert last.startswith("grbl-1 S003:  75%") and "| 50/200, elapsed 0:05:00, remaining 0:01:40; Run" in last, last


def test_an_eta_beyond_today_carries_its_date():
    """A finish later today is a clock time; one 49 hours on is that day's date and time (as datetime says it)."""
    from fabline.progress import finish_time

    noon = time.mktime((2026, 12, 2, 12, 0, 0, 0, 0, -1))
    assert finish_time(noon + 3600, noon) == "13:00"
    later = noon + 49 * 3600 + 21 * 60
    day = datetime.datetime.fromtimestamp(later)
    assert finish_time(later, noon) == f"{day:%a} {day.day} {day:%b} {day:%H:%M}" == "Fri 4 Dec 13:21"
    assert finish_time(time.mktime((2027, 1, 1, 9, 30, 0, 0, 0, -1)), noon) == "Fri 1 Jan 2027 09:30"


def test_waiting_for_the_operator_is_not_remaining_work(tmp_path, monkeypatch):
    """A sheet half cut in 100 s, then two hours in "needs attention" and an hour paused: the runner page's remaining
    time is what it was when the waiting began, and the elapsed work after each wait counts only the cutting."""
    from fabline.jobs.queue import JobQueue
    from fabline.jobs.streaming import program_timeline
    from fabline.jobs.web import Timelines, job_eta
    from runner_support import square_program

    clock = [1_000_000.0]
    monkeypatch.setattr(time, "time", lambda: clock[0])
    program = square_program(tmp_path / "s.gcode", 10, 10, squares=4)
    queue = JobQueue(tmp_path / "q.sqlite")
    job_id = queue.submit("j", programs=[("S1", str(program), "")])
    queue.claim_for_machine("m1")
    queue.confirm_sheet(job_id)
    queue.start_sheet(job_id, "m1")
    lines = queue.sheets(job_id)[0].lines
    timelines = Timelines()

    def eta() -> dict:
        job = next(j for j in queue.snapshot()["jobs"] if j["id"] == job_id)
        deadline = time.monotonic() + 60
        while (found := job_eta(queue, job, [], timelines)) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return found

    clock[0] += 100.0
    queue.sheet_progress(job_id, 0, lines // 2)
    before = eta()
    assert before["sheet"]["elapsed_s"] == 100
    plan = program_timeline(program)
    assert before["sheet"]["fraction"] == pytest.approx(plan[lines // 2 - 1] / plan[-1], abs=1e-4)  # the page's bar
    assert before["sheet"]["fraction"] != pytest.approx(0.5, abs=0.05)  # not the share of lines
    queue.need_attention(job_id, {"reason": "link failed", "done": lines // 2, "lines": lines, "file_line": 9})
    clock[0] += 7200.0
    waiting = eta()
    assert waiting["sheet"]["remaining_s"] == before["sheet"]["remaining_s"]
    assert waiting["job"]["remaining_s"] == before["job"]["remaining_s"] and waiting["sheet"]["elapsed_s"] == 100
    queue.resolve(job_id, "resume")
    clock[0] += 20.0
    assert eta()["sheet"]["elapsed_s"] == 120
    queue.set_cutting_state(job_id, "paused")
    clock[0] += 3600.0
    assert eta()["sheet"]["elapsed_s"] == 120
    queue.set_cutting_state(job_id, "cutting")
    clock[0] += 5.0
    assert eta()["sheet"]["elapsed_s"] == 125
    queue.close()


def _sheet(name, port, seconds, machine, planned, outcome="finished", done=None):
    return {"sheet": name, "port": port, "lines": 100, "executed": 100 if outcome == "finished" else 40,
            "outcome": outcome, "seconds": seconds, "machine_s": machine, "planned_s": planned,
            "planned_done_s": planned if done is None else done}


def test_the_streaming_table_of_two_parallel_machines():
    """Three sheets on two machines cutting at once, the stage 230 s of wall time: each machine's wall time is the
    sum of its own sheets (one after another), the job's is the stage's 230 s, not the 330 s of all sheets; machine
    time is summed over the machines (machine-hours) from each controller's clock; only the unfinished sheet has
    time left."""
    sheets = [_sheet("S1", "sim://m1?time_scale=2000", 100.0, 40000.0, 39000.0),
              _sheet("S2", "sim://m2?time_scale=2000", 110.0, 41000.0, 40000.0),
              _sheet("S3", "sim://m1?time_scale=2000", 120.0, 20000.0, 50000.0, "aborted", done=20000.0)]
    stream = {"sheets": sheets, "lines": 300, "executed": 240, "finished": False, "wall_s": 230.0}
    html = stream_table(stream, {})
    rows = re.findall(r"<tr[^>]*>(.*?)</tr>", html)
    cells = [re.findall(r"<t[dh]>(.*?)</t[dh]>", row) for row in rows]
    job = next(c for c in cells if c[0] == "job")
    assert job[-1] == "230.0" and "330.0" not in html
    assert job[5] == "28:03:20" and job[6] == "35:50:00"  # 101 000 s taken, 129 000 s planned
    assert job[7] == "8:20:00"  # the aborted sheet's 30 000 planned seconds left
    machines = {c[0]: c for c in cells if c[0].startswith("sim://")}
    assert machines["sim://m1"][-1] == "220.0" and machines["sim://m2"][-1] == "110.0"
    assert machines["sim://m1"][5] == "16:40:00"  # 60 000 s of machine time on m1
    s1 = next(c for c in cells if c[0] == "S1")
    assert s1[5] == "11:06:40" and s1[7] == ""  # wall 100 s x 2000 would be 55:33:20; a finished sheet has none left


def test_the_run_summary_line_of_two_parallel_machines():
    from fabline.jobs.pipeline import stream_summary

    sheets = [_sheet("S1", "sim://m1", 100.0, 40000.0, 39000.0), _sheet("S2", "sim://m2", 110.0, 41000.0, 40000.0)]
    assert stream_summary(sheets, 2, 120.0) == ("stream: 2 sheet(s) on 2 machine(s) in 120.0 s; machine time (summed "
                                                "over the machines) planned 21:56:40, taken 22:30:00")


JOB = """
name = "again"
stages = ["unroll", "nest", "export", "stream", "report"]
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[stock]
sheet = "1200x500"
[machine]
time_scale = 1000.0
ports = ["sim://resume-finished"]
[output]
folder = "out"
"""


def test_resume_after_a_finished_run_cuts_nothing_and_reports_no_time(tmp_path, capsys):
    """`fabline run --resume` of a job whose run finished: one line says there is nothing left to cut, no sheet line
    claims lines finished now, no machine time is taken, and the report marks the sheets as cut earlier."""
    job = tmp_path / "again.toml"
    job.write_text(JOB, encoding="utf-8")
    assert main(["run", str(job)]) == 0
    first = capsys.readouterr().out
    count = len(json.loads((tmp_path / "out" / "report.json").read_text())["nesting"]["sheets"])
    assert main(["run", str(job), "--resume"]) == 0
    again = capsys.readouterr().out
    assert f"stream: nothing left to cut: all {count} sheets finished in an earlier run" in again
    assert "taken" not in again and not re.search(r"stream: sheet \d+ of", again), again
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert len(data["stream"]["sheets"]) == count
    assert all(s["earlier"] and "machine_s" not in s for s in data["stream"]["sheets"])
    html = (tmp_path / "out" / "report.html").read_text()
    table = html[html.index("<table id=stream>"):html.index("</table>", html.index("<table id=stream>"))]
    assert table.count("finished in an earlier run") == count
    assert f"{count} of {count} sheets finished ({count} in an earlier run)" in html
    for sheet in data["nesting"]["sheets"]:  # lengths at the manual's precision: m to the millimetre
        assert f"cut {sheet['cut_length_mm'] / 1000:.3f} m, planned machine time" in html
    assert re.search(r"machine time \(summed over the machines\) planned \d+:\d\d:\d\d, taken \d+:\d\d:\d\d", first)


def test_the_survey_summary_gives_all_four_counts_adding_up_to_the_nodes():
    from fabline.verdicts import verdict_counts, verdict_text

    summary = {"nodes": 440, "measured": 428, "passed": 369, "failed": 17, "uncertain": 42, "not_seen": 12}
    counts = verdict_counts(summary)
    assert sum(counts.values()) == summary["nodes"]
    assert verdict_text(summary) == "369 pass, 17 fail, 42 uncertain, 12 not seen of 440 nodes"
    data = {"model": {"name": "m", "lamellas": 1, "nodes": 440}, "parts": None, "nesting": None,
            "structure": {"lamellas": []}, "stream": {"sheets": []},
            "survey": {"summary": summary, "tolerance_mm": 10.0}}
    row = re.search(r"<td>survey</td><td>(.*?)</td>", summary_block(data))[1]
    numbers = [int(n) for n in re.findall(r"(\d+) (?:pass|fail|uncertain|not seen)", row)]
    assert len(numbers) == 4 and sum(numbers) == 440, row


def test_the_deviation_map_title_prints_mm_to_a_tenth(tmp_path, monkeypatch):
    """The title of the deviation map: `RMS 10.5 mm`, not `RMS 10.4966 mm` (fabline.units.mm)."""
    import cv2

    from fabline.model.designs import DESIGNS
    from fabline.survey import measure

    texts = []
    monkeypatch.setattr(measure.cv2, "putText", lambda canvas, text, *args: texts.append(text))
    monkeypatch.setattr(measure, "write_image", lambda path, canvas: None)
    network = DESIGNS["enneper"](size=(1.5, 1.5), spacing=0.5)
    summary = {"nodes": len(network.nodes), "measured": 0, "passed": 0, "failed": 0, "uncertain": 0,
               "not_seen": len(network.nodes), "rms_deviation_mm": 10.4966, "max_deviation_mm": 21.04, "k_sigma": 2.0}
    measure.write_deviation_map(network, {"tolerance_mm": 10.0, "nodes": {}, "summary": summary}, tmp_path / "m.png")
    title = next(text for text in texts if "RMS" in text)
    assert "RMS 10.5 mm" in title and "max 21.0 mm" in title and "10.4966" not in title, title
    assert cv2 is measure.cv2


def test_a_program_paused_for_the_operator_keeps_its_remaining_time_and_takes_no_machine_time(tmp_path):
    """An M0 halfway: while the machine stands held for the operator, every progress report keeps the elapsed and
    remaining time it had (waiting is not work); the run's machine time by the simulator's clock is the motion's
    alone (with the $1 = 25 ms stepper lock after each move), and the time held is told apart."""
    import threading

    path = tmp_path / "pause.gcode"
    path.write_text("G21\nG90\nG1 X100 F600\nM0\nG1 X0\n", encoding="ascii")
    url = "sim://held-clock?time_scale=50&settings=120:800,121:800,110:6000,111:6000"
    reports, results = [], []
    streamer = Streamer(url, status_interval=0.02)
    worker = threading.Thread(target=lambda: results.append(streamer.run(path, on_progress=reports.append)))
    worker.start()
    try:
        deadline = time.monotonic() + 60
        while not any(r.message for r in reports) and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)
        first = len(reports)
        time.sleep(1.5)
        held = [r for r in reports[first:] if r.message]
        streamer.resume()
        worker.join(60)
    finally:
        close_simulator("held-clock")
    assert len(held) >= 5
    assert max(r.elapsed for r in held) - min(r.elapsed for r in held) < 0.05
    assert max(r.remaining for r in held) - min(r.remaining for r in held) < 0.05
    result = results[0]
    assert result.completed and result.held >= 1.8
    assert result.machine == pytest.approx(2 * (100 / 10 + 10 / A + 0.025), rel=1e-6)


def test_the_report_does_not_call_a_survey_with_uncertain_nodes_all_within_tolerance():
    from fabline.jobs.report import _survey_section

    summary = {"nodes": 440, "measured": 428, "passed": 386, "failed": 0, "uncertain": 42, "not_seen": 12,
               "k_sigma": 2.0, "photos": 40, "photos_used": 40, "rms_deviation_mm": 4.04, "max_deviation_mm": 9.96,
               "worst": ["N1-1"], "reprojection_rms_px": 0.3}
    survey = {"summary": summary, "tolerance_mm": 10.0, "deviation_map": None, "file": "survey.json", "scale": None,
              "reference": "all", "registration_rms_mm": 4.0, "truth": None, "not_seen": {}, "problems": []}
    text = _survey_section(survey, Path("."))
    assert "every measured node within tolerance" not in text
    assert "none out of tolerance, 42 too close to tell (386 pass, 0 fail, 42 uncertain, 12 not seen of 440 nodes" in text
