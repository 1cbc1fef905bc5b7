"""The runner's job queue in SQLite (WAL mode): jobs, their sheets, machines and operator requests, crash-safe.

States of a job:
  queued -> preparing -> ready -> cutting -> ready -> ... -> cutting -> done
  ready means "the next sheet is prepared and waits for a machine and for the operator to confirm it is
  loaded"; cutting is "sheet k of n" on one machine. Any live state may go to paused (and back to the state
  it left) or to cancelled; preparing or cutting may go to failed. done, failed and cancelled are final.
  attention: a sheet's cutting stopped without finishing (the runner restarted, the link failed); the job
  waits until the operator chooses: resume the sheet where it stopped, restart it, skip it, or cancel.
  Cutting never continues by itself: nobody else knows whether the sheet, the machine and its origin are
  still as they were.
Every stream of a sheet is one run with an id of its own and its own journal (sheets.run_id, sheets.journal):
a journal of another job, run or program never decides where a new run starts.
Every change is one short IMMEDIATE transaction, so several runner threads (or processes) never claim the
same job or sheet twice, and a runner killed at any moment leaves the database consistent.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from fabline.errors import FablineError
from fabline.fileio import check_outputs

FINAL_STATES = frozenset({"failed", "cancelled", "done"})
TRANSITIONS: dict[str, frozenset[str]] = {
    "queued": frozenset({"preparing", "paused", "cancelled", "failed"}),
    "preparing": frozenset({"queued", "ready", "failed", "paused", "cancelled"}),
    "ready": frozenset({"cutting", "paused", "cancelled", "failed"}),
    "cutting": frozenset({"ready", "done", "failed", "paused", "cancelled", "attention"}),
    "paused": frozenset({"queued", "ready", "cutting", "cancelled", "failed", "attention"}),
    "attention": frozenset({"cutting", "ready", "done", "cancelled"}),
    "failed": frozenset(), "cancelled": frozenset(), "done": frozenset(),
}
REQUESTS = ("pause", "resume", "cancel", "frame")
CHOICES = ("resume", "restart", "skip", "cancel")
"""What the operator may do with a job that needs attention: resume the sheet where it stopped (optionally
from a given file line), restart the sheet from its first line, skip the sheet, or cancel the job."""

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    job_file TEXT,
    state TEXT NOT NULL,
    paused_from TEXT,
    machine TEXT,
    sheet INTEGER NOT NULL DEFAULT 0,
    sheets INTEGER NOT NULL DEFAULT 0,
    confirmed INTEGER NOT NULL DEFAULT -1,
    request TEXT,
    error TEXT,
    report TEXT,
    attention TEXT,
    output TEXT,
    stopped TEXT,
    created REAL NOT NULL,
    updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS sheets (
    job_id INTEGER NOT NULL REFERENCES jobs(id),
    k INTEGER NOT NULL,
    name TEXT NOT NULL,
    program TEXT NOT NULL,
    svg TEXT NOT NULL DEFAULT '',
    facts TEXT NOT NULL DEFAULT '{}',
    lines INTEGER NOT NULL DEFAULT 0,
    done_lines INTEGER NOT NULL DEFAULT 0,
    machine TEXT,
    started REAL,
    finished REAL,
    run_id TEXT,
    journal TEXT,
    resume INTEGER NOT NULL DEFAULT 0,
    from_line INTEGER,
    skipped INTEGER NOT NULL DEFAULT 0,
    waited REAL NOT NULL DEFAULT 0,
    waiting_since REAL,
    PRIMARY KEY (job_id, k)
);
CREATE TABLE IF NOT EXISTS machines (
    name TEXT PRIMARY KEY,
    port TEXT NOT NULL,
    state TEXT NOT NULL DEFAULT 'idle',
    job_id INTEGER,
    position TEXT NOT NULL DEFAULT '[0, 0, 0]',
    updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS commands (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    machine TEXT NOT NULL,
    line TEXT,
    override TEXT,
    state TEXT NOT NULL DEFAULT 'pending',
    answer TEXT,
    created REAL NOT NULL,
    updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time REAL NOT NULL,
    job_id INTEGER,
    machine TEXT,
    message TEXT NOT NULL
);
"""


@dataclass(frozen=True)
class SheetRow:
    """One sheet of a job: its program file, an SVG picture of it, what the operator loads (`facts`: size,
    material, thickness, part count; {} for programs submitted alone) and how far it has been cut."""

    job_id: int
    k: int
    name: str
    program: str
    svg: str
    lines: int
    done_lines: int
    machine: str | None
    started: float | None
    finished: float | None
    run_id: str | None = None
    journal: str | None = None
    resume: int = 0
    from_line: int | None = None
    skipped: int = 0
    facts: str = "{}"
    waited: float = 0.0
    """Seconds the sheet, under way, stood waiting (paused, needs attention): not work, so no ETA counts it."""
    waiting_since: float | None = None

    def waiting(self, now: float) -> float:
        """Seconds this sheet has stood waiting by `now` (a wait in progress included)."""
        return self.waited + (now - self.waiting_since if self.waiting_since is not None else 0.0)

    def load_facts(self) -> dict[str, Any]:
        """The sheet's facts for the load prompt (JSON in the database)."""
        return json.loads(self.facts or "{}")


def describe_load(name: str, k: int, count: int, facts: dict[str, Any]) -> str:
    """The load prompt's line: which sheet, its size, material, thickness and parts (what is known of them)."""
    said = [f"{facts['width_mm']:g} x {facts['height_mm']:g} mm"] if "width_mm" in facts else []
    if facts.get("material"):
        said.append(facts["material"] + (f" {facts['thickness_mm']:g} mm thick" if facts.get("thickness_mm") else ""))
    if "parts" in facts:
        said.append(f"{facts['parts']} parts")
    return f"sheet {k + 1} of {count}: {name}" + (f" ({', '.join(said)})" if said else "")


@dataclass(frozen=True)
class JobRow:
    """One job as stored: state, the machine it runs on, the sheet being cut and the one confirmed loaded."""

    id: int
    name: str
    job_file: str | None
    state: str
    paused_from: str | None
    machine: str | None
    sheet: int
    sheets: int
    confirmed: int
    request: str | None
    error: str | None
    report: str | None
    created: float
    updated: float
    attention: str | None = None
    output: str | None = None
    stopped: str | None = None

    def describe(self) -> str:
        """The state as an operator reads it: 'cutting sheet 2 of 3', 'ready: load sheet 1 of 3'."""
        if self.state == "attention":
            detail = self.checkpoint()
            return (f"needs attention: sheet {self.sheet + 1} of {self.sheets} stopped after file line "
                    f"{detail.get('file_line') or 'none'}: {detail.get('reason', 'interrupted')}")
        if self.state == "cutting":
            return f"cutting sheet {self.sheet + 1} of {self.sheets}"
        if self.state == "ready":
            waiting = "confirmed, waiting for a machine" if self.confirmed >= self.sheet else "load and confirm"
            return f"ready: sheet {self.sheet + 1} of {self.sheets} ({waiting})"
        if self.state == "failed" and self.error:
            return f"failed: {self.error}"
        return self.state

    def checkpoint(self) -> dict[str, Any]:
        """Why a job needs attention and where its sheet stopped: reason, done (lines known executed), lines,
        file_line (the last one known executed) and position (the machine's last reported work position)."""
        return json.loads(self.attention) if self.attention else {}


class JobQueue:
    """The SQLite queue; one connection per thread (open one JobQueue per thread or process)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        check_outputs(files=(self.path,))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
        except sqlite3.OperationalError as exc:
            raise FablineError(f"{self.path}: cannot open the runner database: {exc}") from None
        self._db.row_factory = sqlite3.Row
        try:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.executescript(_SCHEMA)
            self._add_new_columns()
        except sqlite3.DatabaseError as exc:
            raise FablineError(f"{self.path}: not a runner database: {exc}") from None
        self.journals = self.path.parent / "journals"

    def _add_new_columns(self) -> None:
        """A queue made by an older fabline gets the columns added since (with their defaults)."""
        for table in ("jobs", "sheets"):
            have = {row[1] for row in self._db.execute(f"PRAGMA table_info({table})")}
            create = _SCHEMA.split(f"CREATE TABLE IF NOT EXISTS {table} (", 1)[1].split(");", 1)[0]
            for line in create.strip().splitlines():
                name = line.split()[0]
                if name not in have and name != "PRIMARY":
                    self._db.execute(f"ALTER TABLE {table} ADD COLUMN {line.strip().rstrip(',')}")

    def close(self) -> None:
        """Close the connection."""
        self._db.close()

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """One IMMEDIATE transaction: the write lock is taken up front, so read-then-update is atomic."""
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield self._db
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    # --- jobs -------------------------------------------------------------------------------------------

    def submit(self, name: str, job_file: str | None = None, programs: list[tuple] | None = None,
               error: str | None = None) -> int:
        """Queue a job file (state queued, prepared by the runner) or ready programs [(sheet name, path, svg[,
        load facts])];
        with `error`, record a job file that cannot run as failed, so the operator sees why."""
        now = time.time()
        with self.transaction() as db:
            state = "failed" if error else "queued" if programs is None else "ready"
            cursor = db.execute("INSERT INTO jobs (name, job_file, state, error, created, updated) "
                                "VALUES (?, ?, ?, ?, ?, ?)", (name, job_file, state, error, now, now))
            job_id = int(cursor.lastrowid)
            if programs is not None:
                self._add_sheets(db, job_id, programs)
            self._event(db, job_id, None, f"job {job_id} {name} submitted ({state}{': ' + error if error else ''})")
        return job_id

    def submit_once(self, name: str, job_file: str, error: str | None = None) -> tuple[int, bool]:
        """Queue a job file unless a job of that file is queued already (in one transaction, so the folder watcher
        and an upload never queue a file twice); (the job's id, whether it is new)."""
        with self.transaction() as db:
            row = db.execute("SELECT id FROM jobs WHERE job_file = ? ORDER BY id DESC LIMIT 1", (job_file,)).fetchone()
            if row is not None:
                return int(row["id"]), False
            now = time.time()
            state = "failed" if error else "queued"
            cursor = db.execute("INSERT INTO jobs (name, job_file, state, error, created, updated) "
                                "VALUES (?, ?, ?, ?, ?, ?)", (name, job_file, state, error, now, now))
            job_id = int(cursor.lastrowid)
            self._event(db, job_id, None, f"job {job_id} {name} submitted ({state}{': ' + error if error else ''})")
        return job_id, True

    def _add_sheets(self, db: sqlite3.Connection, job_id: int, programs: list[tuple],
                    lines: list[int] | None = None) -> None:
        if not programs:
            raise FablineError(f"job {job_id}: no sheets to cut")
        for k, (name, program, svg, *facts) in enumerate(programs):
            db.execute("INSERT INTO sheets (job_id, k, name, program, svg, facts, lines) VALUES (?, ?, ?, ?, ?, ?, ?)",
                       (job_id, k, name, str(program), svg, json.dumps(facts[0] if facts else {}),
                        lines[k] if lines is not None else _count_lines(program)))
        db.execute("UPDATE jobs SET sheets = ? WHERE id = ?", (len(programs), job_id))

    def job(self, job_id: int) -> JobRow:
        """One job; an unknown id is a FablineError."""
        row = self._db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            raise FablineError(f"job {job_id}: no such job")
        return JobRow(**dict(row))

    def jobs(self) -> list[JobRow]:
        """Every job, oldest first."""
        return [JobRow(**dict(r)) for r in self._db.execute("SELECT * FROM jobs ORDER BY id")]

    def job_files(self) -> set[str]:
        """The job files already in the queue (any state)."""
        return {r[0] for r in self._db.execute("SELECT job_file FROM jobs WHERE job_file IS NOT NULL")}

    def sheets(self, job_id: int) -> list[SheetRow]:
        """The sheets of a job in cutting order."""
        return [SheetRow(**{k: r[k] for k in SheetRow.__dataclass_fields__})
                for r in self._db.execute("SELECT * FROM sheets WHERE job_id = ? ORDER BY k", (job_id,))]

    def _move(self, db: sqlite3.Connection, job: JobRow, state: str, **fields: Any) -> None:
        """Change a job's state (checked against TRANSITIONS) and any other columns, in the open transaction."""
        if state != job.state and state not in TRANSITIONS[job.state]:
            raise FablineError(f"job {job.id}: cannot go from {job.state} to {state}")
        fields = {"state": state, "updated": time.time(), **fields}
        db.execute(f"UPDATE jobs SET {', '.join(f'{k} = ?' for k in fields)} WHERE id = ?", (*fields.values(), job.id))
        if state in ("paused", "attention"):  # a sheet under way starts waiting for the operator
            db.execute("UPDATE sheets SET waiting_since = ? WHERE job_id = ? AND k = ? AND started IS NOT NULL "
                       "AND finished IS NULL AND waiting_since IS NULL", (fields["updated"], job.id, job.sheet))
        else:  # ... and stops waiting when the job moves on (the wait is kept apart from the work)
            db.execute("UPDATE sheets SET waited = waited + (? - waiting_since), waiting_since = NULL "
                       "WHERE job_id = ? AND waiting_since IS NOT NULL", (fields["updated"], job.id))

    def _locked_job(self, db: sqlite3.Connection, job_id: int) -> JobRow:
        row = db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            raise FablineError(f"job {job_id}: no such job")
        return JobRow(**dict(row))

    # --- preparation ------------------------------------------------------------------------------------

    def claim_preparation(self) -> JobRow | None:
        """Take the oldest queued job into preparing, or None."""
        with self.transaction() as db:
            row = db.execute("SELECT * FROM jobs WHERE state = 'queued' ORDER BY id LIMIT 1").fetchone()
            if row is None:
                return None
            job = JobRow(**dict(row))
            self._move(db, job, "preparing")
        return self.job(job.id)

    def prepared(self, job_id: int, programs: list[tuple], report: str | None,
                 output: str | None = None, lines: list[int] | None = None) -> None:
        """A job's sheet programs are made (in its output folder): preparing -> ready (unless it was paused or
        cancelled meanwhile). `lines`: the programs' command lines when known (reused sheets), else counted."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state != "preparing" and not (job.state == "paused" and job.paused_from == "preparing"):
                return  # cancelled, failed, or given back to the queue by a stopping runner: nothing is recorded
            self._add_sheets(db, job_id, programs, lines)
            if job.state == "paused":
                db.execute("UPDATE jobs SET paused_from = 'ready', report = ?, output = ? WHERE id = ?",
                           (report, output, job_id))
            else:
                self._move(db, job, "ready", report=report, output=output)
            self._event(db, job_id, None, f"job {job_id} prepared: {len(programs)} sheet(s)")

    def give_back_preparation(self) -> list[int]:
        """A stopping runner's unfinished preparations go back to the queue, all at once (preparation is repeatable:
        the next start prepares them afresh); returns their ids."""
        with self.transaction() as db:
            rows = db.execute("SELECT id FROM jobs WHERE state = 'preparing' OR (state = 'paused' AND "
                              "paused_from = 'preparing') ORDER BY id").fetchall()
            db.execute("UPDATE jobs SET state = 'queued', updated = ? WHERE state = 'preparing'", (time.time(),))
            db.execute("UPDATE jobs SET paused_from = 'queued' WHERE state = 'paused' AND paused_from = 'preparing'")
            for row in rows:
                self._event(db, row["id"], None, f"job {row['id']}: the runner stopped during its preparation; "
                            "it is prepared afresh at the next start")
        return [row["id"] for row in rows]

    def fail(self, job_id: int, error: str) -> None:
        """A job cannot go on: failed, with the one-line reason."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state in FINAL_STATES:
                return
            self._move(db, job, "failed", error=error, request=None)
            self._event(db, job_id, job.machine, f"job {job_id} failed: {error}")

    # --- machines ---------------------------------------------------------------------------------------

    def register_machine(self, name: str, port: str) -> None:
        """Add or update a machine; its job (if any) stays assigned, so a restarted runner resumes it."""
        with self.transaction() as db:
            db.execute("INSERT INTO machines (name, port, updated) VALUES (?, ?, ?) "
                       "ON CONFLICT(name) DO UPDATE SET port = excluded.port, updated = excluded.updated",
                       (name, port, time.time()))

    def keep_machines(self, names: list[str]) -> list[str]:
        """Forget every machine not in `names` (the machines this start drives): gone from the page and the status;
        a job that waited on one with its sheet not yet started goes back to whichever machine is free, the sheet
        to be confirmed loaded again there. Returns the names forgotten."""
        with self.transaction() as db:
            known = [row["name"] for row in db.execute("SELECT name FROM machines ORDER BY name")]
            gone = [name for name in known if name not in names]
            for name in gone:
                db.execute("DELETE FROM machines WHERE name = ?", (name,))
                db.execute("UPDATE jobs SET machine = NULL, confirmed = MIN(confirmed, sheet - 1), updated = ? "
                           "WHERE machine = ? AND (state = 'ready' OR (state = 'paused' AND paused_from != 'cutting'))",
                           (time.time(), name))
                held = [row["id"] for row in db.execute("SELECT id FROM jobs WHERE machine = ? AND state IN "
                                                        "('cutting', 'paused', 'attention')", (name,))]
                self._event(db, None, name, f"machine {name} removed (not among the runner's machines)" +
                            "".join(f"; job {job}'s sheet was being cut on it: start the runner with {name} again to "
                                    "go on, or cancel the job" for job in held))
        return gone

    def machines(self) -> list[dict[str, Any]]:
        """Every machine: name, port, state, job, position."""
        rows = self._db.execute("SELECT * FROM machines ORDER BY name").fetchall()
        return [{**dict(r), "position": json.loads(r["position"])} for r in rows]

    def set_machine(self, name: str, state: str | None = None, position: list[float] | None = None) -> None:
        """Record a machine's state and/or position."""
        fields: dict[str, Any] = {"updated": time.time()}
        if state is not None:
            fields["state"] = state
        if position is not None:
            fields["position"] = json.dumps([round(float(v), 3) for v in position])
        with self.transaction() as db:
            db.execute(f"UPDATE machines SET {', '.join(f'{k} = ?' for k in fields)} WHERE name = ?",
                       (*fields.values(), name))

    def claim_for_machine(self, machine: str) -> JobRow | None:
        """The job this machine works on: the one already assigned to it (after a restart), else the oldest
        ready job nobody has; None when there is nothing to do."""
        with self.transaction() as db:
            row = db.execute("SELECT * FROM jobs WHERE machine = ? AND state IN ('ready', 'cutting', 'paused', 'attention') "
                             "ORDER BY id LIMIT 1", (machine,)).fetchone()
            if row is None:
                row = db.execute("SELECT * FROM jobs WHERE machine IS NULL AND state = 'ready' "
                                 "ORDER BY id LIMIT 1").fetchone()
                if row is None:
                    db.execute("UPDATE machines SET job_id = NULL WHERE name = ?", (machine,))
                    return None
                db.execute("UPDATE jobs SET machine = ?, updated = ? WHERE id = ?", (machine, time.time(), row["id"]))
                self._event(db, row["id"], machine, f"job {row['id']} assigned to {machine}")
            db.execute("UPDATE machines SET job_id = ? WHERE name = ?", (row["id"], machine))
        return self.job(row["id"])

    def start_sheet(self, job_id: int, machine: str) -> SheetRow | None:
        """ready -> cutting for the job's current sheet if the operator confirmed it, as a new run with a journal
        of its own; a cutting job's sheet as the operator's choice after an interruption left it (resume or
        restart); None if the sheet may not start (yet)."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state == "cutting" and job.machine == machine:
                pass  # the operator chose to resume or restart this sheet (resolve): its run is set
            elif job.state == "ready" and job.machine == machine and job.confirmed >= job.sheet:
                self._move(db, job, "cutting")
                self._new_run(db, job)
                db.execute("UPDATE sheets SET machine = ?, started = ? WHERE job_id = ? AND k = ?",
                           (machine, time.time(), job_id, job.sheet))
                self._event(db, job_id, machine, f"job {job_id}: cutting sheet {job.sheet + 1} of {job.sheets}")
            else:
                return None
        return self.sheets(job_id)[job.sheet]

    def _new_run(self, db: sqlite3.Connection, job: JobRow) -> None:
        """A new run of the job's current sheet: a fresh run id and a journal nobody has written."""
        run_id = uuid.uuid4().hex[:12]
        journal = self.journals / f"job{job.id}-sheet{job.sheet + 1}-{run_id}.journal"
        db.execute("UPDATE sheets SET run_id = ?, journal = ?, resume = 0, from_line = NULL, done_lines = 0 "
                   "WHERE job_id = ? AND k = ?", (run_id, str(journal), job.id, job.sheet))

    def sheet_progress(self, job_id: int, k: int, done_lines: int) -> None:
        """How many lines of sheet k the controller has executed."""
        with self.transaction() as db:
            db.execute("UPDATE sheets SET done_lines = ? WHERE job_id = ? AND k = ?", (done_lines, job_id, k))

    def finish_sheet(self, job_id: int, k: int) -> JobRow:
        """Sheet k is cut: on to the next sheet (ready, awaiting confirmation) or done."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state != "cutting" or job.sheet != k:
                raise FablineError(f"job {job_id}: sheet {k + 1} finished but the job is {job.describe()}")
            db.execute("UPDATE sheets SET done_lines = lines, finished = ? WHERE job_id = ? AND k = ?",
                       (time.time(), job_id, k))
            last = k + 1 >= job.sheets
            self._move(db, job, "done" if last else "ready", sheet=k if last else k + 1)
            self._event(db, job_id, job.machine, f"job {job_id}: sheet {k + 1} of {job.sheets} cut"
                        + ("; job done" if last else f"; load sheet {k + 2}"))
            if last:
                db.execute("UPDATE machines SET job_id = NULL WHERE name = ?", (job.machine,))
        return self.job(job_id)

    # --- operator -------------------------------------------------------------------------------------

    def confirm_sheet(self, job_id: int, k: int | None = None) -> JobRow:
        """The operator says sheet k (default: the job's next sheet) is on the bed; it may start."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            k = job.sheet if k is None else k
            if job.state not in ("ready", "paused") or k != job.sheet:
                raise FablineError(f"job {job_id}: sheet {k + 1} cannot be confirmed now ({job.describe()})")
            db.execute("UPDATE jobs SET confirmed = ?, updated = ? WHERE id = ?", (k, time.time(), job_id))
            self._event(db, job_id, job.machine, f"job {job_id}: operator confirmed sheet {k + 1} is loaded")
        return self.job(job_id)

    def request(self, job_id: int, action: str) -> JobRow:
        """Pause, resume or cancel a job, or frame its next sheet. A job not being cut changes at once; a cutting
        job gets the request and its machine's worker carries it out (feed hold, cycle start, abort) and records
        the outcome. Framing (the head traces the sheet's outline, laser off) is for a job whose sheet waits for
        the operator's confirmation on its machine; the machine's worker carries it out."""
        if action not in REQUESTS:
            raise FablineError(f"unknown action {action!r} (use one of {', '.join(REQUESTS)})")
        if action in ("resume", "cancel") and self.job(job_id).state == "attention":
            return self.resolve(job_id, action)
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state in FINAL_STATES:
                raise FablineError(f"job {job_id}: already {job.state}")
            if job.state == "attention":
                raise FablineError(f"job {job_id}: {job.describe()}; choose one of: {', '.join(CHOICES)}")
            cutting = job.state == "cutting" or (job.state == "paused" and job.paused_from == "cutting")
            if action == "frame":
                if job.state != "ready" or job.machine is None or job.confirmed >= job.sheet:
                    raise FablineError(f"job {job_id}: a sheet is framed while it waits on its machine for the "
                                       f"operator's confirmation ({job.describe()})")
                db.execute("UPDATE jobs SET request = 'frame' WHERE id = ?", (job_id,))
            elif action == "pause" and job.state != "paused":
                if cutting:
                    db.execute("UPDATE jobs SET request = 'pause' WHERE id = ?", (job_id,))
                else:
                    self._move(db, job, "paused", paused_from=job.state)
            elif action == "resume":
                if job.state != "paused" and job.request != "pause":
                    raise FablineError(f"job {job_id}: not paused ({job.describe()})")
                if cutting:
                    db.execute("UPDATE jobs SET request = 'resume' WHERE id = ?", (job_id,))
                else:
                    self._move(db, job, job.paused_from or "queued", paused_from=None)
            elif action == "cancel":
                if cutting:
                    db.execute("UPDATE jobs SET request = 'cancel' WHERE id = ?", (job_id,))
                else:
                    self._move(db, job, "cancelled")
                    if job.machine:
                        db.execute("UPDATE machines SET job_id = NULL WHERE name = ?", (job.machine,))
            self._event(db, job_id, job.machine, f"job {job_id}: operator asked to {action}")
        return self.job(job_id)

    def act(self, job_id: int, action: str, from_line: int | None = None) -> dict[str, Any]:
        """One operator action (the page's buttons, `fabline runner ACTION`): confirm the sheet, pause, resume,
        cancel, frame, restart or skip a sheet, resume from a file line, or requeue; the job's state after it."""
        if action == "requeue":
            return {"id": self.requeue(job_id), "requeued": job_id}
        if action == "confirm":
            job = self.confirm_sheet(job_id)
        elif action in ("restart", "skip") or from_line is not None:
            job = self.resolve(job_id, action, from_line)
        else:
            job = self.request(job_id, action)
        return {"id": job.id, "state": job.state, "status": job.describe(), "request": job.request}

    def take_request(self, job_id: int) -> str | None:
        """The pending operator request of a cutting job, cleared as it is taken."""
        with self.transaction() as db:
            row = db.execute("SELECT request FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None or row["request"] is None:
                return None
            db.execute("UPDATE jobs SET request = NULL WHERE id = ?", (job_id,))
        return row["request"]

    def set_cutting_state(self, job_id: int, state: str, stopped: dict[str, Any] | None = None) -> None:
        """The worker carried out a request on a cutting job: paused, cutting again, or cancelled (with `stopped`,
        where its sheet stopped, as `JobRow.checkpoint` says it)."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            extra = {"stopped": json.dumps(stopped)} if stopped is not None else {}
            self._move(db, job, state, paused_from="cutting" if state == "paused" else None, **extra)
            if state == "cancelled":
                db.execute("UPDATE machines SET job_id = NULL WHERE name = ?", (job.machine,))
            self._event(db, job_id, job.machine, f"job {job_id}: {state}")

    def resolve(self, job_id: int, choice: str, from_line: int | None = None) -> JobRow:
        """The operator's choice for a job that needs attention: resume its sheet where it stopped (from its
        journal, or from file line `from_line`), restart the sheet, skip it, or cancel the job."""
        if choice not in CHOICES:
            raise FablineError(f"unknown choice {choice!r} (use one of {', '.join(CHOICES)})")
        if from_line is not None and (choice != "resume" or from_line < 1):
            raise FablineError("a start line goes with resume, and is a file line number from 1")
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state != "attention":
                raise FablineError(f"job {job_id}: does not need attention ({job.describe()})")
            where = (job_id, job.sheet)
            if choice == "resume":
                db.execute("UPDATE sheets SET resume = 1, from_line = ? WHERE job_id = ? AND k = ?", (from_line, *where))
                self._move(db, job, "cutting", attention=None)
            elif choice == "restart":
                self._new_run(db, job)
                self._move(db, job, "cutting", attention=None)
            elif choice == "skip":
                db.execute("UPDATE sheets SET skipped = 1, finished = ? WHERE job_id = ? AND k = ?", (time.time(), *where))
                last = job.sheet + 1 >= job.sheets
                self._move(db, job, "done" if last else "ready", sheet=job.sheet if last else job.sheet + 1,
                           attention=None)
                if last:
                    db.execute("UPDATE machines SET job_id = NULL WHERE name = ?", (job.machine,))
            else:
                self._move(db, job, "cancelled", attention=None, stopped=job.attention)
                db.execute("UPDATE machines SET job_id = NULL WHERE name = ?", (job.machine,))
            line = f" from file line {from_line}" if from_line else ""
            self._event(db, job_id, job.machine, f"job {job_id}: operator chose to {choice} sheet {job.sheet + 1}{line}"
                        if choice != "cancel" else f"job {job_id}: operator cancelled the job")
        return self.job(job_id)

    def requeue(self, job_id: int) -> int:
        """A failed or cancelled job again, as a new job (its file prepared afresh, or its programs ready to cut,
        each sheet a new run); returns the new job's id."""
        job = self.job(job_id)
        if job.state not in ("failed", "cancelled"):
            raise FablineError(f"job {job_id}: only a failed or cancelled job can be queued again ({job.describe()})")
        programs = None if job.job_file else [(s.name, s.program, s.svg, s.load_facts()) for s in self.sheets(job_id)]
        new = self.submit(job.name, job_file=job.job_file, programs=programs)
        self.log(job_id, None, f"job {job_id} queued again as job {new}")
        return new

    def need_attention(self, job_id: int, checkpoint: dict[str, Any]) -> None:
        """A sheet stopped without finishing: the job waits for the operator's choice (`resolve`). `checkpoint`
        says why and where (see JobRow.checkpoint)."""
        with self.transaction() as db:
            job = self._locked_job(db, job_id)
            if job.state in FINAL_STATES:
                return
            self._move(db, job, "attention", attention=json.dumps(checkpoint), request=None, paused_from=None)
            self._event(db, job_id, job.machine, f"job {job_id}: {self._locked_job(db, job_id).describe()}")

    def interrupted(self) -> list[JobRow]:
        """Jobs whose sheet was being cut (or held in a pause) when the runner stopped: no stream runs for them."""
        rows = self._db.execute("SELECT * FROM jobs WHERE state = 'cutting' OR (state = 'paused' AND paused_from = 'cutting') "
                                "ORDER BY id").fetchall()
        return [JobRow(**dict(r)) for r in rows]

    # --- the machines' console ---------------------------------------------------------------------------

    def add_command(self, machine: str, line: str | None = None, override: str | None = None) -> int:
        """An operator's console command for a machine's worker to carry out: a checked console `line` or a
        real-time `override` by name (see fabline.jobs.console); returns its id (state pending)."""
        now = time.time()
        with self.transaction() as db:
            if db.execute("SELECT 1 FROM machines WHERE name = ?", (machine,)).fetchone() is None:
                raise FablineError(f"no machine named {machine!r}")
            cursor = db.execute("INSERT INTO commands (machine, line, override, created, updated) VALUES (?, ?, ?, ?, ?)",
                                (machine, line, override, now, now))
        return int(cursor.lastrowid)

    def pending_commands(self, machine: str) -> list[dict[str, Any]]:
        """The machine's console commands not carried out yet, oldest first."""
        return [dict(r) for r in self._db.execute("SELECT * FROM commands WHERE machine = ? AND state = 'pending' "
                                                  "ORDER BY id", (machine,))]

    def command(self, command_id: int) -> dict[str, Any]:
        """One console command: its line or override, state (pending, done, refused, failed) and answer."""
        row = self._db.execute("SELECT * FROM commands WHERE id = ?", (command_id,)).fetchone()
        if row is None:
            raise FablineError(f"console command {command_id}: no such command")
        return {**dict(row), "answer": json.loads(row["answer"]) if row["answer"] else None}

    def finish_command(self, command_id: int, state: str, answer: list[str]) -> None:
        """A console command was carried out (done: `answer` is the controller's), refused or failed (`answer`
        says why); the command and its answer go into the event log too."""
        with self.transaction() as db:
            row = db.execute("SELECT * FROM commands WHERE id = ?", (command_id,)).fetchone()
            db.execute("UPDATE commands SET state = ?, answer = ?, updated = ? WHERE id = ?",
                       (state, json.dumps(answer), time.time(), command_id))
            what = row["line"] if row["line"] is not None else f"override {row['override']}"
            said = " | ".join(answer) if answer else "sent"
            self._event(db, None, row["machine"], f"console on {row['machine']}: {what} -> "
                        + (said if state == "done" else f"{state}: {said}"))

    # --- recovery and log -------------------------------------------------------------------------------

    def recover(self) -> int:
        """After a crash: jobs left in preparing go back to queued (preparation is repeatable); returns how many."""
        with self.transaction() as db:
            count = db.execute("UPDATE jobs SET state = 'queued', updated = ? WHERE state = 'preparing'",
                               (time.time(),)).rowcount
            count += db.execute("UPDATE jobs SET paused_from = 'queued' WHERE state = 'paused' AND "
                                "paused_from = 'preparing'").rowcount
            if count:
                self._event(db, None, None, f"runner restarted: {count} job(s) back to queued for preparation")
        return count

    def log(self, job_id: int | None, machine: str | None, message: str) -> None:
        """Add a line to the event log."""
        with self.transaction() as db:
            self._event(db, job_id, machine, message)

    def _event(self, db: sqlite3.Connection, job_id: int | None, machine: str | None, message: str) -> None:
        db.execute("INSERT INTO events (time, job_id, machine, message) VALUES (?, ?, ?, ?)",
                   (time.time(), job_id, machine, message))

    def events(self, after: int = 0, limit: int = 200) -> list[dict[str, Any]]:
        """Event log entries with id > after, oldest first (at most `limit`, the newest ones)."""
        rows = self._db.execute("SELECT * FROM (SELECT * FROM events WHERE id > ? ORDER BY id DESC LIMIT ?) "
                                "ORDER BY id", (after, limit)).fetchall()
        return [dict(r) for r in rows]

    def what_was_cut(self, job: JobRow, sheets: list[SheetRow]) -> dict[str, Any] | None:
        """For a cancelled or failed job: the sheets finished (names, parts on them) and where the sheet being cut
        stopped (its name, lines executed and acknowledged, the last file line of each), or None for other jobs."""
        if job.state not in ("cancelled", "failed") or not sheets:
            return None
        finished = [s for s in sheets if s.finished is not None and not s.skipped]
        stopped = json.loads(job.stopped) if job.stopped else None
        if stopped is not None:
            stopped = {**stopped, "sheet": sheets[job.sheet].name, "k": job.sheet}
        return {"sheets_finished": [s.name for s in finished], "sheets": len(sheets),
                "parts_finished": sum(s.load_facts().get("parts", 0) for s in finished)
                if all("parts" in s.load_facts() for s in finished) else None,
                "stopped": stopped}

    def snapshot(self) -> dict[str, Any]:
        """Queue, machines and sheet progress as plain data for the web page and `fabline runner status`."""
        jobs = []
        for job in self.jobs():
            sheets = self.sheets(job.id)
            skipped = sum(s.skipped for s in sheets)
            status = job.describe() + (f" ({skipped} sheet(s) skipped)" if skipped else "")
            jobs.append({**job.__dict__, "status": status, "checkpoint": job.checkpoint(),
                         "cut": self.what_was_cut(job, sheets),
                         "sheet_list": [{"k": s.k, "name": s.name, "lines": s.lines, "done_lines": s.done_lines,
                                         "machine": s.machine, "skipped": bool(s.skipped), "facts": s.load_facts(),
                                         "load": describe_load(s.name, s.k, len(sheets), s.load_facts())}
                                        for s in sheets]})
        return {"jobs": jobs, "machines": self.machines(), "events": self.events(limit=20)}


def _count_lines(program: str | os.PathLike) -> int:
    """Command lines of a G-code program as the streamer sends them; a bad program is a FablineError."""
    from fabline.machine.program import load_program

    return len(load_program(program).lines)
