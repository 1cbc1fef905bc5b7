"""The runner takes job files from its folder: a good one is prepared (model to G-code) and cut, a bad one
is queued as failed with its one-line error; `fabline runner status/confirm/pause` work on the same queue.
Every job's outputs stay in its own folder under the runner's `runs` folder, whatever output folder it names."""

from __future__ import annotations

import time

from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner
from fabline.machine import load_program
from runner_support import executed_program_lines

GOOD = """
name = "tiny"
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[output]
folder = "../out/tiny"
"""


def wait_for(condition, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.1)


def test_job_folder_to_cut_sheets(tmp_path, cli):
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "tiny.toml").write_text(GOOD, encoding="utf-8")
    (jobs / "broken.toml").write_text(GOOD.replace('name = "tiny"', 'name = "broken"\ncolour = "red"'), encoding="utf-8")
    db = tmp_path / "runner.sqlite"
    log = tmp_path / "executed.log"
    runner = Runner(db, [MachineConfig("m1", f"sim://prepare-m1?time_scale=2000&settings=32:1,110:12000,111:12000,130:4100,131:2100&log={log}")], poll=0.05)
    runner.watch_folder(jobs, every=0.2)
    runner.start()
    queue = JobQueue(db)
    try:
        wait_for(lambda: len(queue.jobs()) == 2, 20)
        jobs_by_name = {j.name: j for j in queue.jobs()}
        broken = jobs_by_name["broken"]
        assert broken.state == "failed"
        assert broken.error == ("broken.toml: colour: unknown key (allowed: name, description, stages, model, "
                                "lamella, stock, unroll, nest, export, machine, output, assembly, survey, analysis)")
        tiny = jobs_by_name["tiny"].id
        wait_for(lambda: queue.job(tiny).state not in ("queued", "preparing"), 240)
        job = queue.job(tiny)
        assert job.state == "ready", job.describe()
        assert job.report == str(db.parent / "runs" / f"job-{tiny}" / "report.html"), "the job's own folder"
        assert not (tmp_path / "out").exists(), "the job file's output.folder is not used by the runner"
        time.sleep(0.5)
        assert queue.job(tiny).state == "ready", "no sheet starts before the operator confirms it"
        code, out, _ = cli("runner", "status", "--db", db)
        assert code == 0 and f"job {tiny:>4} tiny" in out and "load and confirm" in out
        code, out, _ = cli("runner", "confirm", str(tiny), "--db", db)
        assert code == 0
        runner.run_until_idle(timeout=120)
    finally:
        runner.stop()
    assert queue.job(tiny).state == "done"
    sheets = queue.sheets(tiny)
    expected = [line.wire.decode().strip() for s in sheets for line in load_program(s.program).lines]
    assert executed_program_lines(log) == expected
    code, _, err = cli("runner", "pause", str(tiny), "--db", db)
    assert code == 2 and err.strip() == f"fabline runner: error: job {tiny}: already done"
