"""How `fabline runner status`, `pause`, `resume`, ... find the runner wherever they are run from.

`fabline runner serve` writes a discovery record (`fabline.runner/1`: the page's URL, the token file, the queue
database, the server's pid) beside its database (`runner.server.json`, the token in `runner.token`, readable by
the user only) and in the user's state folder (`$XDG_STATE_HOME/fabline/runner.json`, by default
`~/.local/state/fabline/`); when it stops it removes the token and the record beside the database (the user's
record stays, naming a process that is gone, so commands still find that queue). A command talks to the server the record names over
HTTP with its token while that server runs; else it opens the queue database it finds (`--db`, the `--jobs`
folder's, `./jobs/runner.sqlite`, or the one the user's record names); else one line says where it looked.
"""

from __future__ import annotations

import json
import os
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fabline.errors import FablineError
from fabline.fileio import _alive, atomic_output, write_json  # _alive: the temp-file sweep's process check

SCHEMA = "fabline.runner/1"
DB_NAME = "runner.sqlite"
TOKEN_HEADER = "X-Fabline-Token"
ANSWER_TIMEOUT = 5.0
"""Seconds a command waits for the server's answer before it says the server does not answer."""


def user_record() -> Path:
    """The user's discovery record: the last runner started by this user, wherever its database is."""
    state = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(state) / "fabline" / "runner.json"


def record_beside(db: Path) -> Path:
    """The discovery record beside a queue database."""
    return db.with_name(f"{db.stem}.server.json")


def token_file(db: Path) -> Path:
    """The file holding the server's token, beside its database (owner-only)."""
    return db.with_name(f"{db.stem}.token")


def page_url(host: str, port: int) -> str:
    """The URL a command on this computer reaches the page at (a server on every address answers on loopback)."""
    host = "127.0.0.1" if host in ("", "0.0.0.0") else "[::1]" if host == "::" else host
    return f"http://{f'[{host}]' if ':' in host and not host.startswith('[') else host}:{port}"


def write_records(db: Path, url: str, token: str) -> list[Path]:
    """Publish a starting server: its token (owner-only) and its record beside the database and in the user's
    state folder; returns the records written."""
    db = db.resolve()
    with atomic_output(token_file(db)) as handle:
        os.chmod(handle.fileno(), 0o600)
        handle.write(token + "\n")
    record = {"schema": SCHEMA, "url": url, "token_file": str(token_file(db)), "db": str(db), "pid": os.getpid()}
    written = []
    for path in (record_beside(db), user_record()):
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        write_json(path, record)
        written.append(path)
    return written


def remove_records(db: Path) -> None:
    """A stopping server withdraws the record beside its database and its token file; the user's record stays,
    naming a pid that is gone, so commands still find the queue it left."""
    db = db.resolve()
    record = _read_record(record_beside(db))
    if record is not None and record["pid"] == os.getpid():
        record_beside(db).unlink(missing_ok=True)
    token_file(db).unlink(missing_ok=True)


def _read_record(path: Path) -> dict[str, Any] | None:
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    fields = {"url": str, "token_file": str, "db": str, "pid": int}
    if not isinstance(record, dict) or record.get("schema") != SCHEMA or \
            not all(isinstance(record.get(k), kind) for k, kind in fields.items()):
        return None
    return record


class LocalRunner:
    """The queue database opened directly (no server running): what a command reads and asks goes to it."""

    def __init__(self, db: Path):
        from fabline.jobs.queue import JobQueue

        self.db, self.where = db, f"queue {db} (no runner server running)"
        self.queue = JobQueue(db)

    def state(self) -> dict[str, Any]:
        return self.queue.snapshot()

    def act(self, job_id: int, action: str, from_line: int | None = None) -> dict[str, Any]:
        return self.queue.act(job_id, action, from_line)


class RemoteRunner:
    """A running server, over its HTTP API with its token: what a command reads and asks goes to it."""

    def __init__(self, url: str, token: str, db: Path):
        self.url, self.token, self.db = url, token, db
        self.where = f"runner {url} (queue {db})"

    def _call(self, method: str, path: str, body: dict | None = None) -> dict[str, Any]:
        data = json.dumps(body).encode() if body is not None else b""
        request = urllib.request.Request(f"{self.url}{path}", data=data if method == "POST" else None, method=method,
                                         headers={TOKEN_HEADER: self.token, "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=ANSWER_TIMEOUT) as answer:
                return json.loads(answer.read())
        except urllib.error.HTTPError as exc:
            try:
                message = json.loads(exc.read()).get("error", exc.reason)
            except (ValueError, AttributeError):
                message = exc.reason
            raise FablineError(str(message)) from None
        except (urllib.error.URLError, OSError, ValueError) as exc:
            raise FablineError(f"runner {self.url} does not answer: {getattr(exc, 'reason', exc)}") from None

    def state(self) -> dict[str, Any]:
        return self._call("GET", "/api/state")

    def act(self, job_id: int, action: str, from_line: int | None = None) -> dict[str, Any]:
        return self._call("POST", f"/api/jobs/{job_id}/{action}", {"from_line": from_line} if from_line else None)

    def answers(self) -> bool:
        """Whether the server answers with this token now."""
        try:
            self.state()
        except FablineError:
            return False
        return True


@dataclass
class Search:
    """Where to look: the database named (`--db`), the jobs folder named (`--jobs`), or neither."""

    db: str | None = None
    jobs: str | None = None

    def databases(self) -> list[Path]:
        if self.db:
            return [Path(self.db)]
        return [Path(self.jobs or "jobs") / DB_NAME]

    def records(self) -> list[Path]:
        beside = [record_beside(db.resolve()) for db in self.databases()]
        return beside if self.db or self.jobs else [*beside, user_record()]


def find_runner(search: Search) -> LocalRunner | RemoteRunner:
    """The running server the records name (answering with its token), else the queue database found; else a
    FablineError saying where it looked."""
    databases = search.databases()
    for path in search.records():
        record = _read_record(path)
        if record is None or not _alive(record["pid"]):
            continue
        try:
            token = Path(record["token_file"]).read_text(encoding="utf-8").strip()
        except OSError:
            continue
        remote = RemoteRunner(record["url"], token, Path(record["db"]))
        if remote.answers():
            return remote
    if not (search.db or search.jobs):
        record = _read_record(user_record())
        if record is not None:
            databases.append(Path(record["db"]))  # the user's last runner, stopped: its queue is still there
    for db in databases:
        if db.is_file():
            return LocalRunner(db)
    looked = ", ".join(dict.fromkeys(str(p) for p in (*search.records(), *databases)))
    raise FablineError(f"no runner found (looked for a running server's record or a queue database at {looked}); "
                       "start one with `fabline runner serve`, or name its queue with --db or its folder with --jobs")
