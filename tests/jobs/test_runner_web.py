"""The runner's web page: 403 without the token, and in headless Chromium: load, confirm sheets, watch it finish."""

from __future__ import annotations

import os
import re
import socket
import time

import httpx
import pytest

from conftest import without_usage
from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner
from fabline.jobs.web import TOKEN_HEADER
from runner_support import (TOKEN, executed_program_lines, free_port, headless_chromium, page_server, square_program,
                            wire_lines)


@pytest.fixture
def served(tmp_path):
    """A queue with one 2-sheet job, a runner on one simulated machine, and the web server on 127.0.0.1."""
    db = tmp_path / "runner.sqlite"
    queue = JobQueue(db)
    sheets = [square_program(tmp_path / f"sheet{k + 1}.gcode", 30, 30 + 40 * k, squares=10) for k in range(2)]
    job_id = queue.submit("web-job", programs=[(p.stem, str(p), "") for p in sheets])
    log = tmp_path / "executed.log"
    runner = Runner(db, [MachineConfig("m1", f"sim://web-m1?time_scale=8&settings=32:1&log={log}")], poll=0.05, prepare=False)
    runner.start()
    with page_server(db) as url:
        yield {"url": url, "queue": queue, "job": job_id, "sheets": sheets, "log": log}
    runner.stop()


def test_everything_but_the_page_shell_needs_the_token(served):
    url, job = served["url"], served["job"]
    with httpx.Client(base_url=url, timeout=10) as client:
        shell = client.get("/")
        assert shell.status_code == 200 and "web-job" not in shell.text
        for path in ("/api/state", f"/api/jobs/{job}/sheets/0.svg", "/api/state?token=wrong"):
            answer = client.get(path)
            assert answer.status_code == 403 and answer.json() == {"error": "forbidden: a valid token is required"}
        with client.stream("GET", "/api/events") as events:
            assert events.status_code == 403
        assert client.get("/api/state", headers={TOKEN_HEADER: TOKEN}).status_code == 200
        assert client.post(f"/api/jobs/{job}/confirm").status_code == 403
        assert client.post(f"/api/jobs/{job}/cancel", headers={TOKEN_HEADER: "wrong"}).status_code == 403
        assert client.post("/api/jobs", json={"job_file": "x.toml"}).status_code == 403
        assert served["queue"].job(job).confirmed == -1, "a refused request changes nothing"
        answer = client.post(f"/api/jobs/{job}/frobnicate", headers={TOKEN_HEADER: TOKEN})
        assert answer.status_code == 404
        answer = client.post(f"/api/jobs/{job}/resume", headers={TOKEN_HEADER: TOKEN})
        assert answer.status_code == 409 and "not paused" in answer.json()["error"]
        assert client.post("/api/jobs/77/confirm", headers={TOKEN_HEADER: TOKEN}).status_code == 409
        picture = client.get(f"/api/jobs/{job}/sheets/0.svg?token={TOKEN}")
        assert picture.status_code == 200 and picture.text.startswith("<svg")
        assert client.get(f"/api/jobs/{job}/sheets/5.svg?token={TOKEN}").status_code == 404
        assert client.get(f"/api/jobs/{10 ** 20}/sheets/0.svg?token={TOKEN}").status_code == 404


def test_a_job_file_that_is_a_fifo_or_a_device_is_refused_at_once_and_the_page_keeps_answering(served, tmp_path):
    fifo = tmp_path / "job.toml"
    os.mkfifo(fifo)  # reading it would block until a writer comes
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (1 << 20) + b"\n")
    with httpx.Client(base_url=served["url"], timeout=10, headers={TOKEN_HEADER: TOKEN}) as client:
        for path, error in ((fifo, f"{fifo}: is a FIFO (named pipe), not a regular file: give the TOML file itself"),
                            ("/dev/zero", "/dev/zero: is a character device, not a regular file: give the TOML file "
                                          "itself"),
                            (big, f"{big}: 1048577 bytes, more than the 1048576 bytes (1 MiB) a TOML file may have: "
                                  "not read")):
            answer = client.post("/api/jobs", json={"job_file": str(path)})
            assert answer.status_code == 400 and answer.json() == {"error": error}
        assert client.get("/api/state").status_code == 200


def test_a_request_naming_another_host_is_refused_dns_rebinding(served):
    with httpx.Client(base_url=served["url"], timeout=10) as client:
        for host in ("evil.example", "127.0.0.1.nip.io", "attacker.test:8080"):
            answer = client.get("/api/state", headers={"Host": host, TOKEN_HEADER: TOKEN})
            assert answer.status_code == 400, host
            assert client.get("/", headers={"Host": host}).status_code == 400
        for host in ("localhost", "127.0.0.1:80", "[::1]:8080"):
            assert client.get("/", headers={"Host": host}).status_code == 200, host


def test_the_server_binds_to_localhost_only_by_default():
    from fabline.cli import build_parser

    args = build_parser().parse_args(["runner", "serve"])
    assert args.host == "127.0.0.1"


@pytest.mark.parametrize("option, value, message", [
    ("--web-port", "99999", "argument --web-port: must be a positive whole number, at most 65535, got '99999'"),
    ("--port", "0", "argument --port: must be a positive whole number, at most 65535, got '0'"),  # the old name
    ("--scan", "-1", "argument --scan: must be a positive number, got '-1'"),
    ("--scan", "nan", "argument --scan: must be a positive number, got 'nan'"),
])
def test_serve_refuses_an_option_that_is_not_a_positive_number(capsys, tmp_path, option, value, message):
    from fabline.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["runner", "serve", "--jobs", str(tmp_path / "jobs"), option, value])
    out, err = capsys.readouterr()
    assert stop.value.code == 2 and out == ""
    assert without_usage(err) == f"fabline runner serve: error: {message}\n"
    assert not list(tmp_path.iterdir())


def test_page_in_headless_chromium_confirm_sheets_and_watch_progress_reach_done(served):
    job, queue = served["job"], served["queue"]
    with headless_chromium() as (sync_api, browser):
        page = browser.new_page()
        page.goto(f"{served['url']}/?token={TOKEN}")
        row = page.locator(f"#queue tr[data-job='{job}']")
        sync_api.expect(row).to_have_attribute("data-state", "ready")
        for k in range(2):
            confirm = page.locator(f".machine button.confirm[data-job='{job}']")
            sync_api.expect(confirm).to_be_visible(timeout=20000)
            sync_api.expect(confirm).to_contain_text(f"sheet{k + 1}")
            confirm.click()
            progress = page.locator(".machine .sheet-progress")
            sync_api.expect(progress).to_contain_text(f"cutting sheet {k + 1} of 2", timeout=20000)
            eta = page.locator(".machine .eta")  # planned machine time corrected by the pace: sheet and job
            sync_api.expect(eta).to_contain_text(re.compile(r"^sheet: elapsed \d+:\d\d:\d\d, remaining \d+:\d\d:\d\d, "
                                                            r"done about .+; job: elapsed \d+:\d\d:\d\d, remaining"),
                                                 timeout=20000)
            picture = page.locator(".machine img")
            sync_api.expect(picture).to_be_visible()
            page.wait_for_function("() => { const i = document.querySelector('.machine img');"
                                   " return i && i.complete && i.naturalWidth > 0; }", timeout=20000)
            if k == 1:  # the operator pauses the second sheet (feed hold) and resumes it from the page
                row.locator("button[data-action='pause']").click()
                sync_api.expect(row).to_have_attribute("data-state", "paused", timeout=20000)
                with httpx.Client(base_url=served["url"], timeout=10, headers={TOKEN_HEADER: TOKEN}) as client:
                    held = next(m for m in client.get("/api/state").json()["machines"] if m["name"] == "m1")
                    svg = client.get(f"/api/jobs/{job}/sheets/1.svg").text
                tool = re.search(r'<g class="tool" data-x="([-\d.]+)" data-y="([-\d.]+)"', svg)  # the head, live
                assert tool and (float(tool[1]), float(tool[2])) == pytest.approx(held["position"][:2], abs=1e-3)
                row.locator("button[data-action='resume']").click()
                sync_api.expect(row).to_have_attribute("data-state", "cutting", timeout=20000)
        sync_api.expect(row).to_have_attribute("data-state", "done", timeout=180000)  # a guard against a hang, not a speed goal
        sync_api.expect(row.locator(".state")).to_have_text("done")
    assert queue.job(job).state == "done"
    expected = [line for sheet in served["sheets"] for line in wire_lines(sheet)]
    assert executed_program_lines(served["log"]) == expected


def test_serve_prints_a_fresh_token_and_binds_to_localhost(tmp_path):
    import signal
    import subprocess

    from runner_support import JOBS_CLI

    (tmp_path / "jobs").mkdir()
    port = free_port()
    server = subprocess.Popen([*JOBS_CLI, "runner", "serve", "--jobs", str(tmp_path / "jobs"), "--port", str(port)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        lines = [server.stdout.readline() for _ in range(3)]
        token = next(line.split()[1] for line in lines if line.startswith("token: "))
        assert len(token) >= 20 and f"open http://127.0.0.1:{port}/?token={token}" in "".join(lines)
        deadline = time.monotonic() + 30
        while True:
            try:
                state = httpx.get(f"http://127.0.0.1:{port}/api/state", headers={TOKEN_HEADER: token}, timeout=5)
                break
            except httpx.ConnectError:
                assert time.monotonic() < deadline and server.poll() is None, server.stderr.read()
                time.sleep(0.2)
        assert [m["name"] for m in state.json()["machines"]] == ["sim1"]
        assert httpx.post(f"http://127.0.0.1:{port}/api/jobs/1/cancel", timeout=5).status_code == 403
        answer = httpx.post(f"http://127.0.0.1:{port}/api/jobs/1/cancel", headers={TOKEN_HEADER: token}, timeout=5)
        assert answer.status_code == 409 and answer.json()["error"] == "job 1: no such job"
        address = socket.gethostbyname(socket.gethostname())
        if not address.startswith("127."):  # not reachable on this host's network address
            with socket.socket() as probe:
                assert probe.connect_ex((address, port)) != 0
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=30)
        server.stdout.close()
        server.stderr.close()


def test_page_keeps_its_buttons_under_live_updates_confirms_cancel_requeues_and_fits_phone_and_desktop(served, tmp_path):
    job, queue = served["job"], served["queue"]
    with headless_chromium() as (sync_api, browser):
        page = browser.new_page(viewport={"width": 1366, "height": 900})
        page.goto(f"{served['url']}/?token={TOKEN}")
        sync_api.expect(page.locator("#live")).to_have_text("live")
        sync_api.expect(page.locator("#ports")).to_contain_text("serial ports found: ")
        row = page.locator(f"#queue tr[data-job='{job}']")
        page.locator(f".machine button.confirm[data-job='{job}']").click()
        sync_api.expect(row).to_have_attribute("data-state", "cutting", timeout=20000)
        page.evaluate("(job) => { window.kept = [document.querySelector(`#queue tr[data-job='${job}'] button[data-action='cancel']`),"
                      " document.querySelector('.machine img'), document.querySelector('.machine .sheet-progress')]; }", job)
        for _ in range(3):  # live updates come and go while the pointer rests on the cancel button
            before = page.locator(".machine .sheet-progress").get_attribute("data-done")
            row.locator("button[data-action='cancel']").hover()
            page.wait_for_function(f"() => document.querySelector('.machine .sheet-progress').dataset.done !== '{before}'",
                                   timeout=20000)
        assert page.evaluate("() => window.kept.every((node) => node && node.isConnected)"), "rebuilt under the pointer"
        page.screenshot(path=str(tmp_path / "desktop.png"), full_page=True)
        page.set_viewport_size({"width": 390, "height": 844})
        assert page.evaluate("() => document.documentElement.scrollWidth") <= 390, "wider than a phone"
        page.screenshot(path=str(tmp_path / "phone.png"), full_page=True)
        row.locator("button[data-action='cancel']").click()
        dialog = page.locator("#confirm")
        sync_api.expect(dialog).to_contain_text(f"Cancel job {job} (web-job)? The machine stops")
        page.locator("#confirm-yes").click()
        sync_api.expect(row).to_have_attribute("data-state", "cancelled", timeout=20000)
        row.locator("button[data-action='requeue']").click()
        again = page.locator(f"#queue tr[data-job='{job + 1}']")
        sync_api.expect(again).to_have_attribute("data-state", "ready", timeout=20000)
    for name in ("desktop.png", "phone.png"):
        assert (tmp_path / name).stat().st_size > 10_000, f"{name}: the page rendered"
    assert queue.job(job).state == "cancelled" and queue.job(job + 1).name == "web-job"


def test_report_of_a_prepared_job_for_token_holders_only(served, tmp_path):
    report = tmp_path / "report.html"
    report.write_text("<html><body>the report</body></html>", encoding="utf-8")
    queue = served["queue"]
    job_id = queue.submit("with-report", job_file=str(tmp_path / "x.toml"))
    queue.claim_preparation()
    queue.prepared(job_id, [("S1", str(served["sheets"][0]), "")], str(report), str(tmp_path))
    with httpx.Client(base_url=served["url"], timeout=10) as client:
        assert client.get(f"/api/jobs/{job_id}/report").status_code == 403
        answer = client.get(f"/api/jobs/{job_id}/report?token={TOKEN}")
        assert answer.status_code == 200 and answer.text == report.read_text(encoding="utf-8")
        assert client.get(f"/api/jobs/{served['job']}/report?token={TOKEN}").status_code == 404


def test_the_progress_picture_puts_the_head_where_the_machine_is(tmp_path):
    """The head's cross-hair lies where the program's moves put that machine position in the picture: at the end
    of a cut ending at the head, on a bare picture and over a sheet picture with its own mm-per-unit scale."""
    from fabline.jobs.pictures import progress_svg

    program = tmp_path / "cut.gcode"
    program.write_text("G21\nG90\nG0 X10 Y20\nM4 S500\nG1 X70 Y45 F600\nG1 X90 Y45\nM5\n", encoding="ascii")
    sheet = tmp_path / "sheet.svg"
    sheet.write_text('<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 400 200" data-mm-per-unit="0.5">'
                     '<rect width="400" height="200"/></svg>', encoding="utf-8")
    for background in ("", str(sheet)):
        svg = progress_svg(program, 7, background, tool=(70.0, 45.0))
        first_cut = re.findall(r'<polyline points="([^"]+)"', svg)[0].split()
        circle = re.search(r'<g class="tool"[^>]*><circle cx="([-\d.]+)" cy="([-\d.]+)"', svg)
        assert (float(circle[1]), float(circle[2])) == pytest.approx(tuple(map(float, first_cut[-1].split(","))),
                                                                      abs=0.01)
    assert 'class="tool"' not in progress_svg(program, 5, str(sheet))
    assert '<circle cx="140" cy="110"' in progress_svg(program, 5, str(sheet), tool=(70.0, 45.0))  # 2 units/mm, y down

