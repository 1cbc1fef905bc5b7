"""`fabline runner status/pause/...` find the runner from any folder (issue 20): a real `fabline runner serve` on a
free port publishes its discovery record; the commands talk to it over HTTP with its token while it runs, open
the queue it left once it stopped, and say in one line where they looked when there is none."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from fabline.jobs.discovery import RemoteRunner, Search, find_runner, record_beside, token_file, user_record
from fabline.jobs.queue import JobQueue
from runner_support import free_port, square_program


def _wait_for_server(state: Path, server: subprocess.Popen) -> RemoteRunner:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        assert server.poll() is None, server.stderr.read()
        try:
            found = find_runner(Search())
        except Exception:  # noqa: BLE001 - not up yet
            found = None
        if isinstance(found, RemoteRunner):
            return found
        time.sleep(0.2)
    raise AssertionError("the runner never answered")


def test_runner_commands_find_the_running_server_then_its_queue_then_say_where_they_looked(tmp_path, cli,
                                                                                         monkeypatch):
    shop, elsewhere, state = tmp_path / "shop", tmp_path / "elsewhere", tmp_path / "state"
    (shop / "jobs").mkdir(parents=True)
    elsewhere.mkdir()
    monkeypatch.setenv("XDG_STATE_HOME", str(state))
    monkeypatch.chdir(elsewhere)  # no ./jobs here: only the records lead to the runner
    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "fabline", "runner", "serve", "--jobs", "jobs", "--web-port",
                               str(port), "--token", "shop-token", "--machine", "m1=sim://discovery?time_scale=50"],
                              cwd=shop, env={**os.environ, "PYTHONPATH": os.environ.get("PYTHONPATH", "")},
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    db = (shop / "jobs" / "runner.sqlite").resolve()
    try:
        remote = _wait_for_server(state, server)
        assert (remote.url, remote.token, remote.db) == (f"http://127.0.0.1:{port}", "shop-token", db)
        record = json.loads(user_record().read_text())
        assert record == json.loads(record_beside(db).read_text())
        assert (record["pid"], record["token_file"]) == (server.pid, str(token_file(db)))
        assert token_file(db).stat().st_mode & 0o077 == 0, "the token is the user's only"

        program = square_program(elsewhere / "plate.gcode", 20, 20, squares=2)
        code, out, err = cli("runner", "submit", "--gcode", program, "--name", "plate-job")
        assert code == 0 and out == f"job 1: plate-job ready, 1 sheet(s) (queue {db})\n", err
        deadline = time.monotonic() + 30
        while JobQueue(db).job(1).machine is None and time.monotonic() < deadline:
            time.sleep(0.1)  # the machine takes the job and waits for the operator
        code, out, err = cli("runner", "status")
        assert code == 0, err
        lines = out.splitlines()
        assert lines[0] == f"runner http://127.0.0.1:{port} (queue {db})"  # asked over HTTP
        assert any(line.startswith("job    1 plate-job") for line in lines)
        assert "     load sheet 1 of 1: plate" in lines
        code, out, err = cli("runner", "pause", "plate-job")  # by name, through the server
        assert code == 0 and out.startswith("job 1: paused"), out + err
        assert JobQueue(db).job(1).state == "paused"
    finally:
        server.send_signal(signal.SIGINT)
        server.communicate(timeout=60)
    assert not record_beside(db).exists() and not token_file(db).exists(), "a stopped server withdraws its record"

    code, out, err = cli("runner", "resume", "1")  # the server is gone: the queue it left, from the user's record
    assert code == 0 and out.startswith("job 1: ready"), out + err
    code, out, _ = cli("runner", "status")
    assert out.splitlines()[0] == f"queue {db} (no runner server running)"
    code, out, _ = cli("runner", "status", "--jobs", shop / "jobs")
    assert out.splitlines()[0] == f"queue {db} (no runner server running)"

    user_record().unlink()
    code, out, err = cli("runner", "status")
    assert code == 2 and out == ""
    assert err == (f"fabline runner: error: no runner found (looked for a running server's record or a queue database "
                   f"at {elsewhere / 'jobs' / 'runner.server.json'}, {user_record()}, jobs/runner.sqlite); start one "
                   "with `fabline runner serve`, or name its queue with --db or its folder with --jobs\n")
