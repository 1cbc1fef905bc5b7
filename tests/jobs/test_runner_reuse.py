"""A re-queued job reuses its prepared sheets when its job file and inputs are unchanged (issue 24: every re-queue
of the example job re-prepared it for 2-2.7 min); a changed input, or a changed program on disk, is prepared
afresh. The prepared output is keyed by a SHA-256 of the job file, its input files and fabline's code."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from fabline.jobs import pipeline
from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import Runner
from fabline.machine import load_program
from fabline.model import save_network
from fabline.model.designs import DESIGNS

JOB = """
name = "reused"
stages = ["unroll", "nest", "export"]
[model]
file = "shell.json"
[output]
folder = "../out/reused"
"""


def _wait_ready(queue: JobQueue, job_id: int, timeout: float = 240) -> None:
    deadline = time.monotonic() + timeout
    while queue.job(job_id).state in ("queued", "preparing"):
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)
    assert queue.job(job_id).state == "ready", queue.job(job_id).describe()


@pytest.fixture
def counted(monkeypatch):
    """How many times the pipeline's unroll, nest and export ran (the real stages, counted)."""
    calls = []
    for stage in ("_unroll", "_nest", "_export"):
        real = getattr(pipeline, stage)
        monkeypatch.setattr(pipeline, stage, lambda result, real=real, stage=stage: (calls.append(stage), real(result))[1])
    return calls


def _programs(queue: JobQueue, job_id: int) -> list[bytes]:
    return [Path(s.program).read_bytes() for s in queue.sheets(job_id)]


def test_a_requeued_unchanged_job_reuses_its_sheets_and_a_changed_input_is_prepared_again(tmp_path, counted):
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    save_network(DESIGNS["enneper"](size=(1.5, 1.5), spacing=0.5), jobs / "shell.json")
    (jobs / "reused.toml").write_text(JOB, encoding="utf-8")
    db = jobs / "runner.sqlite"
    runner = Runner(db, [], poll=0.05)
    runner.start()
    queue = JobQueue(db)
    try:
        first = queue.submit("reused", job_file=str(jobs / "reused.toml"))
        _wait_ready(queue, first)
        assert counted == ["_unroll", "_nest", "_export"]
        queue.act(first, "cancel")

        again = queue.requeue(first)
        _wait_ready(queue, again)
        assert counted == ["_unroll", "_nest", "_export"], "unchanged: nothing unrolled, nested or exported again"
        assert _programs(queue, again) == _programs(queue, first)
        assert [s.lines for s in queue.sheets(again)] == [len(load_program(s.program).lines) for s in queue.sheets(first)]
        assert all(Path(s.program).is_relative_to(jobs / "runs" / f"job-{again}") for s in queue.sheets(again))
        assert [s.load_facts()["picture"] for s in queue.sheets(again)] == \
            [str(jobs / "runs" / f"job-{again}" / Path(s.svg).relative_to(jobs / "runs" / f"job-{first}"))
             for s in queue.sheets(first)]
        assert any("its prepared sheets reused" in e["message"] for e in queue.events() if e["job_id"] == again)

        save_network(DESIGNS["enneper"](size=(1.5, 1.5), spacing=0.45), jobs / "shell.json")  # the model changed
        queue.act(again, "cancel")
        changed = queue.requeue(again)
        _wait_ready(queue, changed)
        assert counted == ["_unroll", "_nest", "_export"] * 2, "a changed input file is prepared afresh"
        assert _programs(queue, changed) != _programs(queue, first)

        program = Path(queue.sheets(changed)[0].program)  # a program edited on disk is not handed out again
        program.write_bytes(program.read_bytes() + b"; edited\n")
        queue.act(changed, "cancel")
        edited = queue.requeue(changed)
        _wait_ready(queue, edited)
        assert counted == ["_unroll", "_nest", "_export"] * 3
    finally:
        runner.stop()


def test_a_job_prepared_before_the_runner_stopped_keeps_its_own_sheets(tmp_path, counted):
    """Killed between writing the sheets and marking the job ready: on restart the job goes back to the queue
    (`recover`) and its own finished preparation is taken as it is, not redone nor copied."""
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    save_network(DESIGNS["enneper"](size=(1.5, 1.5), spacing=0.5), jobs / "shell.json")
    (jobs / "reused.toml").write_text(JOB, encoding="utf-8")
    db = jobs / "runner.sqlite"
    queue = JobQueue(db)
    job = queue.submit("reused", job_file=str(jobs / "reused.toml"))
    runner = Runner(db, [], poll=0.05)
    runner.start()
    try:
        _wait_ready(queue, job)
    finally:
        runner.stop()
    programs = [s.program for s in queue.sheets(job)]
    with queue.transaction() as db_:  # as a runner killed just before `prepared` left it
        db_.execute("DELETE FROM sheets WHERE job_id = ?", (job,))
        db_.execute("UPDATE jobs SET state = 'preparing', sheets = 0 WHERE id = ?", (job,))
    runner = Runner(db, [], poll=0.05)
    runner.start()
    try:
        _wait_ready(queue, job)
    finally:
        runner.stop()
    assert counted == ["_unroll", "_nest", "_export"]
    assert [s.program for s in queue.sheets(job)] == programs
