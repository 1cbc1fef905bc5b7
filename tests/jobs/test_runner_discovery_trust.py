"""Discovery trusts nothing it finds (issue 25 item 3): a `jobs/runner.server.json` planted in a cloned or shared
folder made `fabline runner status` read any file and send it as the token to any URL. A record is used only when
it is the user's, not writable by others, names a loopback URL, a live process of the user and the token file its
server writes beside it (owner-only, not a link); any other is reported in one line, its token file unread and
nothing sent to its URL. A listener stands for the planted URL and counts what reaches it."""

from __future__ import annotations

import builtins
import io
import json
import os
import socket
import threading
from pathlib import Path

import pytest

from fabline.jobs.discovery import SCHEMA, RemoteRunner, Search, find_runner, queue_lock, token_file
from fabline.locks import exclusive_lock

SECRET = "the user's private key\n"


class Listener:
    """A tiny HTTP server on `host`: records each request's bytes and answers `{}` (an empty runner state)."""

    def __init__(self, host: str):
        self.sock = socket.socket()
        self.sock.bind((host, 0))
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.requests: list[bytes] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(2)
                data = b""
                try:
                    while b"\r\n\r\n" not in data:
                        chunk = conn.recv(4096)
                        if not chunk:
                            break
                        data += chunk
                except OSError:
                    pass
                self.requests.append(data)
                conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Type: application/json\r\nContent-Length: 2\r\n\r\n{}")

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def shop(tmp_path, monkeypatch):
    """A cloned folder with jobs/ and a user state folder of its own; yields (jobs folder, listener on 127.0.0.2).
    This process holds the queue's lock as its server would, so a record naming it passes that check."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    monkeypatch.chdir(tmp_path)
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    listener = Listener("127.0.0.2")
    with exclusive_lock(queue_lock((jobs / "runner.sqlite").resolve()), "test queue"):
        yield jobs, listener
    listener.close()


def plant(jobs: Path, url: str, token: Path | str | None = None, pid: int | None = None, mode: int = 0o644) -> Path:
    db = (jobs / "runner.sqlite").resolve()
    record = jobs / "runner.server.json"
    record.write_text(json.dumps({"schema": SCHEMA, "url": url, "token_file": str(token or token_file(db)),
                                  "db": str(db), "pid": os.getpid() if pid is None else pid}))
    os.chmod(record, mode)
    return record


def write_token(path: Path, text: str = "good-token\n", mode: int = 0o600) -> Path:
    path.write_text(text)
    os.chmod(path, mode)
    return path


@pytest.fixture
def opened(monkeypatch):
    """Every path opened for reading while a command looks for the runner."""
    paths: list[str] = []
    real_os_open, real_open, real_io_open = os.open, builtins.open, io.open

    def os_open(path, *args, **kwargs):
        paths.append(os.fspath(path))
        return real_os_open(path, *args, **kwargs)

    def any_open(path, *args, **kwargs):
        if isinstance(path, (str, os.PathLike)):
            paths.append(os.fspath(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(builtins, "open", any_open)
    monkeypatch.setattr(io, "open", any_open)
    return paths


def test_a_stale_record_is_passed_over_in_silence(shop, tmp_path):
    """A server killed (kill -9) leaves its record; no process serves its queue: not a planted record, no line."""
    _, listener = shop
    jobs = tmp_path / "killed" / "jobs"
    jobs.mkdir(parents=True)
    write_token(jobs / "runner.token")
    dead = os.fork()
    if dead == 0:
        os._exit(0)
    os.waitpid(dead, 0)
    plant(jobs, f"http://127.0.0.2:{listener.port}", pid=dead)  # the server was killed: nothing to say
    said: list[str] = []
    with pytest.raises(Exception, match="no runner found"):
        find_runner(Search(jobs=str(jobs)), said.append)
    assert said == [] and listener.requests == []


def test_a_record_of_the_users_own_server_is_used(shop):
    """The control: the listener does hear a record that passes every check, with the token beside it."""
    jobs, listener = shop
    write_token(jobs / "runner.token")
    plant(jobs, f"http://127.0.0.2:{listener.port}")
    said: list[str] = []
    found = find_runner(Search(), said.append)
    assert isinstance(found, RemoteRunner) and found.token == "good-token" and said == []
    assert len(listener.requests) == 1 and b"X-Fabline-Token: good-token" in listener.requests[0]


@pytest.mark.parametrize("case", ["foreign url", "etc passwd", "another file", "world-writable record",
                                  "symlinked token", "token readable by others", "pid 1", "hard-linked token",
                                  "user part in url"])
def test_a_planted_record_is_reported_and_ignored_its_token_unread_nothing_sent(shop, tmp_path, opened, case, cli):
    jobs, listener = shop
    secret = write_token(tmp_path / "id_private", SECRET)
    url = f"http://127.0.0.2:{listener.port}"
    good_token = jobs / "runner.token"
    if case == "foreign url":
        other = Listener("127.0.0.1")  # 0.0.0.0 reaches this computer on Linux, yet it is no loopback address
        write_token(good_token)
        plant(jobs, f"http://0.0.0.0:{other.port}")
        listener = other
        why = "is not http:// on this computer"
    elif case == "etc passwd":
        plant(jobs, url, "/etc/passwd")
        why = "is not the one its server writes"
    elif case == "another file":
        plant(jobs, url, secret)
        why = "is not the one its server writes"
    elif case == "world-writable record":
        write_token(good_token)
        plant(jobs, url, mode=0o666)
        why = "writable by group or others"
    elif case == "symlinked token":
        good_token.symlink_to(secret)
        plant(jobs, url)
        why = "a symbolic link"
    elif case == "token readable by others":
        write_token(good_token, mode=0o644)
        plant(jobs, url)
        why = "not owner-only"
    elif case == "pid 1":
        write_token(good_token)
        plant(jobs, url, pid=1)  # always alive
        why = f"it names process 1, but the queue {(jobs / 'runner.sqlite').resolve()} is served by process {os.getpid()}"
    elif case == "hard-linked token":
        os.link(secret, good_token)
        plant(jobs, url)
        why = "2 hard links"
    else:
        write_token(good_token)
        plant(jobs, f"http://evil@127.0.0.2:{listener.port}")
        why = "is not http:// on this computer"
    opened.clear()
    code, out, err = cli("runner", "status")
    lines = err.splitlines()
    assert lines[0].startswith(f"fabline: ignored the runner record {(jobs / 'runner.server.json').resolve()}: ") and \
        why in lines[0], err
    assert listener.requests == [], "nothing may reach the URL a planted record names"
    assert str(secret) not in opened and "/etc/passwd" not in opened
    assert str(good_token) not in opened and str(good_token.resolve()) not in opened, opened
    if case == "foreign url":
        other.close()
