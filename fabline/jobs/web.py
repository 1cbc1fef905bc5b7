"""The runner's web page and API (Starlette): queue, machines, live sheet pictures, operator buttons.

Who may see and do what: the page shell (`/`, static HTML with no data in it) is open; every other route,
reads included, needs the token printed at start-up, as the `X-Fabline-Token` header or a `token` query
parameter (what the page's event stream and pictures use), or it gets 403 and nothing else: job names,
file paths and errors are for the operator only. Requests must name an allowed host in their Host header
(loopback names by default, `--allow-host` adds more), so a web page elsewhere cannot reach the runner
through DNS rebinding. Live updates go out as server-sent events: the whole snapshot whenever it changes.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import os
import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from fabline.errors import FablineError
from fabline.jobs.console import check_line, check_override
from fabline.jobs.jobfile import load_job_file
from fabline.jobs.pictures import progress_svg
from fabline.jobs.queue import JobQueue
from fabline.progress import Eta, estimate, finish_time, simulated_speedup

TOKEN_HEADER = "X-Fabline-Token"
ACTIONS = ("confirm", "pause", "resume", "cancel", "restart", "skip", "requeue", "frame")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
_LARGEST_ID = 2 ** 62  # ids beyond SQLite's integers are no job


def create_app(db_path: str | Path, token: str, poll: float = 0.25, hosts: tuple[str, ...] = (),
               jobs: str | Path | None = None, console_timeout: float = 150.0) -> Starlette:
    """The web application over the queue at `db_path`; `token` guards everything but the page shell;
    requests must name one of the loopback `LOOPBACK_HOSTS` or of `hosts` in their Host header. Uploaded job
    files go into `jobs` (default: the queue's folder); a console command waits `console_timeout` s for its machine."""
    queue = JobQueue(db_path)
    jobs_folder = Path(jobs) if jobs is not None else Path(db_path).parent
    page = resources.files("fabline.jobs").joinpath("static/index.html").read_text(encoding="utf-8")

    def authorised(request: Request) -> bool:
        given = request.headers.get(TOKEN_HEADER) or request.query_params.get("token") or ""
        return hmac.compare_digest(given.encode(), token.encode())

    def guarded(handler):
        """`handler` for token holders only; anyone else gets 403 and nothing of the queue."""
        async def route(request: Request) -> Response:
            if not authorised(request):
                return JSONResponse({"error": "forbidden: a valid token is required"}, status_code=403)
            return await handler(request)
        return route

    async def index(request: Request) -> Response:
        return HTMLResponse(page)

    timelines = Timelines()

    def snapshot() -> dict:
        state = {**queue.snapshot(), "ports": serial_ports()}
        for job in state["jobs"]:
            job["eta"] = job_eta(queue, job, state["machines"], timelines)
        return state

    async def state(request: Request) -> Response:
        return JSONResponse(snapshot())

    async def events(request: Request) -> Response:
        async def stream():
            last = None
            while not await request.is_disconnected():
                text = json.dumps(snapshot(), separators=(",", ":"))
                if text != last:
                    last = text
                    yield f"event: state\ndata: {text}\n\n"
                else:
                    yield ": keep-alive\n\n"
                await asyncio.sleep(poll)

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    async def sheet_picture(request: Request) -> Response:
        job_id, k = int(request.path_params["job"]), int(request.path_params["k"])
        try:
            if job_id >= _LARGEST_ID:
                raise FablineError(f"job {job_id}: no such job")
            sheets = queue.sheets(job_id)
            if not 0 <= k < len(sheets):
                raise FablineError(f"job {job_id}: no sheet {k + 1}")
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=404)
        sheet, job = sheets[k], queue.job(job_id)
        tool = None
        if job.machine and job.sheet == k and job.state in ("cutting", "paused", "attention"):  # the head is on it
            tool = next((m["position"][:2] for m in queue.machines() if m["name"] == job.machine), None)
        svg = await asyncio.to_thread(progress_svg, sheet.program, sheet.done_lines, sheet.svg, tool)
        return Response(svg, media_type="image/svg+xml", headers={"Cache-Control": "no-store"})

    async def act(request: Request) -> Response:
        job_id, action = int(request.path_params["job"]), request.path_params["action"]
        if action not in ACTIONS:
            return JSONResponse({"error": f"unknown action {action!r}"}, status_code=404)
        try:
            from_line = await _from_line(request)
            if job_id >= _LARGEST_ID:
                raise FablineError(f"job {job_id}: no such job")
            return JSONResponse(queue.act(job_id, action, from_line))
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)

    async def report(request: Request) -> Response:
        job_id = int(request.path_params["job"])
        try:
            path = queue.job(job_id).report if job_id < _LARGEST_ID else None
        except FablineError:
            path = None
        if not path or not Path(path).is_file():
            return JSONResponse({"error": f"job {job_id}: no report (yet)"}, status_code=404)
        return FileResponse(path, media_type="text/html")

    async def submit(request: Request) -> Response:
        try:
            body = await request.json()
            spec = await asyncio.to_thread(load_job_file, body["job_file"])  # a slow disk never stalls the page
            job_id = queue.submit(spec.name, job_file=str(spec.path))
        except (KeyError, TypeError, ValueError):
            return JSONResponse({"error": "expected JSON {\"job_file\": PATH}"}, status_code=400)
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        return JSONResponse({"id": job_id})

    async def console(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in {machine["name"] for machine in queue.machines()}:
            return JSONResponse({"error": f"no machine named {name!r}"}, status_code=404)
        try:
            body = await request.json()
            if not isinstance(body, dict) or ("line" in body) == ("override" in body):
                raise ValueError
            if "line" in body:
                line, kind = check_line(body["line"])
                if kind == "setting" and body.get("confirm") is not True:
                    raise FablineError(f"console: {line} changes the controller's setting for every later program: "
                                       "confirm it (send it again with \"confirm\": true)")
                command = queue.add_command(name, line=line)
            else:
                command = queue.add_command(name, override=check_override(body["override"]))
        except (ValueError, TypeError):
            return JSONResponse({"error": "expected JSON {\"line\": \"$X\"} (with \"confirm\": true for a $N=V "
                                          "setting) or {\"override\": \"feed +10%\"}"}, status_code=400)
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)
        deadline = time.monotonic() + console_timeout
        while (done := queue.command(command))["state"] == "pending":
            if time.monotonic() > deadline:
                return JSONResponse({"error": f"machine {name}: its worker did not take the command within "
                                              f"{console_timeout:g} s (is the runner running?)", "id": command},
                                    status_code=504)
            await asyncio.sleep(0.05)
        status = 200 if done["state"] == "done" else 409
        return JSONResponse({"id": command, "state": done["state"], "answer": done["answer"],
                             **({"error": "; ".join(done["answer"])} if status != 200 else {})}, status_code=status)

    async def upload(request: Request) -> Response:
        try:
            body = await request.json()
            name, text = body["name"], body["text"]
            if not isinstance(name, str) or not isinstance(text, str):
                raise TypeError
        except (KeyError, TypeError, ValueError):
            return JSONResponse({"error": "expected JSON {\"name\": \"JOB.toml\", \"text\": \"...\"}"},
                                status_code=400)
        try:
            path, spec = await asyncio.to_thread(save_upload, jobs_folder, name, text)
            job_id, new = queue.submit_once(spec.name, job_file=str(path))
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        return JSONResponse({"id": job_id, "file": str(path), "new": new})

    routes = [
        Route("/", index),
        Route("/api/machines/{name}/console", guarded(console), methods=["POST"]),
        Route("/api/jobs/upload", guarded(upload), methods=["POST"]),
        Route("/api/state", guarded(state)),
        Route("/api/events", guarded(events)),
        Route("/api/jobs/{job:int}/sheets/{k:int}.svg", guarded(sheet_picture)),
        Route("/api/jobs/{job:int}/report", guarded(report)),
        Route("/api/jobs/{job:int}/{action}", guarded(act), methods=["POST"]),
        Route("/api/jobs", guarded(submit), methods=["POST"]),
    ]
    allowed = [*LOOPBACK_HOSTS, *hosts]
    return Starlette(routes=routes, middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=allowed)])


_UPLOAD_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,80}\.toml")


def save_upload(folder: Path, name: str, text: str) -> tuple[Path, Any]:
    """An uploaded job file checked (as if it lay in `folder`: its relative paths resolve there) and written into
    `folder` as `name`, or as `STEM-SHA8.toml` when a different file has that name (a queued job's file is never
    changed under it); returns the file and its job."""
    import hashlib
    import tomllib

    from fabline.fileio import atomic_output
    from fabline.jobs.jobfile import JOB_FILE_LIMIT, job_from_dict

    if not _UPLOAD_NAME.fullmatch(name):
        raise FablineError(f"upload {name!r}: a job file's name is letters, digits, '.', '_' or '-' ending in .toml")
    data = text.encode("utf-8")
    if len(data) > JOB_FILE_LIMIT:
        raise FablineError(f"upload {name}: {len(data)} bytes; a job file has at most {JOB_FILE_LIMIT}")
    path = folder.resolve() / name
    if path.exists() and (not path.is_file() or path.read_bytes() != data):
        path = path.with_name(f"{path.stem}-{hashlib.sha256(data).hexdigest()[:8]}.toml")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FablineError(f"{name}: malformed TOML: {exc}") from None
    spec = job_from_dict(raw, path)
    if not path.exists():
        with atomic_output(path, "wb") as handle:
            handle.write(data)
    return path, spec


class Timelines:
    """Planned seconds per line of sheet programs (`fabline.jobs.streaming.program_timeline`), each computed once,
    in a background thread (a 20 000-line sheet takes a second or two): None until it is ready."""

    def __init__(self):
        self._ready: dict[tuple[str, float], Any] = {}
        self._asked: set[tuple[str, float]] = set()
        self._lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="timeline")

    def get(self, program: str):
        """The program's timeline (numpy array), or None while it is computed or if it cannot be read."""
        try:
            key = (program, os.stat(program).st_mtime)
        except OSError:
            return None
        with self._lock:
            if key in self._ready or key in self._asked:
                return self._ready.get(key)
            self._asked.add(key)
        self._pool.submit(self._compute, key)
        return None

    def _compute(self, key: tuple[str, float]) -> None:
        from fabline.jobs.streaming import program_timeline

        try:
            timeline = program_timeline(key[0])
        except FablineError:
            return
        with self._lock:
            self._ready[key] = timeline


def job_eta(queue: JobQueue, job: dict, machines: list[dict], timelines: Timelines) -> dict | None:
    """Elapsed and remaining time of a job's current sheet and of the whole job, from the planned time of the lines
    done and to do corrected by the pace so far (`fabline.progress.estimate`), in seconds on the job's machine
    (a simulator's time scale applied), with `finish_at` the estimated end (Unix time); None until every sheet's
    plan is known or when the job is not under way. Time a sheet stood waiting for the operator (paused, needs
    attention) is not counted as work, so waiting does not make the remaining time grow; `fraction` is the share of
    the planned machine time done, what the page's bar shows."""
    if job["state"] in ("queued", "preparing", "failed", "cancelled") or not job["sheet_list"]:
        return None
    rows = queue.sheets(job["id"])
    plans = [timelines.get(row.program) for row in rows]
    if any(plan is None or not len(plan) for plan in plans):
        return None
    port = next((m["port"] for m in machines if m["name"] == job.get("machine")), "")
    speedup = simulated_speedup(port)
    now = time.time()
    planned_total = planned_done = worked = 0.0
    sheet = None
    for row, plan in zip(rows, plans):
        total = float(plan[-1]) / speedup
        done = float(plan[min(row.done_lines, len(plan)) - 1]) / speedup if row.done_lines else 0.0
        elapsed = max((row.finished or now) - row.started - row.waiting(now), 0.0) if row.started else 0.0
        if row.skipped:
            continue
        planned_total, planned_done, worked = planned_total + total, planned_done + done, worked + elapsed
        if row.k == job["sheet"]:
            sheet = estimate(total, done, elapsed if row.started and not row.finished else 0.0)
    whole = estimate(planned_total, planned_done, worked)
    finishing = job["state"] not in ("done",)
    return {"sheet": _eta_dict(sheet, now) if sheet is not None and finishing else None,
            "job": _eta_dict(whole, now) if finishing else None}


def _eta_dict(eta: Eta, now: float) -> dict:
    """Whole seconds, so the live page's snapshot changes once a second, not on every poll; `finish` is the end as
    a clock reads it (with its date when that is not today)."""
    return {"elapsed_s": round(eta.elapsed), "remaining_s": round(eta.remaining), "planned_s": round(eta.planned),
            "pace": round(eta.pace, 2), "finish_at": round(now + eta.remaining),
            "finish": finish_time(round(now + eta.remaining), now),
            "fraction": round(eta.fraction, 4) if eta.fraction is not None else None}


_PORTS_TTL = 5.0
_ports_seen: list = [0.0, []]


def serial_ports() -> list[dict[str, str]]:
    """The serial ports this computer has (device and description, as pyserial finds them), looked up at most
    every few seconds: the page shows them so the operator can tell which one a machine is on."""
    from serial.tools import list_ports

    now = time.monotonic()
    if now - _ports_seen[0] > _PORTS_TTL:
        _ports_seen[:] = [now, [{"device": p.device, "description": p.description or ""}
                                for p in sorted(list_ports.comports(), key=lambda p: p.device)]]
    return _ports_seen[1]


async def _from_line(request: Request) -> int | None:
    """The optional `from_line` (a file line to resume from) of an action's JSON body."""
    body = await request.body()
    if not body.strip():
        return None
    try:
        value = json.loads(body).get("from_line")
    except (ValueError, AttributeError):
        raise FablineError("expected a JSON object such as {\"from_line\": 158}") from None
    if value is None:
        return None
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value < _LARGEST_ID:
        raise FablineError(f"from_line: expected a file line number from 1, got {value!r}")
    return value
