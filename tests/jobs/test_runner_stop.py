"""`fabline runner serve` stops cleanly, as real processes and real signals show: SIGTERM, SIGINT or SIGHUP while a
job is being prepared (the export's worker processes running) leaves no process the server started, frees the
port, withdraws the record and the token, gives the job back to the queue whole, exits 143, 130 or 129 with one
line; the next server on the same folder starts at once, and a machine left off its command line is gone from
the page's API and from `fabline runner status`. A kill -9 of the server alone takes its workers with it, and
the next server takes its lock over with a note. SIGTERM while a sheet is cut: the restart waits for the
operator, and "resume here" cuts every line exactly once."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from fabline.jobs.queue import JobQueue
from fabline.link import SimulatorServer
from runner_support import JOBS_CLI, executed_program_lines, free_port, square_program, wire_lines

REPO = Path(__file__).resolve().parents[2]
TOKEN = "stop-token"
SERVE = [sys.executable, "-c", "import faulthandler, signal\nfaulthandler.register(signal.SIGUSR2, all_threads=True)\n"
         + JOBS_CLI[2]]
"""The runner's command, telling where each of its threads is on SIGUSR2 (what a test shows when a stop hangs)."""
JOB = """
name = "medium"
[model]
design = "enneper"
[model.options]
size = [3.0, 3.0]
spacing = 0.3
[stock]
sheet = "1000x500"
[nest]
time_limit = 1.0
[output]
folder = "out"
"""
"""About 30 sheets: the export's worker processes run for seconds, so a signal can land while they work."""


def processes() -> dict[int, tuple[int, int, str]]:
    """Every process on the machine: pid -> (parent pid, process group, state letter), from /proc."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            state, ppid, pgid = stat[stat.rindex(")") + 2:].split()[:3]
            found[int(entry.name)] = (int(ppid), int(pgid), state)
    return found


def below(pid: int) -> set[int]:
    """The living processes whose chain of parents leads to `pid`."""
    table = processes()
    found: set[int] = set()
    level = {pid}
    while level:
        level = {child for child, (parent, _, state) in table.items() if parent in level and state != "Z"}
        found |= level
    return found


def alive(pids: set[int]) -> set[int]:
    table = processes()
    return {pid for pid in pids if pid in table and table[pid][2] != "Z"}


def in_group(pgid: int) -> set[int]:
    return {pid for pid, (_, group, state) in processes().items() if group == pgid and state != "Z"}


def listening_inode(port: int) -> str:
    """The socket inode listening on 127.0.0.1:port, from /proc/net/tcp."""
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[1] == f"0100007F:{port:04X}" and fields[3] == "0A":
            return fields[9]
    raise AssertionError(f"nothing listens on port {port}")


def open_files(pid: int) -> set[str]:
    """What the process has open: paths, and socket:[inode] for sockets."""
    found = set()
    try:
        fds = list(Path(f"/proc/{pid}/fd").iterdir())
    except OSError:  # it has ended meanwhile
        return found
    for fd in fds:
        try:
            found.add(os.readlink(fd))
        except OSError:
            pass
    return found


def port_is_free(port: int) -> bool:
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
            probe.listen()
        except OSError:
            return False
    return True


class Shop:
    """A jobs folder with the medium job file, its own state folder, and servers started on it."""

    def __init__(self, tmp_path: Path):
        self.tmp = tmp_path
        self.jobs = tmp_path / "jobs"
        self.jobs.mkdir()
        (self.jobs / "medium.toml").write_text(JOB, encoding="utf-8")
        self.db = self.jobs / "runner.sqlite"
        self.port = free_port()
        self.env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")}
        self.started: list[tuple[subprocess.Popen, Path]] = []

    def end(self) -> None:
        """Kill whatever a failed test left running."""
        for server, _ in self.started:
            for pid in in_group(server.pid):
                os.kill(pid, signal.SIGKILL)
            if server.poll() is None:
                server.wait(10)

    def serve(self, *machines: str) -> tuple[subprocess.Popen, Path, Path]:
        """`fabline runner serve` on the folder (its own session); returns it and its stdout and stderr files."""
        out, err = self.tmp / f"serve{len(self.started) + 1}.out", self.tmp / f"serve{len(self.started) + 1}.err"
        command = [*SERVE, "runner", "serve", "--jobs", str(self.jobs), "--web-port", str(self.port), "--token",
                   TOKEN, "--scan", "0.1", *(f"--machine={m}" for m in machines)]
        with out.open("w") as stdout, err.open("w") as stderr:
            server = subprocess.Popen(command, cwd=REPO, env=self.env, stdout=stdout, stderr=stderr,
                                      start_new_session=True)
        self.started.append((server, err))
        return server, out, err

    def state(self, server: subprocess.Popen, err: Path, timeout: float = 60) -> dict:
        """The page's /api/state once the server answers."""
        deadline = time.monotonic() + timeout
        while True:
            assert server.poll() is None, f"the server exited {server.returncode}: {err.read_text()}"
            try:
                return httpx.get(f"http://127.0.0.1:{self.port}/api/state", headers={"X-Fabline-Token": TOKEN},
                                 timeout=5).json()
            except httpx.HTTPError:
                assert time.monotonic() < deadline, "the server never answered"
                time.sleep(0.1)

    def workers(self, server: subprocess.Popen, err: Path) -> set[int]:
        """Wait until the job is being prepared and the server has worker processes; returns them."""
        queue = JobQueue(self.db)
        deadline = time.monotonic() + 240
        try:
            while True:
                assert server.poll() is None, f"the server exited {server.returncode}: {err.read_text()}"
                jobs = queue.jobs()
                assert not jobs or jobs[0].state in ("queued", "preparing"), jobs[0].describe()
                children = below(server.pid)
                if jobs and jobs[0].state == "preparing" and children:
                    return children
                assert time.monotonic() < deadline, "no worker process while the job was being prepared"
                time.sleep(0.01)
        finally:
            queue.close()

    def stop(self, server: subprocess.Popen, number: int) -> int:
        server.send_signal(number)
        try:
            return server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            server.send_signal(signal.SIGUSR2)
            time.sleep(1)
            err = next(err for started, err in self.started if started is server)
            raise AssertionError(f"the server did not stop; its threads:\n{err.read_text()[-6000:]}") from None


@pytest.fixture
def shop(tmp_path):
    shop = Shop(tmp_path)
    yield shop
    shop.end()


@pytest.mark.parametrize("number, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)],
                         ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_stop_signal_during_preparation_ends_everything_and_the_next_server_starts(shop, number, code):
    server, _, err = shop.serve("m1=sim://stop-m1?time_scale=100", "m2=sim://stop-m2?time_scale=100")
    assert [m["name"] for m in shop.state(server, err)["machines"]] == ["m1", "m2"]
    workers = shop.workers(server, err)
    kept = {f"socket:[{listening_inode(shop.port)}]", f"{shop.db}.lock"}  # both would outlive the server
    deadline = time.monotonic() + 2  # a worker just forked closes its copies as it starts
    while any(open_files(worker) & kept for worker in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(open_files(worker) & kept for worker in workers), "a worker keeps the page's socket or the lock"
    assert shop.stop(server, number) == code, err.read_text()
    assert err.read_text().splitlines()[-1].startswith(f"fabline runner: stopped by {signal.Signals(number).name} ")
    assert not alive(workers | {server.pid}), "a worker outlived the server"
    assert not in_group(server.pid), "a process of the server's group is left"
    assert port_is_free(shop.port)
    assert not (shop.jobs / "runner.server.json").exists() and not (shop.jobs / "runner.token").exists()
    job = JobQueue(shop.db).jobs()[0]
    assert job.state == "queued", job.describe()  # given back whole: prepared afresh at the next start

    again, out, err = shop.serve("m2=sim://stop-m2?time_scale=100")  # m1 left off the command line
    try:
        assert [m["name"] for m in shop.state(again, err)["machines"]] == ["m2"]
        assert "fabline runner: machine m1 removed (not given with --machine)" in out.read_text().splitlines()
        status = subprocess.run([*JOBS_CLI, "runner", "status", "--jobs", str(shop.jobs)], cwd=REPO, env=shop.env,
                                capture_output=True, text=True, timeout=60)
        machines = [line for line in status.stdout.splitlines() if line.startswith("machine ")]
        assert status.returncode == 0 and len(machines) == 1 and machines[0].startswith("machine m2 "), status.stdout
        assert status.stdout.startswith(f"runner http://127.0.0.1:{shop.port}"), "asked the running server"
    finally:
        assert shop.stop(again, signal.SIGTERM) == 143, err.read_text()
    assert not in_group(again.pid) and port_is_free(shop.port)


def test_a_killed_server_takes_its_workers_along_and_the_next_one_takes_its_lock_over(shop):
    server, _, err = shop.serve("m1=sim://kill-m1?time_scale=100")
    workers = shop.workers(server, err)
    os.kill(server.pid, signal.SIGKILL)  # the server alone, as the out-of-memory killer would
    server.wait(timeout=30)
    deadline = time.monotonic() + 20  # every process it forked (the snapshot's and any forked since) is in its group
    while in_group(server.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(workers) and not in_group(server.pid), f"outlived their killed server: {in_group(server.pid)}"
    assert port_is_free(shop.port)
    again, out, err = shop.serve("m1=sim://kill-m1?time_scale=100")
    try:
        shop.state(again, err)
        assert (f"fabline runner: process {server.pid} ended without stopping its runner of queue {shop.db}; its lock "
                f"{shop.db}.lock is taken over") in out.read_text().splitlines()
    finally:
        assert shop.stop(again, signal.SIGTERM) == 143, err.read_text()


def test_sigterm_while_a_sheet_is_cut_leaves_it_for_the_operator_and_resume_cuts_each_line_once(tmp_path):
    (tmp_path / "jobs").mkdir()
    program = square_program(tmp_path / "sheet.gcode", 20, 20, squares=12, closed=False)
    db = tmp_path / "jobs" / "runner.sqlite"
    queue = JobQueue(db)
    job_id = queue.submit("cut", programs=[(program.stem, str(program), "")])
    log = tmp_path / "executed.log"
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")}
    with SimulatorServer(log=log, time_scale=5.0, faults={"settings": "32:1"}) as simulator:
        command = [*JOBS_CLI, "runner", "serve", "--jobs", str(tmp_path / "jobs"), "--machine", f"m1={simulator.url}",
                   "--auto-confirm", "--web-port", str(free_port()), "--token", TOKEN]
        runner = subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True, start_new_session=True)
        deadline = time.monotonic() + 60
        while queue.sheets(job_id)[0].done_lines < 8:
            assert runner.poll() is None and time.monotonic() < deadline, runner.stderr.read()
            time.sleep(0.01)
        runner.send_signal(signal.SIGTERM)
        assert runner.wait(timeout=60) == 143
        assert runner.stderr.read().splitlines()[-1].startswith("fabline runner: stopped by SIGTERM ")
        runner.stderr.close()
        assert queue.job(job_id).state in ("cutting", "attention"), queue.job(job_id).describe()
        held = len(executed_program_lines(log))
        runner = subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True, start_new_session=True)
        try:
            deadline = time.monotonic() + 60
            while queue.job(job_id).state != "attention":
                assert runner.poll() is None and time.monotonic() < deadline, runner.stderr.read()
                time.sleep(0.02)
            time.sleep(0.3)
            assert len(executed_program_lines(log)) == held, "the machine moved by itself after the restart"
            queue.resolve(job_id, "resume")
            deadline = time.monotonic() + 120
            while queue.job(job_id).state != "done":
                assert runner.poll() is None and time.monotonic() < deadline, queue.job(job_id).describe()
                time.sleep(0.05)
        finally:
            runner.send_signal(signal.SIGTERM)
            assert runner.wait(timeout=60) == 143
            runner.stderr.close()
    assert executed_program_lines(log) == wire_lines(program), "each line cut exactly once"


def test_a_machine_left_off_the_next_start_is_forgotten_and_a_job_waiting_on_it_goes_to_another(tmp_path):
    from fabline.jobs.runner import MachineConfig, Runner

    program = square_program(tmp_path / "sheet.gcode", 10, 10)
    queue = JobQueue(tmp_path / "runner.sqlite")
    Runner(queue.path, [MachineConfig("m1", "sim://a"), MachineConfig("m2", "sim://b")])
    waiting, cut = (queue.submit(name, programs=[("S1", str(program), "")]) for name in ("waiting", "cut"))
    assert queue.claim_for_machine("m2").id == waiting
    queue.confirm_sheet(waiting)  # loaded on m2's bed
    with queue.transaction() as db:
        db.execute("UPDATE jobs SET machine = 'm2', state = 'attention', attention = '{}' WHERE id = ?", (cut,))
    runner = Runner(queue.path, [MachineConfig("m1", "sim://a")])
    assert runner.removed == ["m2"]
    assert [m["name"] for m in queue.machines()] == ["m1"]
    job = queue.job(waiting)
    assert (job.state, job.machine, job.confirmed) == ("ready", None, -1), "to be confirmed loaded on another machine"
    assert (queue.job(cut).state, queue.job(cut).machine) == ("attention", "m2"), "a half-cut sheet stays where it is"
    assert queue.events()[-1]["message"] == ("machine m2 removed (not among the runner's machines); job 2's sheet was "
                                             "being cut on it: start the runner with m2 again to go on, or cancel the job")


def test_a_lock_held_by_the_children_of_a_process_that_ended_names_them_and_is_taken_over_when_they_end(tmp_path):
    from fabline.errors import FablineError
    from fabline.locks import exclusive_lock

    lock = tmp_path / "queue.lock"
    holder = subprocess.run([sys.executable, "-c", (
        "import os, sys, time\n"
        "from fabline.locks import exclusive_lock\n"
        "with exclusive_lock(sys.argv[1], 'q'):\n"
        "    child = os.fork()\n"
        "    if child == 0:\n"
        "        os.close(1), os.close(2)\n"
        "        time.sleep(60)\n"
        "        os._exit(0)\n"
        "    print(os.getpid(), child, flush=True)\n"
        "    os._exit(0)\n"), str(lock)], cwd=REPO, capture_output=True, text=True, timeout=30)
    parent, child = map(int, holder.stdout.split())
    try:
        with pytest.raises(FablineError) as refused:
            with exclusive_lock(lock, "the test queue"):
                pass
        assert str(refused.value) == (f"the test queue is in use by process {child}, left by process {parent}, which "
                                      f"has ended (`kill {child}` ends it) (lock {lock}); wait for it to finish or stop it")
    finally:
        os.kill(child, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while alive({child}) and time.monotonic() < deadline:
        time.sleep(0.05)
    noted = []
    with exclusive_lock(lock, "the test queue", taken_over=noted.append):
        assert noted == [parent]
    with exclusive_lock(lock, "the test queue", taken_over=noted.append):
        assert noted == [parent], "a lock released in order leaves no pid behind"
