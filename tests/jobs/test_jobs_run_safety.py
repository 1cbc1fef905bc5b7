"""`fabline run` at a real machine: nothing moves without a confirmation it can ask for, one run per job folder,
and a new run never cuts over an interrupted one unless asked to (--restart) or continued (--resume)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from fabline.link import SimulatorServer
from fabline.link.journal import Journal
from fabline.locks import exclusive_lock, lock_path
from fabline.machine import load_program
from runner_support import executed_program_lines

JOB = """
name = "safety"
stages = ["unroll", "nest", "export", "stream"]
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[stock]
sheet = "1200x500"
[machine]
time_scale = 1000.0
ports = ["{port}"]
[output]
folder = "out"
"""


def write_job(tmp_path: Path, port: str) -> Path:
    job = tmp_path / "safety.toml"
    job.write_text(JOB.format(port=port), encoding="utf-8")
    return job


def fabline(*args, **options) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabline", *map(str, args)], capture_output=True, text=True,
                          timeout=300, **options)


def test_a_real_machine_with_standard_input_closed_is_refused_before_anything_is_done(tmp_path):
    log = tmp_path / "executed.log"
    with SimulatorServer(log=log, time_scale=100.0) as simulator:  # socket://: a machine fabline cannot see into
        job = write_job(tmp_path, simulator.url)
        closed = fabline("run", job, preexec_fn=lambda: os.close(0), stdin=subprocess.DEVNULL)
        assert closed.returncode == 2 and "Traceback" not in closed.stderr
        assert closed.stderr.strip() == (f"fabline run: error: {job}: the job cuts on a real machine and asks before each "
                                         "sheet, but standard input is closed; run it from a terminal, or pass --yes if "
                                         "the sheets are loaded")
        assert not (tmp_path / "out").exists()
        at_end = fabline("run", job, stdin=subprocess.DEVNULL)  # open but empty (cron, nohup): the prompt gets no answer
        assert at_end.returncode == 2 and "Traceback" not in at_end.stderr
        assert at_end.stderr.strip().endswith("was not confirmed: standard input closed; nothing more is cut "
                                              "(run it again with --resume)")
    assert executed_program_lines(log) == [], "nothing moved"


def test_a_second_run_of_one_job_is_refused_naming_the_first(tmp_path, cli):
    job = write_job(tmp_path, "sim://safety-lock?time_scale=1000")
    folder = tmp_path / "out"
    with exclusive_lock(lock_path(folder), "test"):
        code, out, err = cli("run", job)
    assert code == 2 and out == ""
    assert err.strip() == (f"fabline run: error: job output folder {folder} is in use by process {os.getpid()} "
                           f"(lock {lock_path(folder)}); wait for it to finish or stop it")
    assert not folder.exists(), "nothing written"


def test_a_new_run_over_an_interrupted_one_needs_restart_or_resume(tmp_path, cli):
    log = tmp_path / "out" / "executed.log"  # a port writes only inside the output folder
    job = write_job(tmp_path, f"sim://safety-restart?time_scale=1000&log={log}")
    interrupted = tmp_path / "out" / "gcode" / "safety_S001.gcode.journal"
    with Journal(interrupted) as journal:  # what a killed run leaves: started, never finished
        journal.record("start", program="safety_S001.gcode", sha256="0" * 64, lines=10, mode="counting")
    code, _, err = cli("run", job)
    assert code == 2 and err.strip() == (
        "fabline run: error: safety.toml: an earlier run stopped before finishing safety_S001.gcode; "
        "continue it with --resume, or cut every sheet afresh with --restart")
    assert [p.name for p in (tmp_path / "out").rglob("*") if p.is_file()] == ["safety_S001.gcode.journal"]
    code, out, err = cli("run", job, "--restart")
    assert code == 0, err
    programs = sorted((tmp_path / "out" / "gcode").glob("*.gcode"))
    assert programs and all(f"{p.name}.journal" in os.listdir(p.parent) for p in programs)
    assert len(executed_program_lines(log)) == sum(len(load_program(p).lines) for p in programs)
