"""The runner survives kill -9: 20 SIGKILLs at random moments of a 3-sheet job, each followed by the operator's
"resume here" on the job that needs attention, then completion, and the controller (a simulator in its own
process) executed every program line exactly once, in order. A restarted runner never resumes by itself."""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import time
from pathlib import Path

from fabline.jobs.queue import JobQueue
from fabline.link import SimulatorServer
from runner_support import JOBS_CLI, executed_program_lines, square_program, wire_lines

REPO = Path(__file__).resolve().parents[2]
KILLS = 20


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_runner(tmp_path: Path, db: Path, url: str) -> subprocess.Popen:
    command = [*JOBS_CLI, "runner", "serve", "--jobs", str(tmp_path / "jobs"), "--db", str(db),
               "--machine", f"m1={url}", "--auto-confirm", "--web-port", str(free_port()), "--token", "t"]
    return subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def progress(queue: JobQueue, job_id: int) -> tuple[str, int]:
    job = queue.job(job_id)
    return job.state, sum(s.done_lines for s in queue.sheets(job_id))


def restart_runner(tmp_path: Path, db: Path, url: str, queue: JobQueue, job_id: int) -> subprocess.Popen:
    """Start a runner again. A job cut off mid-sheet then waits for the operator, without moving the machine,
    until the operator chooses "resume here"."""
    interrupted = queue.job(job_id).state == "cutting"
    runner = start_runner(tmp_path, db, url)
    if interrupted:
        deadline = time.monotonic() + 60
        while queue.job(job_id).state != "attention":
            assert time.monotonic() < deadline and runner.poll() is None, f"no attention: {queue.job(job_id).describe()}"
            time.sleep(0.02)
        _, done = progress(queue, job_id)
        time.sleep(0.3)
        assert progress(queue, job_id) == ("attention", done), "the runner resumed by itself"
        assert queue.job(job_id).checkpoint()["reason"] == "the runner stopped while the sheet was being cut"
        queue.resolve(job_id, "resume")
    return runner


def test_twenty_sigkills_during_a_three_sheet_job(tmp_path):
    (tmp_path / "jobs").mkdir()
    sheets = [square_program(tmp_path / "gcode" / f"sheet{k + 1}.gcode", 20, 20 + 30 * k, squares=14) for k in range(3)]
    expected = [line for sheet in sheets for line in wire_lines(sheet)]
    db = tmp_path / "runner.sqlite"
    queue = JobQueue(db)
    job_id = queue.submit("kill-test", programs=[(p.stem, str(p), "") for p in sheets])
    log = tmp_path / "executed.log"
    rng = random.Random(20171)
    with SimulatorServer(log=log, time_scale=5.0, faults={"settings": "32:1"}) as simulator:
        for kill in range(KILLS):
            runner = restart_runner(tmp_path, db, simulator.url, queue, job_id)
            _, before = progress(queue, job_id)
            # a random moment while this runner streams: after 1 to 4 more lines are done, plus up to 0.2 s
            target = before + rng.randint(1, 4)
            deadline = time.monotonic() + 60
            while progress(queue, job_id)[1] < target and runner.poll() is None and time.monotonic() < deadline:
                time.sleep(0.01)
            assert runner.poll() is None, f"runner {kill + 1} exited: {runner.stderr.read()[-2000:]}"
            time.sleep(rng.uniform(0.0, 0.2))
            state, _ = progress(queue, job_id)
            assert state in ("cutting", "ready"), f"kill {kill + 1} would not fall during the job: {state}"
            os.killpg(runner.pid, signal.SIGKILL)
            runner.wait()
            runner.stderr.close()
        runner = restart_runner(tmp_path, db, simulator.url, queue, job_id)
        try:
            deadline = time.monotonic() + 120
            while progress(queue, job_id)[0] not in ("done", "failed") and time.monotonic() < deadline:
                assert runner.poll() is None, runner.stderr.read()[-2000:]
                time.sleep(0.1)
        finally:
            runner.send_signal(signal.SIGTERM)
            runner.wait(timeout=30)
            runner.stderr.close()
    job = queue.job(job_id)
    assert job.state == "done", job.describe()
    assert executed_program_lines(log) == expected
