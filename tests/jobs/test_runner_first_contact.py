"""First contact (issue 24): `fabline runner serve --jobs jobs/ --web-port N`, started as docs/jobs.md says, with
no `--machine`, makes a simulated machine set up as the example job's profile (grbl-laser: laser mode, a 4 x 2 m bed),
says so, and cuts a job written for that profile to its end: its sheets stream instead of being refused for
`$32` or for travel, as they were on a stock controller."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import httpx

from runner_support import free_port

SMALL_JOB = """
name = "first-contact"
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[output]
folder = "../out/first-contact"
"""
"""A small job with the example job's defaults (profile grbl-laser, 4000 x 2000 mm sheets): preparing the
example job itself takes minutes."""


def test_runner_serve_as_the_readme_says_cuts_a_grbl_laser_job_on_its_default_machine(tmp_path):
    shop = tmp_path / "shop"
    (shop / "jobs").mkdir(parents=True)
    (shop / "jobs" / "first-contact.toml").write_text(SMALL_JOB, encoding="utf-8")
    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "fabline", "runner", "serve", "--jobs", "jobs/", "--web-port",
                               str(port)], cwd=shop, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              env={**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")})
    try:
        lines = [server.stdout.readline() for _ in range(4)]
        assert lines[3] == "  machine sim1=sim://sim1?machine=grbl-laser&time_scale=2000 (profile grbl-laser: laser mode $32=1, " \
                           "4100 x 2100 mm travel)\n", lines
        token = lines[1].removeprefix("token: ").strip()
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"X-Fabline-Token": token}, timeout=10)
        deadline = time.monotonic() + 300

        def job() -> dict | None:
            try:
                jobs = client.get("/api/state").json()["jobs"]
            except httpx.TransportError:
                return None
            return jobs[0] if jobs else None

        while (state := job()) is None or state["state"] in ("queued", "preparing") or state["machine"] is None:
            assert server.poll() is None and time.monotonic() < deadline, server.stderr.read() if server.poll() else state
            time.sleep(0.2)
        assert state["state"] == "ready", state["status"]
        assert client.post(f"/api/jobs/{state['id']}/confirm").status_code == 200
        while (state := job())["state"] == "ready" or (state["state"] == "cutting" and
                                                        state["sheet_list"][0]["done_lines"] < 5):
            assert time.monotonic() < deadline, state
            time.sleep(0.2)
        assert state["state"] == "cutting", state["status"]  # not "needs attention: ... needs $32=1"
        machine = client.get("/api/state").json()["machines"][0]
        assert (machine["name"], machine["state"]) == ("sim1", f"cutting job {state['id']} sheet 1 of {state['sheets']}")
        while (state := job())["state"] not in ("done", "failed", "cancelled", "attention"):  # to the job's end
            assert time.monotonic() < deadline, state
            if state["state"] == "ready":  # the operator loads the next sheet
                client.post(f"/api/jobs/{state['id']}/confirm")
            time.sleep(0.2)
        assert state["state"] == "done", state["status"]
        assert [s["done_lines"] for s in state["sheet_list"]] == [s["lines"] for s in state["sheet_list"]]
    finally:
        server.send_signal(signal.SIGINT)
        server.communicate(timeout=60)


def test_serve_refuses_a_simulated_machine_of_an_unknown_profile_before_starting(tmp_path, cli):
    (tmp_path / "jobs").mkdir()
    code, out, err = cli("runner", "serve", "--jobs", tmp_path / "jobs", "--machine", "m1=sim://m1?machine=grbl-lazer")
    assert code == 2 and out == ""
    assert err.splitlines()[0].startswith("fabline runner: error: --machine m1=sim://m1?machine=grbl-lazer: ")
    assert "grbl-laser" in err.splitlines()[0], "the known profiles are named"
    assert not (tmp_path / "jobs" / "runner.sqlite").exists(), "nothing started"
