"""The runner's HTTP API against hostile input: security headers (CSP, X-Frame-Options, nosniff) on every answer, a
hostile job's markup never runs in the page, bodies over the limit refused before they are read (in the app and in a
real `runner serve`), deep or mistyped JSON answered with one-line 400s, and no traceback for a client's input."""

from __future__ import annotations

import asyncio
import json
import logging
import re
import select
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import httpx
import pytest

from fabline.jobs.queue import JobQueue
from fabline.jobs.web import BODY_LIMIT, JSON_DEPTH, TOKEN_HEADER, create_app
from runner_support import JOBS_CLI, TOKEN, free_port, headless_chromium, page_server, square_program

MIB = 1 << 20


def run(app, requests):
    """`requests(client)` (a coroutine function) against `app` in process, with the token; its result."""
    async def main():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1",
                                     headers={TOKEN_HEADER: TOKEN}) as client:
            return await requests(client)
    return asyncio.run(main())


@pytest.fixture
def app(tmp_path):
    return create_app(tmp_path / "runner.sqlite", TOKEN)


def headers_hold(answer: httpx.Response) -> None:
    assert answer.headers["x-frame-options"] == "DENY", answer.request.url
    assert answer.headers["x-content-type-options"] == "nosniff", answer.request.url
    policy = answer.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in policy and "unsafe-inline" not in policy.split("style-src")[0], policy


def test_every_answer_carries_the_security_headers_errors_and_404s_too(app):
    async def requests(client):
        return [await client.get("/"), await client.get("/api/state"),
                await client.get("/api/state", headers={TOKEN_HEADER: "no"}),
                await client.get("/nowhere"), await client.get("/api/jobs"),  # 405: POST only
                await client.get("/", headers={"Host": "evil.example"}),
                await client.post("/api/jobs", content=b"{", headers={"Content-Type": "application/json"}),
                await client.post("/api/jobs", content=b"x", headers={"Content-Length": str(BODY_LIMIT + 1)}),
                await client.get("/api/jobs/7/sheets/0.svg"), await client.get("/api/jobs/7/report")]
    answers = run(app, requests)
    assert [a.status_code for a in answers] == [200, 200, 403, 404, 405, 400, 400, 413, 404, 404]
    for answer in answers:
        headers_hold(answer)
    page = answers[0].headers["content-security-policy"]
    directives = dict(d.strip().split(" ", 1) for d in page.split(";"))
    assert directives["default-src"] == "'self'" and directives["img-src"] == "'self' data:"
    assert re.fullmatch(r"'sha256-[A-Za-z0-9+/]{43}='", directives["script-src"]), page  # its one script, by hash
    assert re.fullmatch(r"'sha256-[A-Za-z0-9+/]{43}='", directives["style-src"]), page
    for answer in answers[1:]:  # JSON and errors may load and run nothing
        assert answer.headers["content-security-policy"].startswith("default-src 'none'")


NESTED = {"submit": ("/api/jobs", "job_file"), "resume": ("/api/jobs/1/resume", "from_line"),
          "console": ("/api/machines/m1/console", "line"), "upload": ("/api/jobs/upload", "name")}


@pytest.mark.parametrize("route", sorted(NESTED))
def test_deep_or_mistyped_json_gets_a_one_line_400_naming_the_field_and_no_traceback(app, tmp_path, route, caplog):
    JobQueue(tmp_path / "runner.sqlite").register_machine("m1", "sim://m1")
    path, key = NESTED[route]
    deep = f'{{"{key}": ' + "[" * 100_000 + "]" * 100_000 + "}"  # past the parser's recursion: a 500 before
    just_too_deep = f'{{"{key}": ' + "[" * JSON_DEPTH + "]" * JSON_DEPTH + "}"  # the object and 32 arrays: 33
    deep_enough = f'{{"{key}": ' + "[" * (JSON_DEPTH - 1) + "]" * (JSON_DEPTH - 1) + "}"  # 32 levels: parsed
    bodies = [(deep, f"body: JSON nested deeper than {JSON_DEPTH} levels"),
              (just_too_deep, f"body: JSON nested deeper than {JSON_DEPTH} levels"), (deep_enough, f"{key}: expected "),
              (f'{{"{key}": {{"a": 1}}}}', f"{key}: expected "), (f'{{"{key}": true}}', f"{key}: expected "),
              ("[1, 2]", "body: expected a JSON object"), ('"text"', "body: expected a JSON object"),
              (b"\xff\xfe{", "body: not JSON"), ("{" + '"a": 1, ' * 3, "body: not JSON"),
              ("1" * 5000, "body: not JSON")]

    async def requests(client):
        return [(await client.post(path, content=body, headers={"Content-Type": "application/json"}), said)
                for body, said in bodies]
    with caplog.at_level(logging.DEBUG):
        answers = run(app, requests)
    for answer, said in answers:
        error = answer.json()["error"]
        assert answer.status_code == 400 and error.startswith(said) and "\n" not in error, (said, answer.text[:300])
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR]


def test_from_line_must_be_a_line_number_not_a_boolean_or_a_string(app):
    async def requests(client):
        return [await client.post("/api/jobs/1/resume", json={"from_line": value}) for value in (True, "12", 0, 1.5)]
    errors = [a.json()["error"] for a in run(app, requests)]
    assert errors == ["from_line: expected a file line number from 1, got true",
                      "from_line: expected a file line number from 1, got a string",
                      "from_line: expected a file line number from 1, got 0",
                      "from_line: expected a file line number from 1, got a number"]


def test_a_body_over_the_limit_is_refused_before_it_is_read(app):
    pulled = []

    async def body(chunks: int):
        for _ in range(chunks):
            pulled.append(64 * 1024)
            yield b"[" * (64 * 1024)

    async def requests(client):
        announced = await client.post("/api/jobs", content=body(300 * 16),
                                      headers={"Content-Length": str(300 * MIB)})
        taken = sum(pulled)
        chunked = await client.post("/api/jobs", content=body(300 * 16))  # no Content-Length: chunked
        return announced, taken, chunked, sum(pulled) - taken
    announced, taken, chunked, streamed = run(app, requests)
    assert announced.status_code == 413 and announced.json()["error"] == (
        f"request body: {300 * MIB} bytes, more than the {BODY_LIMIT} bytes (4 MiB) the runner takes: not read")
    assert taken == 0  # the app never asked for a byte of it
    assert chunked.status_code == 413 and chunked.json()["error"].startswith("request body (sent without a length): ")
    assert BODY_LIMIT < streamed <= BODY_LIMIT + 64 * 1024  # refused on the chunk that passed the limit
    headers_hold(chunked)


def test_an_internal_error_is_logged_once_and_answered_with_a_one_line_500(app, monkeypatch, caplog):
    monkeypatch.setattr(JobQueue, "snapshot", lambda self: 1 / 0)

    async def requests(client):
        return await client.get("/api/state")
    with caplog.at_level(logging.ERROR):
        answer = run(app, requests)
    assert answer.status_code == 500
    assert answer.json() == {"error": "internal error in the runner (its log has the details)"}
    headers_hold(answer)
    logged = [r for r in caplog.records if r.exc_info]
    assert len(logged) == 1 and logged[0].exc_info[0] is ZeroDivisionError
    assert "GET /api/state" in logged[0].getMessage()


def vm_rss_kib(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"^VmRSS:\s+(\d+) kB", status, re.M)[1])


def post_streaming(port: int, token: str, total: int, chunked: bool) -> tuple[int, dict, int]:
    """POST `total` bytes to /api/jobs over a raw socket, 64 KiB at a time, made as they go (never held whole),
    stopping as soon as the server answers (or closes: Linux keeps what it received readable after a reset);
    (status, JSON answer, body bytes sent)."""
    head = (f"POST /api/jobs HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{TOKEN_HEADER}: {token}\r\n"
            "Content-Type: application/json\r\n"
            + ("Transfer-Encoding: chunked\r\n\r\n" if chunked else f"Content-Length: {total}\r\n\r\n"))
    piece = b"[" * (64 * 1024)
    frame = (b"%x\r\n" % len(piece)) + piece + b"\r\n" if chunked else piece
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
        sock.sendall(head.encode())
        while sent < total and not select.select([sock], [], [], 0)[0]:
            try:
                sock.sendall(frame)
            except (BrokenPipeError, ConnectionResetError):  # it answered and closed: its answer is still to be read
                break
            sent += len(piece)
        answer = b""
        while b"\r\n\r\n" not in answer or len(answer.split(b"\r\n\r\n", 1)[1]) < int(
                re.search(rb"content-length: (\d+)", answer.split(b"\r\n\r\n")[0], re.I)[1]):
            more = sock.recv(65536)
            assert more, answer
            answer += more
    head_text, body = answer.split(b"\r\n\r\n", 1)
    return int(head_text.split()[1]), json.loads(body), sent


IN_FLIGHT_KIB = 32 * 1024
"""The server's growth allowed for a refused body: what the client had in flight (a tenth of the 300 MB at most)."""


def test_a_real_runner_serve_refuses_300_mb_without_reading_it(tmp_path):
    (tmp_path / "jobs").mkdir()
    port = free_port()
    server = subprocess.Popen([*JOBS_CLI, "runner", "serve", "--jobs", str(tmp_path / "jobs"), "--port", str(port)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        token = next(line.split()[1] for line in iter(server.stdout.readline, "") if line.startswith("token: "))
        deadline = time.monotonic() + 30
        while True:
            try:
                state = httpx.get(f"http://127.0.0.1:{port}/api/state", headers={TOKEN_HEADER: token}, timeout=5)
                assert state.is_success
                break
            except httpx.ConnectError:
                assert time.monotonic() < deadline and server.poll() is None
                time.sleep(0.2)
        before = vm_rss_kib(server.pid)
        status, answer, sent = post_streaming(port, token, 300 * MIB, chunked=False)
        grown = vm_rss_kib(server.pid) - before
        assert status == 413 and answer["error"].startswith(f"request body: {300 * MIB} bytes, more than the"), answer
        # before: the whole body read, +296 MB; now what arrived before the 413 went out: up to about 11 MB seen
        # (the client's first 9.5 MB in flight, read from the socket while the answer is sent), 2 MB typically
        assert sent < 300 * MIB // 10 and grown < IN_FLIGHT_KIB, (sent, grown)
        status, answer, sent = post_streaming(port, token, 300 * MIB, chunked=True)
        grown = vm_rss_kib(server.pid) - before
        assert status == 413 and answer["error"].startswith("request body (sent without a length): "), answer
        assert sent < 300 * MIB // 10 and grown < IN_FLIGHT_KIB + BODY_LIMIT // 1024, (sent, grown)
        assert httpx.get(f"http://127.0.0.1:{port}/api/state", headers={TOKEN_HEADER: token}, timeout=5).is_success
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=30)
        errors = server.stderr.read()
        server.stdout.close()
        server.stderr.close()
    assert "Traceback" not in errors, errors


class Listener:
    """A local HTTP listener recording every request made to it (what an injected script would call home to)."""

    def __init__(self):
        self.hits: list[bytes] = []
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:  # a request, not a bare connection (Chromium may preconnect to an origin it saw)
                if request := conn.recv(4096):
                    self.hits.append(request)
                conn.sendall(b"HTTP/1.1 204 No Content\r\nContent-Length: 0\r\n\r\n")


def test_a_hostile_job_renders_as_text_and_no_script_runs(tmp_path):
    listener = Listener()
    home = f"http://127.0.0.1:{listener.port}"
    payload = (f"<img src=x onerror=\"window.__pwned='img';fetch('{home}/img')\">"
               f"<script>window.__pwned='script';fetch('{home}/script')</script>"
               f"<svg onload=\"window.__pwned='svg'\"></svg><iframe src=\"{home}/frame\"></iframe>")
    db = tmp_path / "runner.sqlite"
    queue = JobQueue(db)
    program = square_program(tmp_path / "sheet.gcode", 10, 10)
    machine = "m<b>" + payload
    queue.register_machine(machine, "sim://x?" + payload)
    queue.set_machine(machine, state=payload)
    job = queue.submit(payload, programs=[(payload, str(program), "", {"material": payload})])
    queue.claim_for_machine(machine)
    queue.submit("failed " + payload, job_file=payload, error=payload)
    queue.log(job, machine, payload)
    with page_server(db) as url, headless_chromium() as (sync_api, browser):
        page = browser.new_page()
        violations = []
        page.on("console", lambda message: violations.append(message.text))
        answer = page.goto(f"{url}/?token={TOKEN}")
        policy = answer.headers["content-security-policy"]
        assert "default-src 'self'" in policy and "frame-ancestors 'none'" in policy
        assert answer.headers["x-frame-options"] == "DENY"
        row = page.locator(f"#queue tr[data-job='{job}']")
        sync_api.expect(row).to_have_attribute("data-state", "ready", timeout=20000)
        sync_api.expect(row).to_contain_text(payload)  # the markup shows as text
        sync_api.expect(page.locator(".machine .load-card")).to_contain_text(payload)
        sync_api.expect(page.locator("#log")).to_contain_text(payload)
        assert page.evaluate("() => document.querySelectorAll('[onerror], [onload], iframe, svg').length"
                             " + document.scripts.length") == 1  # the page's own script, nothing of the payload
        # Were markup ever to reach the DOM as HTML (a future slip), the CSP keeps its handlers from running.
        page.evaluate("(html) => { const d = document.createElement('div'); d.innerHTML = html;"
                      " document.body.append(d); }", payload)
        page.wait_for_timeout(1500)
        assert page.evaluate("() => window.__pwned === undefined")
        assert any("Content Security Policy" in text for text in violations), violations
    listener.sock.close()
    assert listener.hits == []


def test_a_report_keeps_its_style_and_pictures_but_runs_no_script(tmp_path):
    pixel = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8BQDwAEhQGAhKmMIQAAAABJRU5ErkJggg=="
    report = tmp_path / "report.html"
    report.write_text("<html><head><style>h1 { color: rgb(255, 0, 0) }</style></head><body>"
                      f'<h1 style="font-size:40px">job</h1><img id=map src="data:image/png;base64,{pixel}">'
                      "<script>window.ran = 1</script></body></html>", encoding="utf-8")
    db = tmp_path / "runner.sqlite"
    queue = JobQueue(db)
    job = queue.submit("reported", job_file=str(tmp_path / "job.toml"))
    queue.claim_preparation()
    queue.prepared(job, [("s", str(square_program(tmp_path / "s.gcode", 1, 1)), "")], str(report))
    with page_server(db) as url, headless_chromium() as (sync_api, browser):
        page = browser.new_page()
        answer = page.goto(f"{url}/api/jobs/{job}/report?token={TOKEN}")
        assert answer.status == 200 and "frame-ancestors 'none'" in answer.headers["content-security-policy"]
        seen = page.evaluate("() => { const h = getComputedStyle(document.querySelector('h1'));"
                             " return [h.color, h.fontSize, document.getElementById('map').naturalWidth, window.ran]; }")
    assert seen == ["rgb(255, 0, 0)", "40px", 1, None]  # style and picture kept; the script never ran
