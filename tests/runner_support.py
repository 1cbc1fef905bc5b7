"""Support for the jobs and runner tests (no tests here): small G-code sheet programs, executed-line logs, the CLI."""

from __future__ import annotations

import os
import shutil
import socket
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

from fabline.machine import load_program

JOBS_CLI = [sys.executable, "-c", (
    "import argparse, sys\n"
    "from fabline.cli import jobs\n"
    "parser = argparse.ArgumentParser(prog='fabline')\n"
    "jobs.register(parser.add_subparsers(dest='command', required=True))\n"
    "args = parser.parse_args()\n"
    "sys.exit(args.func(args))\n")]
"""`fabline` with only the jobs stage's subcommands, the same handlers: a restarted runner need not wait for
every other stage's imports (scipy and friends), which would dominate a test that restarts it 21 times."""


CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TOKEN = "s3cret-token"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def page_server(db: Path):
    """The runner's web page over the queue at `db`, served on 127.0.0.1 with TOKEN; yields its URL."""
    import uvicorn

    from fabline.jobs.web import create_app

    server = uvicorn.Server(uvicorn.Config(create_app(db, TOKEN, poll=0.1), host="127.0.0.1", port=free_port(),
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started
    try:
        yield f"http://127.0.0.1:{server.config.port}"
    finally:
        server.should_exit = True
        thread.join(10)


@contextmanager
def headless_chromium():
    """Playwright's sync API (the test extra) and Debian's Chromium, headless. Without Chromium the test is skipped
    on a developer's machine, saying how to install it, and fails under CI (CI=true), which installs it."""
    if not os.path.exists(CHROMIUM):
        missing = f"{CHROMIUM} is missing: the browser tests need Debian's Chromium (apt-get install -y chromium)"
        if os.environ.get("CI"):
            pytest.fail(missing)
        pytest.skip(missing)
    from playwright import sync_api
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=shutil.which(CHROMIUM) or CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield sync_api, browser
        finally:
            browser.close()


def square_program(path: Path, x: float, y: float, squares: int = 1, size: float = 5.0, closed: bool = True) -> Path:
    """A laser program cutting `squares` squares in a row starting at (x, y); coordinates make it unique. With
    `closed=False` each square lacks its last side, so the path never passes a point twice and a feed hold
    anywhere tells which line the machine was in."""
    lines = ["G21 G90 G17 G94", "M5"]
    for k in range(squares):
        x0 = x + k * (size + 2)
        lines += [f"G0 X{x0:.3f} Y{y:.3f}", "M4 S1000", f"G1 X{x0 + size:.3f} Y{y:.3f} F3000",
                  f"G1 X{x0 + size:.3f} Y{y + size:.3f}", f"G1 X{x0:.3f} Y{y + size:.3f}"] + ([f"G1 X{x0:.3f} Y{y:.3f}"] if closed else []) + ["M5"]
    lines += ["G0 X0 Y0", "M2"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


def wire_lines(path: Path) -> list[str]:
    """The program's lines exactly as the controller receives (and the simulator logs) them."""
    return [line.wire.decode("ascii").strip() for line in load_program(path).lines]


def executed_program_lines(log: Path) -> list[str]:
    """The simulator's executed-line log without a resume's modal preamble (lines without an N word)."""
    if not log.exists():
        return []
    return [text for text in log.read_text(encoding="ascii").splitlines() if text.startswith("N")]
