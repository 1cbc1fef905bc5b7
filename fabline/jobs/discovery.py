"""How `fabline runner status`, `pause`, `resume`, ... find the runner wherever they are run from.

`fabline runner serve` writes a discovery record (`fabline.runner/1`: the page's URL, the token file, the queue
database, the server's pid) beside its database (`runner.server.json`, the token in `runner.token`, readable by
the user only) and in the user's state folder (`$XDG_STATE_HOME/fabline/runner.json`, by default
`~/.local/state/fabline/`); when it stops it removes the token and the record beside the database (the user's
record stays, naming a process that is gone, so commands still find that queue). A command talks to the server the record names over
HTTP with its token while that server runs; else it opens the queue database it finds (`--db`, the `--jobs`
folder's, `./jobs/runner.sqlite`, or the one the user's record names); else one line says where it looked.

A record is a file anyone can plant (a cloned or shared folder), so a command trusts nothing it finds: a record is
used only if it is the user's own regular file, not writable by group or others, names a loopback URL and a live
process of the user, and names as token the file the server writes (`<db>.token` beside the database, and beside
the record for a record beside a database), itself the user's, owner-only, not a link. A record failing any of
this is reported in one line and ignored: its token file is not read and nothing is sent to its URL.
"""

from __future__ import annotations

import ipaddress
import json
import os
import stat
import sys
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from fabline.errors import FablineError
from fabline.fileio import atomic_output, process_alive, write_json
from fabline.locks import lock_holder

SCHEMA = "fabline.runner/1"
DB_NAME = "runner.sqlite"
TOKEN_HEADER = "X-Fabline-Token"
RECORD_LIMIT = 64 * 1024
"""Bytes a record or a token file may have (the server writes a few hundred)."""
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
        os.chmod(path, 0o644)  # whatever the umask: a command trusts no record that others could have written
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
    """A record's fields if it is a well-formed `fabline.runner/1` record, else None (read as it is: the server
    withdrawing its own record, which `remove_records` does, needs no trust)."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return _fields(record)


def _fields(record: Any) -> dict[str, Any] | None:
    fields = {"url": str, "token_file": str, "db": str, "pid": int}
    if not isinstance(record, dict) or record.get("schema") != SCHEMA or \
            not all(isinstance(record.get(k), kind) for k, kind in fields.items()):
        return None
    return record


class Untrusted(Exception):
    """Why a discovery record (or its token file) is not used."""


def _own_file(info: os.stat_result, what: str, private: bool) -> None:
    """Refuse a file (its status) that is not a regular file of this user, writable by group or others, or
    (`private`) readable by them or with other hard links (a link to a file elsewhere)."""
    if stat.S_ISLNK(info.st_mode):
        raise Untrusted(f"its {what} is a symbolic link")
    if not stat.S_ISREG(info.st_mode):
        raise Untrusted(f"its {what} is not a regular file")
    if info.st_uid != os.getuid():
        raise Untrusted(f"its {what} belongs to another user (uid {info.st_uid})")
    if info.st_mode & (0o077 if private else 0o022):
        raise Untrusted(f"its {what} has mode {stat.S_IMODE(info.st_mode):04o}, "
                        f"{'not owner-only (0600)' if private else 'writable by group or others'}")
    if private and info.st_nlink != 1:
        raise Untrusted(f"its {what} has {info.st_nlink} hard links")
    if info.st_size > RECORD_LIMIT:
        raise Untrusted(f"its {what} is {info.st_size} bytes long")


def _read_own(path: Path, what: str, private: bool = False) -> str:
    """The text of a file checked by `_own_file` before it is opened (without following a symbolic link) and
    again once open (it cannot have been swapped in between)."""
    try:
        _own_file(os.lstat(path), what, private)
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as exc:
        raise Untrusted(f"its {what} cannot be opened ({exc.strerror})") from None
    with os.fdopen(fd, "rb") as handle:
        _own_file(os.fstat(fd), what, private)
        try:
            return handle.read(RECORD_LIMIT + 1).decode("utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise Untrusted(f"its {what} cannot be read: {exc}") from None


def _loopback(url: str) -> bool:
    """Whether `url` is http:// to this computer only (127.0.0.0/8, ::1, localhost), with no user part."""
    try:
        parts = urllib.parse.urlsplit(url)
        parts.port  # noqa: B018 - raises on a bad port
    except ValueError:
        return False
    if parts.scheme != "http" or parts.username is not None or parts.hostname is None:
        return False
    if parts.hostname == "localhost":
        return True
    try:
        return ipaddress.ip_address(parts.hostname).is_loopback
    except ValueError:
        return False


def _users_process(pid: int) -> bool:
    """Whether `pid` is a process of this user (where /proc tells; elsewhere, any live process)."""
    try:
        return os.stat(f"/proc/{pid}").st_uid == os.getuid()
    except FileNotFoundError:
        return not os.path.isdir("/proc") and process_alive(pid)
    except OSError:
        return False


def queue_lock(db: Path) -> Path:
    """The lock `fabline runner serve` holds on its queue while it runs (one runner per queue)."""
    return Path(f"{db}.lock")


def trusted_record(path: Path) -> tuple[dict[str, Any], str] | None:
    """The record at `path` and its server's token, if the record may be used (see the module); None if there is
    no record or its server is gone; Untrusted (saying why) if it must not be used."""
    if not os.path.lexists(path):
        return None
    record = _fields(_json(_read_own(path, "record file")))
    if record is None:
        raise Untrusted(f"not a {SCHEMA} record")
    if not _loopback(record["url"]):
        raise Untrusted(f"its URL {record['url']!r} is not http:// on this computer (127.0.0.1, ::1, localhost)")
    db = Path(record["db"])
    if not db.is_absolute() or Path(record["token_file"]) != token_file(db):
        raise Untrusted(f"its token file {record['token_file']!r} is not the one its server writes beside "
                        f"its database ({token_file(db) if db.is_absolute() else 'a relative database path'})")
    if path.resolve() != user_record().resolve() and os.path.realpath(db.parent) != os.path.realpath(path.parent):
        raise Untrusted(f"its database {db} is not beside it")
    serving = lock_holder(queue_lock(db))
    if serving is None:
        if process_alive(record["pid"]):
            raise Untrusted(f"it names process {record['pid']}, which does not serve the queue {db}")
        return None  # its server is gone (killed): the queue it left is found below
    if serving != record["pid"] or not _users_process(serving):
        raise Untrusted(f"it names process {record['pid']}, but the queue {db} is served by process {serving}"
                        if serving != record["pid"] else f"its server, process {serving}, is not one of yours")
    return record, _read_own(token_file(db), "token file", private=True).strip()


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return None


def _say(line: str) -> None:
    print(f"fabline: {line}", file=sys.stderr)


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


def find_runner(search: Search, say: Callable[[str], None] = _say) -> LocalRunner | RemoteRunner:
    """The running server the records name (answering with its token), else the queue database found; else a
    FablineError saying where it looked. A record that may not be used is reported through `say`, one line."""
    databases = search.databases()
    untrusted: set[Path] = set()
    for path in dict.fromkeys(search.records()):
        try:
            found = trusted_record(path)
        except Untrusted as why:
            say(f"ignored the runner record {path}: {why}")
            untrusted.add(path)
            continue
        if found is None:
            continue
        record, token = found
        remote = RemoteRunner(record["url"], token, Path(record["db"]))
        if remote.answers():
            return remote
    if not (search.db or search.jobs) and user_record() not in untrusted:
        try:  # its database is opened only if the record is the user's own
            record = _fields(_json(_read_own(user_record(), "record file")))
        except Untrusted:
            record = None
        if record is not None:
            databases.append(Path(record["db"]))  # the user's last runner, stopped: its queue is still there
    for db in databases:
        if db.is_file():
            return LocalRunner(db)
    looked = ", ".join(dict.fromkeys(str(p) for p in (*search.records(), *databases)))
    raise FablineError(f"no runner found (looked for a running server's record or a queue database at {looked}); "
                       "start one with `fabline runner serve`, or name its queue with --db or its folder with --jobs")
