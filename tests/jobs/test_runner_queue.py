"""The runner's SQLite queue: WAL mode, the state machine, operator confirmation, and 100 jobs on 4 machines."""

from __future__ import annotations

import sqlite3
import threading
import time
from collections import Counter

import pytest

from fabline.errors import FablineError
from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner, parse_machine
from runner_support import executed_program_lines, square_program, wire_lines


@pytest.fixture
def queue(tmp_path):
    q = JobQueue(tmp_path / "q.sqlite")
    yield q
    q.close()


def programs(tmp_path, count, tag=0):
    return [(f"S{k + 1}", str(square_program(tmp_path / f"p{tag}_{k}.gcode", 10 + k, 10 + tag)), "")
            for k in range(count)]


def test_database_is_in_wal_mode(queue):
    mode = sqlite3.connect(queue.path).execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"


def test_state_machine_with_operator_confirmation(queue, tmp_path):
    job_id = queue.submit("j", programs=programs(tmp_path, 2))
    assert queue.job(job_id).state == "ready"
    assert queue.claim_for_machine("m1").id == job_id
    assert queue.claim_for_machine("m2") is None, "a job belongs to one machine"
    assert queue.start_sheet(job_id, "m1") is None, "no sheet starts before the operator confirms it"
    assert "load and confirm" in queue.job(job_id).describe()
    queue.confirm_sheet(job_id)
    sheet = queue.start_sheet(job_id, "m1")
    assert sheet.k == 0 and queue.job(job_id).describe() == "cutting sheet 1 of 2"
    with pytest.raises(FablineError, match="cannot be confirmed now"):
        queue.confirm_sheet(job_id)
    after = queue.finish_sheet(job_id, 0)
    assert after.state == "ready" and after.sheet == 1
    assert queue.start_sheet(job_id, "m1") is None, "the second sheet needs its own confirmation"
    queue.confirm_sheet(job_id, 1)
    assert queue.start_sheet(job_id, "m1").k == 1
    assert queue.finish_sheet(job_id, 1).state == "done"
    with pytest.raises(FablineError, match="already done"):
        queue.request(job_id, "pause")


def test_pause_resume_cancel_of_jobs_not_being_cut(queue, tmp_path):
    job_id = queue.submit("j", job_file=str(tmp_path / "x.toml"))
    assert queue.request(job_id, "pause").state == "paused"
    assert queue.claim_preparation() is None, "a paused job is not prepared"
    assert queue.request(job_id, "resume").state == "queued"
    assert queue.request(job_id, "cancel").state == "cancelled"
    with pytest.raises(FablineError, match="already cancelled"):
        queue.request(job_id, "resume")
    with pytest.raises(FablineError, match="unknown action"):
        queue.request(job_id, "explode")
    with pytest.raises(FablineError, match="no such job"):
        queue.job(999)


def test_requests_on_a_cutting_job_go_to_its_worker(queue, tmp_path):
    job_id = queue.submit("j", programs=programs(tmp_path, 1))
    queue.claim_for_machine("m1")
    queue.confirm_sheet(job_id)
    queue.start_sheet(job_id, "m1")
    assert queue.request(job_id, "pause").state == "cutting"
    assert queue.take_request(job_id) == "pause" and queue.take_request(job_id) is None
    queue.set_cutting_state(job_id, "paused")
    assert queue.job(job_id).paused_from == "cutting"
    queue.request(job_id, "resume")
    assert queue.take_request(job_id) == "resume"


def test_a_crash_during_preparation_requeues_the_job(tmp_path):
    queue = JobQueue(tmp_path / "q.sqlite")
    job_id = queue.submit("j", job_file=str(tmp_path / "x.toml"))
    assert queue.claim_preparation().state == "preparing"
    queue.close()
    Runner(tmp_path / "q.sqlite", [MachineConfig("m1", "sim://unused")])  # a restarted runner recovers
    assert JobQueue(tmp_path / "q.sqlite").job(job_id).state == "queued"


def test_bad_programs_and_machine_specs_are_refused(queue, tmp_path):
    bad = tmp_path / "bad.gcode"
    bad.write_text("G1 X1 ?\n", encoding="ascii")
    with pytest.raises(FablineError, match="bad.gcode:1"):
        queue.submit("j", programs=[("S1", str(bad), "")])
    assert queue.jobs() == [], "nothing is queued when a program is bad"
    with pytest.raises(FablineError, match="expected NAME=PORT"):
        parse_machine("laser")


def test_concurrent_claims_never_give_a_job_to_two_machines(tmp_path):
    path = tmp_path / "q.sqlite"
    setup = JobQueue(path)
    for k in range(40):
        setup.submit(f"j{k}", programs=programs(tmp_path, 1, tag=k))
    claimed: dict[str, list[int]] = {}

    def claim(machine):
        queue = JobQueue(path)
        mine = claimed.setdefault(machine, [])
        while (job := queue.claim_for_machine(machine)) is not None:
            mine.append(job.id)
            queue.confirm_sheet(job.id)
            queue.start_sheet(job.id, machine)
            queue.finish_sheet(job.id, 0)
        queue.close()

    threads = [threading.Thread(target=claim, args=(f"m{k}",)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    ids = [i for mine in claimed.values() for i in mine]
    assert sorted(ids) == list(range(1, 41))
    assert all(job.state == "done" for job in setup.jobs())


def test_hundred_jobs_on_four_simulated_machines_none_lost_or_run_twice(tmp_path):
    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    expected = {}
    for k in range(100):
        program = square_program(tmp_path / "programs" / f"job{k}.gcode", 100 + k, 50)
        job_id = queue.submit(f"job{k}", programs=[("S1", str(program), "")])
        expected[job_id] = wire_lines(program)
    logs = {f"m{k}": tmp_path / f"m{k}.log" for k in range(4)}
    machines = [MachineConfig(name, f"sim://q100-{name}?time_scale=1000&settings=32:1,130:1000&log={log}") for name, log in logs.items()]
    runner = Runner(db, machines, auto_confirm=True, poll=0.02, prepare=False)
    runner.start()
    try:
        runner.run_until_idle(timeout=150)
    finally:
        runner.stop()
    jobs = queue.jobs()
    assert [j.state for j in jobs] == ["done"] * 100
    used = Counter(j.machine for j in jobs)
    assert len(used) == 4, f"every machine took jobs: {used}"
    # The truth is what the controllers executed: every job's lines exactly once, on the machine the queue says.
    for name, log in logs.items():
        executed = executed_program_lines(log)
        mine = sorted((j for j in jobs if j.machine == name), key=lambda j: queue.sheets(j.id)[0].started)
        assert executed == [line for j in mine for line in expected[j.id]], f"machine {name}"


def test_pause_resume_and_cancel_a_sheet_being_cut(tmp_path):
    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    first = square_program(tmp_path / "first.gcode", 10, 10, squares=8)
    second = square_program(tmp_path / "second.gcode", 10, 60, squares=8)
    job_a = queue.submit("a", programs=[("S1", str(first), "")])
    log = tmp_path / "m1.log"
    runner = Runner(db, [MachineConfig("m1", f"sim://pause-m1?time_scale=4&settings=32:1&log={log}")], auto_confirm=True, poll=0.05,
                    prepare=False)
    runner.start()

    def wait(condition, timeout=30.0):
        deadline = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < deadline, "timed out"
            time.sleep(0.05)

    try:
        wait(lambda: queue.sheets(job_a)[0].done_lines >= 5)
        queue.request(job_a, "pause")
        wait(lambda: queue.job(job_a).state == "paused")
        time.sleep(0.5)  # the feed hold decelerates; then the machine stands still
        held = queue.machines()[0]["position"], len(executed_program_lines(log))
        time.sleep(1.0)
        assert (queue.machines()[0]["position"], len(executed_program_lines(log))) == held, "feed hold: no motion"
        queue.request(job_a, "resume")
        wait(lambda: queue.job(job_a).state == "done")
        assert executed_program_lines(log) == wire_lines(first)
        job_b = queue.submit("b", programs=[("S1", str(second), "")])
        wait(lambda: queue.sheets(job_b)[0].done_lines >= 5)
        queue.request(job_b, "cancel")
        wait(lambda: queue.job(job_b).state == "cancelled")
    finally:
        runner.stop()
    executed = executed_program_lines(log)[len(wire_lines(first)):]
    assert 0 < len(executed) < len(wire_lines(second))
    assert executed == wire_lines(second)[:len(executed)], "a cancelled sheet stops; nothing out of order"
