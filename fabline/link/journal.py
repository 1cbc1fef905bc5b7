"""The stream journal: an append-only, fsynced record of every line sent to and answered by the controller.

Format (`fabline.link-journal/1`): one JSON object per line, each with an `event`:
  start    {program, sha256, lines, mode, origin, identity, settings, build}
                                             a new job (or a resumed one) begins: origin = the controller's work
                                             position [x, y, z] where the run started (a resume keeps the first
                                             run's), identity = {name: text} given by the caller (job, run ids),
                                             settings = {"110": 500.0, ...} ($$) and build = its `$I` lines (a
                                             held controller refuses `$$`: a resume checks these before it lets
                                             the controller go on)
  forced   {problems}                        the run went on despite these controller conflicts (--force)
  paused   {line}                            the program paused (M0) at file line `line`, waiting for cycle start
  sent     {n, line}                         program line n (0-based; `line` = file line) was written to the port
  ok       {n, line}                         the controller accepted line n (parsed into its planner)
  error    {n, line, code}                   the controller rejected line n with error:code
  alarm    {code}                            the controller raised ALARM:code
  done     {count}                           the first `count` lines are known to be executed
  resume   {count}                           a resume restarts after the first `count` lines
  stopped  {reason}                          the stream stopped early (error, alarm, abort, lost
                                             connection, a log that could not be written)
  finished {}                                every line executed; the job is complete
Records are fsynced at least every 50 ms, and at once when the stream stops; the `sent` records of a batch are
flushed to the operating system before the batch is written to the port, so a killed host never leaves a line
on the controller that its journal does not show as sent (only a lost disk write can, and a resume then refuses). A journal that cannot be written
(disk full, device gone) raises JournalError at the next record, so the stream stops rather than cut unrecorded.
A half-written last record (the host died while writing it) is ignored when reading and cut off before
anything is appended; any other malformed record is a one-line error naming the journal line, and so is a record
after a `stopped` one other than a new start or a resume (records were lost between them).
Default location: beside the program, `<program>.journal`.
"""

from __future__ import annotations

import json
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path

from fabline.errors import FablineError
from fabline.fileio import open_append

JOURNAL_FORMAT = "fabline.link-journal/1"


def default_journal_path(program_path: str | os.PathLike) -> Path:
    """Where a program's journal lives unless told otherwise: `<program>.journal`."""
    return Path(f"{program_path}.journal")


@dataclass
class JournalState:
    """What a journal says about a job, replayed from its records."""

    sha256: str | None = None
    total: int = 0
    acked: int = 0
    sent: int = 0
    done: int = 0
    resumed_at: int | None = None
    finished: bool = False
    error: tuple[int, int | None] | None = None
    alarm: int | None = None
    stopped: str | None = None
    origin: tuple[float, float, float] | None = None
    identity: dict[str, str] | None = None
    settings: dict[int, float] | None = None
    build: list[str] | None = None


class JournalError(FablineError):
    """The journal cannot be written: records from here on would be lost, so no further line may be sent."""


class Journal:
    """Append-only job journal; `commit()` makes everything recorded so far durable (fsync).

    With `sync_interval` a background thread also commits that often, so a streaming loop never
    waits for the disk (an fsync can take longer than the controller's buffer lasts). A write that fails there
    is raised by the next `record()`; `abandon()` then lets the stream stop without recording anything more.
    """

    def __init__(self, path: str | os.PathLike, sync_interval: float | None = None):
        self.path = Path(path)
        self.sync_interval = sync_interval
        self._handle = None
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._syncer: threading.Thread | None = None
        self._failure: JournalError | None = None
        self._abandoned = False

    def open(self, fresh: bool = False) -> "Journal":
        """Open for appending (creating the file and its folder if needed), after cutting off a torn last record;
        `fresh` starts an empty journal instead (the caller holds the journal's lock)."""
        if fresh:
            self.path.unlink(missing_ok=True)
        else:
            _cut_torn_tail(self.path)
        self._handle = open_append(self.path, "journal", newline="\n")
        if self.sync_interval:
            self._closing.clear()
            self._syncer = threading.Thread(target=self._sync_periodically, name="journal-sync", daemon=True)
            self._syncer.start()
        return self

    def record(self, event: str, **fields) -> None:
        """Append one record (buffered until the next commit)."""
        if self._abandoned:
            return
        text = json.dumps({"event": event, **fields}, separators=(",", ":")) + "\n"
        with self._lock:
            self._raise_failure()
            self._guarded(self._handle.write, text)

    def flush(self) -> None:
        """Hand everything recorded so far to the operating system (no fsync): it survives the host process being
        killed, so a `sent` record flushed before its line is written to the port bounds what the controller can
        have received."""
        if self._abandoned:
            return
        with self._lock:
            self._raise_failure()
            self._guarded(self._handle.flush)

    def commit(self) -> None:
        """Flush and fsync: every record so far survives a crash."""
        if self._abandoned:
            return
        with self._lock:
            self._raise_failure()
            self._guarded(self._handle.flush)
        self._guarded(os.fsync, self._handle.fileno())

    @property
    def failed(self) -> bool:
        """Whether a write to the journal failed (its records from then on are lost)."""
        return self._failure is not None

    def abandon(self) -> None:
        """Give up on a journal that failed: later records and commits are dropped while the stream stops."""
        self._abandoned = True

    def _guarded(self, write, *args) -> None:
        try:
            write(*args)
        except OSError as exc:
            self._failure = JournalError(f"{self.path}: cannot write the journal: {exc.strerror or exc}")
            raise self._failure from None

    def _raise_failure(self) -> None:
        if self._failure is not None:
            raise self._failure

    def _sync_periodically(self) -> None:
        while not self._closing.wait(self.sync_interval):
            try:
                self.commit()
            except JournalError:
                return  # kept in _failure: the streaming loop's next record raises it

    def close(self) -> None:
        """Stop the background commits, commit and close (a failed journal is closed as far as it got)."""
        if self._handle is not None:
            self._closing.set()
            if self._syncer is not None:
                self._syncer.join()
                self._syncer = None
            try:
                if self._failure is None:
                    self.commit()
            finally:
                try:
                    self._handle.close()
                except OSError:
                    pass  # its buffer could not be written either: the failure was already raised
                self._handle = None

    def __enter__(self) -> "Journal":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()


def _cut_torn_tail(path: Path) -> None:
    """Truncate a journal after its last complete record, so a record appended next does not glue onto a torn one."""
    try:
        data = path.read_bytes()
        if data and not data.endswith(b"\n"):
            with open(path, "rb+") as handle:
                handle.truncate(data.rfind(b"\n") + 1)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise FablineError(f"{path}: cannot repair the journal's torn last record: {exc.strerror}") from None


_FIELDS = {
    "start": {"sha256": str, "lines": int},
    "sent": {"n": int}, "ok": {"n": int}, "error": {"n": int}, "alarm": {}, "done": {"count": int},
    "resume": {"count": int}, "stopped": {"reason": str}, "finished": {}, "forced": {}, "paused": {},
}


_AFTER_STOP = ("start", "resume", "stopped")
"""What may follow a `stopped` record: a new run, the same run's resume after a reconnect, or a second verdict."""


def _checked(record, path: Path, number: int) -> dict:
    """A record with the fields its event needs, of the right types; anything else is a one-line error."""
    if not isinstance(record, dict) or not isinstance(record.get("event"), str):
        raise FablineError(f"{path}:{number}: malformed journal record (no event)")
    needed = _FIELDS.get(record["event"])
    if needed is None:
        raise FablineError(f"{path}:{number}: unknown journal event {record['event']!r}")
    for name, kind in needed.items():
        value = record.get(name)
        if not isinstance(value, kind) or isinstance(value, bool) or (kind is int and value < 0):
            raise FablineError(f"{path}:{number}: journal record {record['event']!r} has no valid {name!r} "
                               f"(got {value!r}); the journal is damaged: start the sheet over with --restart, or "
                               "resume with --from-line")
    return record


def _origin(record: dict, path: Path, number: int) -> tuple[float, float, float] | None:
    value = record.get("origin")
    if value is None:
        return None
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise FablineError(f"{path}:{number}: journal start record has a malformed origin {value!r}")
    return tuple(float(v) for v in value)


def _identity(record: dict, path: Path, number: int) -> dict[str, str] | None:
    value = record.get("identity")
    if value is None:
        return None
    if not isinstance(value, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise FablineError(f"{path}:{number}: journal start record has a malformed identity {value!r}")
    return value


def _controller(record: dict, path: Path, number: int) -> tuple[dict[int, float] | None, list[str] | None]:
    """The controller's settings and `$I` lines a start record keeps (None where an older fabline kept none)."""
    settings, build = record.get("settings"), record.get("build")
    if settings is not None:
        if not isinstance(settings, dict) or not all(
                isinstance(k, str) and k.isdigit() and isinstance(v, (int, float)) and not isinstance(v, bool)
                for k, v in settings.items()):
            raise FablineError(f"{path}:{number}: journal start record has malformed settings {settings!r}")
        settings = {int(k): float(v) for k, v in settings.items()}
    if build is not None and (not isinstance(build, list) or not all(isinstance(text, str) for text in build)):
        raise FablineError(f"{path}:{number}: journal start record has a malformed build {build!r}")
    return settings, build


def read_journal(path: str | os.PathLike) -> JournalState:
    """Replay a journal into a JournalState; a malformed record other than a torn last one is an error."""
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii")
    except FileNotFoundError:
        raise FablineError(f"{path}: no journal to resume from (was the job ever started with this journal?)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FablineError(f"{path}: cannot read the journal ({exc}); start the sheet over with --restart") from None
    state, stopped_at = JournalState(), None
    rows = text.split("\n")
    for number, row in enumerate(rows, 1):
        if not row:
            continue
        try:
            record = json.loads(row)
        except (json.JSONDecodeError, RecursionError):
            if number == len(rows):
                break  # torn by a crash while it was written
            raise FablineError(f"{path}:{number}: malformed journal record; the journal is damaged: start the sheet "
                               "over with --restart, or resume with --from-line") from None
        event = _checked(record, path, number)["event"]
        if stopped_at is not None and event not in _AFTER_STOP:
            raise FablineError(f"{path}:{number}: journal record {event!r} follows the stop recorded at line "
                               f"{stopped_at} with no new start: the journal lost records, so it cannot tell how far "
                               f"the controller got (it knew {state.done} lines executed there); check the part and "
                               "continue by hand with --resume --from-line N, N the first line not yet cut")
        stopped_at = number if event == "stopped" else None if event in ("start", "resume") else stopped_at
        if event == "start":
            if state.sha256 not in (None, record["sha256"]):
                raise FablineError(f"{path}:{number}: journal mixes two different programs")
            state.sha256, state.total = record["sha256"], record["lines"]
            state.origin, state.identity = _origin(record, path, number), _identity(record, path, number)
            state.settings, state.build = _controller(record, path, number)
            state.finished, state.stopped, state.error, state.alarm = False, None, None, None
            state.sent = state.acked = state.done = 0  # a run starts from nothing; a resume record says otherwise
            state.resumed_at = None
        elif event == "sent":
            state.sent = max(state.sent, record["n"] + 1)
        elif event == "ok":
            state.acked = max(state.acked, record["n"] + 1)
        elif event == "error":
            state.error = (record["n"], record.get("code") if isinstance(record.get("code"), int) else None)
        elif event == "alarm":
            state.alarm = record.get("code") if isinstance(record.get("code"), int) else None
        elif event == "done":
            state.done = max(state.done, record["count"])
        elif event == "resume":
            state.resumed_at = record["count"]
            state.done = state.acked = state.sent = record["count"]
        elif event == "stopped":
            state.stopped = record["reason"]
        elif event == "finished":
            state.finished = True
    if state.sha256 is None:
        raise FablineError(f"{path}: journal has no start record (damaged, or its run never began); start the sheet "
                           "over with --restart")
    return state
