"""Fault tests on the GRBL simulator: after each fault and a resume, every program line ran exactly once, in order."""

from __future__ import annotations

import math
import os
import random
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from fabline.errors import FablineError
from fabline.link import SimulatorServer, Streamer, StreamInterrupted, executed_file_lines, read_journal
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine import load_program

REPO = Path(__file__).resolve().parents[2]


def write_program(path: Path, contours: int = 12, points: int = 24) -> Path:
    """A laser job like the export stage writes: rapid to each contour, cut it with M4 on, M5 after."""
    lines = ["(fabline test job)", "G21", "G90", "G17", "G94", "M5"]
    for contour in range(contours):
        cx, cy = 40.0 + 30.0 * (contour % 4), 40.0 + 30.0 * (contour // 4)
        lines.append(f"G0 X{cx + 10:.3f} Y{cy:.3f} ; contour {contour}")
        lines.append("M4 S800")
        for step in range(1, points + 1):
            angle = 2 * math.pi * step / points
            lines.append(f"G1 X{cx + 10 * math.cos(angle):.3f} Y{cy + 10 * math.sin(angle):.3f} F2400")
        lines.append("G2 X{0:.3f} Y{1:.3f} I-5 J0".format(cx, cy))
        lines.append("M5")
    lines += ["G0 X0 Y0", "M2"]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


@pytest.fixture
def job(tmp_path):
    program = write_program(tmp_path / "sheet.gcode")
    return program, tmp_path / "executed.log"


@pytest.fixture
def sim_url(job):
    """A uniquely named in-process simulator; its executed-line log is the test's truth."""
    name = f"t{uuid.uuid4().hex[:8]}"

    def url(**options):
        defaults = {"time_scale": 200, "log": job[1], "settings": "32:1"}  # a stock build set up for a laser
        query = "&".join(f"{key}={value}" for key, value in {**defaults, **options}.items())
        return f"sim://{name}?{query}"

    yield url
    close_simulator(name)


def speed_up(url: str, time_scale: float = 200) -> None:
    """Run the rest of a job fast once the fault under test has played out at a realistic pace."""
    get_simulator(url[6:].split("?")[0]).time_scale = time_scale


def expected_lines(program: Path) -> list[int]:
    return [line.file_line for line in load_program(program).lines]


def test_clean_run_executes_everything_once_without_overflow(job, sim_url):
    program, log = job
    url = sim_url()
    seen = []
    result = Streamer(url, status_interval=0.05).run(program, on_progress=seen.append)
    assert result.completed and result.executed == result.total
    assert executed_file_lines(log) == expected_lines(program)
    assert get_simulator(url[6:].split("?")[0]).overflowed == 0
    last = seen[-1]
    assert (last.acked, last.percent, last.state) == (last.total, 100.0, "Idle")
    assert any(p.state == "Run" and p.position is not None and p.remaining is not None for p in seen)
    assert read_journal(f"{program}.journal").finished


def test_disconnects_at_ten_random_points_then_resume(job, sim_url):
    program, log = job
    total_bytes = sum(len(line.wire) for line in load_program(program).lines)
    drops = sorted(random.Random(7).sample(range(50, total_bytes), 10))
    url = sim_url(drop_at=",".join(map(str, drops)))
    interruptions, resume = 0, False
    while True:
        try:
            result = Streamer(url, status_interval=0.05, connect_timeout=2).run(program, resume=resume)
            break
        except StreamInterrupted as exc:
            assert exc.reason == "connection"
            interruptions, resume = interruptions + 1, True
    assert result.completed
    assert interruptions == 10
    assert executed_file_lines(log) == expected_lines(program)


def test_reconnect_after_usb_drop_is_detected_and_continued(job, sim_url):
    program, log = job
    url = sim_url(drop_at="900,2500,4100")
    result = Streamer(url, status_interval=0.05, reconnect_timeout=5).run(program)
    assert result.completed
    assert executed_file_lines(log) == expected_lines(program)


def test_injected_error_stops_with_line_and_words_then_resumes(job, sim_url):
    program, log = job
    bad = expected_lines(program)[45]
    url = sim_url(error_line=bad, error_code=33, time_scale=10)  # real-time-like: the planner holds seconds of work
    with pytest.raises(StreamInterrupted) as stopped:
        Streamer(url, status_interval=0.05).run(program)
    speed_up(url)
    assert stopped.value.reason == "error"
    assert f"sheet.gcode:{bad}:" in str(stopped.value) and "error:33 (the motion command has an invalid target" in str(stopped.value)
    executed = executed_file_lines(log)
    assert executed == expected_lines(program)[: len(executed)] and bad not in executed
    result = Streamer(url, status_interval=0.05).run(program, resume=True)
    assert result.completed
    assert executed_file_lines(log) == expected_lines(program)


def test_alarm_mid_job_needs_unlock_then_resumes(job, sim_url):
    program, log = job
    alarm_line = expected_lines(program)[5 + 28 * 6 + 10]  # a G1 cut
    url = sim_url(alarm_line=alarm_line, alarm_code=1)
    with pytest.raises(StreamInterrupted) as stopped:
        Streamer(url, status_interval=0.05).run(program)
    assert stopped.value.reason == "alarm" and "ALARM:1 (hard limit triggered" in str(stopped.value)
    with pytest.raises(FablineError, match="alarm"):
        Streamer(url).run(program, resume=True)
    result = Streamer(url, status_interval=0.05).run(program, resume=True, unlock=True)
    assert result.completed
    assert executed_file_lines(log) == expected_lines(program)


def test_corrupted_byte_and_stall_are_survived(job, sim_url):
    program, log = job
    url = sim_url(corrupt_at="1500", stall_at="800", stall_seconds=0.5, time_scale=10)
    with pytest.raises(StreamInterrupted) as stopped:
        Streamer(url, status_interval=0.05).run(program)
    speed_up(url)
    assert stopped.value.reason == "error"
    assert Streamer(url, status_interval=0.05).run(program, resume=True).completed
    assert executed_file_lines(log) == expected_lines(program)


def test_abort_from_another_thread_then_resume(job, sim_url):
    program, log = job
    url = sim_url()
    streamer = Streamer(url, status_interval=0.05)

    def on_progress(progress):
        if progress.acked > 120:
            streamer.abort()

    result = streamer.run(program, on_progress=on_progress)
    assert not result.completed and result.reason == "aborted"
    assert executed_file_lines(log) == expected_lines(program)[: result.executed]
    before = len(log.read_text().splitlines())
    assert Streamer(url, status_interval=0.05).run(program, resume=True).completed
    assert executed_file_lines(log) == expected_lines(program)
    preamble = [text for text in log.read_text().splitlines()[before:] if not text.startswith("N")]
    assert preamble[0] == "G21G90G17G94M5"  # laser off before any move
    moves = [text for text in preamble if text.startswith(("G0X", "G0Z"))]
    if moves:  # none when the machine already stands at the restart point
        assert all("M4" not in text for text in preamble[: preamble.index(moves[-1]) + 1])
    assert any(text.startswith("F2400S800M") for text in preamble), preamble  # feed and power restored


def acknowledged(journal: Path) -> int:
    """How many ok records a journal holds so far."""
    return journal.read_text().count('"event":"ok"') if journal.exists() else 0


def test_host_killed_mid_job_then_resume_in_new_process(tmp_path):
    program = write_program(tmp_path / "sheet.gcode", contours=16)
    journal, log = Path(f"{program}.journal"), tmp_path / "executed.log"
    host = ("import sys; from fabline.link import Streamer; "
            "Streamer(sys.argv[1], status_interval=0.05).run(sys.argv[2], resume=sys.argv[3] == 'resume')")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    rng = random.Random(3)
    with SimulatorServer(log=log, time_scale=30, faults={"settings": "32:1"}) as server:
        for kill in range(3):
            process = subprocess.Popen([sys.executable, "-c", host, server.url, str(program),
                                        "resume" if kill else "new"], env=env, stderr=subprocess.PIPE)
            target = acknowledged(journal) + rng.randrange(20, 80)
            deadline = time.monotonic() + 60
            while acknowledged(journal) < target and process.poll() is None and time.monotonic() < deadline:
                time.sleep(0.01)
            assert process.poll() is None, process.communicate()[1]
            process.send_signal(signal.SIGKILL)
            process.wait()
        finished = subprocess.run([sys.executable, "-c", host, server.url, str(program), "resume"], env=env,
                                  capture_output=True, text=True, timeout=120)
        assert finished.returncode == 0, finished.stderr
    assert executed_file_lines(log) == expected_lines(program)
    assert read_journal(journal).finished


def test_a_controller_that_falls_silent_is_treated_as_a_lost_connection(job, sim_url):
    program, log = job
    url = sim_url(stall_at="2000", stall_seconds=2.0)
    with pytest.raises(StreamInterrupted) as stopped:
        Streamer(url, status_interval=0.05, silence_timeout=0.5).run(program)
    assert stopped.value.reason == "connection" and "sent nothing for 0.5 s" in str(stopped.value)
    time.sleep(1.6)
    assert Streamer(url, status_interval=0.05).run(program, resume=True).completed
    assert executed_file_lines(log) == expected_lines(program)


def test_resume_when_the_host_died_during_a_feed_hold(job, sim_url):
    program, log = job
    url = sim_url(time_scale=10)
    streamer = Streamer(url, status_interval=0.05)

    def pause_then_die(progress):
        if progress.acked > 60 and not streamer.paused:
            streamer.pause()
        elif streamer.paused and progress.state == "Hold":
            raise KeyboardInterrupt  # the host goes away with the machine held mid-cut

    with pytest.raises(KeyboardInterrupt):
        streamer.run(program, on_progress=pause_then_die)
    speed_up(url)
    assert Streamer(url, status_interval=0.05).run(program, resume=True).completed
    assert executed_file_lines(log) == expected_lines(program)


def test_a_new_run_never_overwrites_an_interrupted_one_by_accident(job, sim_url):
    """After an interrupted run, a plain new run is refused (it would cut the done lines twice); --restart starts
    over with a fresh journal, and a later --resume continues the latest run, not an older, longer one."""
    program, log = job
    lines = load_program(program).lines
    # both in a contour's G1 cuts: a rejected M5 right after an arc is parsed only once the arc's chords are all
    # planned, and the hold then carries the machine past it into the next G0 (the streamer rightly refuses to guess)
    late, early = lines[len(lines) * 2 // 3 - 10].file_line, lines[len(lines) // 4].file_line
    with pytest.raises(StreamInterrupted):
        Streamer(sim_url(error_line=late), status_interval=0.05).run(program)
    with pytest.raises(FablineError, match=r"stopped after file line \d+ without finishing; continue it with --resume"):
        Streamer(sim_url(), status_interval=0.05).run(program)
    get_simulator(sim_url()[6:].split("?")[0]).faults.error_line = early
    with pytest.raises(StreamInterrupted):
        Streamer(sim_url(), status_interval=0.05).run(program, restart=True)
    state = read_journal(f"{program}.journal")
    assert state.done < len(lines) // 4 + 2  # the journal tells the latest run, which stopped early
    before = len(executed_file_lines(log))
    result = Streamer(sim_url(), status_interval=0.05).run(program, resume=True)
    assert result.completed
    executed = executed_file_lines(log)[before:]
    assert executed == expected_lines(program)[-len(executed):] and executed[0] <= early  # nothing skipped
