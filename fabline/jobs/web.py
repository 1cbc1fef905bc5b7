"""The runner's web page and API (Starlette): queue, machines, live sheet pictures, operator buttons.

Who may see and do what: the page shell (`/`, static HTML with no data in it) is open; every other route,
reads included, needs the token printed at start-up, as the `X-Fabline-Token` header or a `token` query
parameter (what the page's event stream and pictures use), or it gets 403 and nothing else: job names,
file paths and errors are for the operator only. Requests must name an allowed host in their Host header
(loopback names by default, `--allow-host` adds more), so a web page elsewhere cannot reach the runner
through DNS rebinding. Live updates go out as server-sent events: the whole snapshot whenever it changes.
Every answer carries a Content-Security-Policy (the page runs only its own script), X-Frame-Options: DENY and
nosniff; a body over BODY_LIMIT is refused (413) before it is read, a malformed, too deep or mistyped JSON body gets a
one-line 400 naming the field, and no client's input ever makes a traceback (`Guard`).
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import hmac
import json
import logging
import os
import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from fabline.errors import FablineError
from fabline.fileio import nesting_depth
from fabline.jobs.console import check_line, check_override
from fabline.jobs.jobfile import load_job_file
from fabline.jobs.pictures import progress_svg
from fabline.jobs.queue import JobQueue
from fabline.progress import Eta, estimate, finish_time, simulated_speedup

TOKEN_HEADER = "X-Fabline-Token"
ACTIONS = ("confirm", "pause", "resume", "cancel", "restart", "skip", "requeue", "frame")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
_LARGEST_ID = 2 ** 62  # ids beyond SQLite's integers are no job
BODY_LIMIT = 4 << 20  # bytes of a request body: an uploaded job file (at most 1 MiB of TOML) as JSON, with room
JSON_DEPTH = 32  # levels of nesting in a request's JSON; the API's bodies have one
_log = logging.getLogger(__name__)


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
        return HTMLResponse(page, headers={"Content-Security-Policy": page_policy(page)})

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
        from_line = await _from_line(request)
        try:
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
        return FileResponse(path, media_type="text/html", headers={"Content-Security-Policy": REPORT_POLICY})

    async def submit(request: Request) -> Response:
        body = await json_object(request, '{"job_file": PATH}')
        job_file = field(body, "job_file", str, "a job file's path")
        try:
            spec = await asyncio.to_thread(load_job_file, job_file)  # a slow disk never stalls the page
            job_id = queue.submit(spec.name, job_file=str(spec.path))
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        return JSONResponse({"id": job_id})

    async def console(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in {machine["name"] for machine in queue.machines()}:
            return JSONResponse({"error": f"no machine named {name!r}"}, status_code=404)
        shape = '{"line": "$X"} (with "confirm": true for a $N=V setting) or {"override": "feed +10%"}'
        body = await json_object(request, shape)
        if ("line" in body) == ("override" in body):
            raise BadRequest(f"body: expected one of \"line\" and \"override\": {shape}")
        confirmed = field(body, "confirm", bool, "true or false", required=False)
        try:
            if "line" in body:
                line, kind = check_line(field(body, "line", str, "a G-code or $ line"))
                if kind == "setting" and confirmed is not True:
                    raise FablineError(f"console: {line} changes the controller's setting for every later program: "
                                       "confirm it (send it again with \"confirm\": true)")
                command = queue.add_command(name, line=line)
            else:
                command = queue.add_command(name, override=check_override(field(body, "override", str,
                                                                                "an override such as \"feed +10%\"")))
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
        body = await json_object(request, '{"name": "JOB.toml", "text": "..."}')
        name = field(body, "name", str, "a job file's name")
        text = field(body, "text", str, "the job file's text")
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
    middleware = [Middleware(Guard), Middleware(TrustedHostMiddleware, allowed_hosts=allowed)]
    return Starlette(routes=routes, middleware=middleware,
                     exception_handlers={BadRequest: _bad_request, HTTPException: _http_error})


PAGE_POLICY = ("default-src 'self'; script-src {scripts}; style-src {styles}; img-src 'self' data:; "
               "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'")
"""The page's Content-Security-Policy: its own inline script and style (by their SHA-256) and nothing else runs."""
REPORT_POLICY = ("default-src 'none'; img-src 'self' data:; style-src 'unsafe-inline'; frame-ancestors 'none'; "
                 "sandbox allow-popups")
"""A job's report: a document with inline style and pictures and no script (none may run in it)."""
API_POLICY = "default-src 'none'; frame-ancestors 'none'; sandbox"
"""Every other answer (JSON, pictures, errors): nothing in it may load or run anything."""
_INLINE = re.compile(r"<(script|style)>(.*?)</\1>", re.DOTALL)


def page_policy(page: str) -> str:
    """PAGE_POLICY for `page`: the hashes of its inline <script> and <style> blocks (no 'unsafe-inline')."""
    found: dict[str, list[str]] = {"script": [], "style": []}
    for kind, text in _INLINE.findall(page):
        found[kind].append("'sha256-" + base64.b64encode(hashlib.sha256(text.encode()).digest()).decode() + "'")
    return PAGE_POLICY.format(scripts=" ".join(found["script"]) or "'none'",
                              styles=" ".join(found["style"]) or "'none'")


class BadRequest(Exception):
    """A client's request that cannot be taken (malformed, too deep, a field of the wrong type): a one-line 400."""


class BodyTooLarge(Exception):
    """A request body that passed BODY_LIMIT while it was read."""


async def _bad_request(request: Request, exc: BadRequest) -> Response:
    return JSONResponse({"error": str(exc)}, status_code=400)


async def _http_error(request: Request, exc: HTTPException) -> Response:
    return JSONResponse({"error": exc.detail}, status_code=exc.status_code, headers=exc.headers)


async def json_object(request: Request, shape: str) -> dict:
    """The request's body as a JSON object, or BadRequest naming what is wrong and the `shape` expected: not JSON,
    nested deeper than JSON_DEPTH (a deep body would otherwise exhaust the parser's recursion), not an object."""
    body = await request.body()
    try:
        value = json.loads(body)
    except RecursionError:
        value = None
        depth = JSON_DEPTH + 1
    except ValueError as exc:
        raise BadRequest(f"body: not JSON ({str(exc).splitlines()[0][:120]}); expected {shape}") from None
    else:
        depth = nesting_depth(value, JSON_DEPTH)
    if depth > JSON_DEPTH:
        raise BadRequest(f"body: JSON nested deeper than {JSON_DEPTH} levels; expected {shape}")
    if not isinstance(value, dict):
        raise BadRequest(f"body: expected a JSON object {shape}, got {_json_type(value)}")
    return value


def field(body: dict, name: str, kind: type, what: str, required: bool = True) -> Any:
    """`body[name]` if it is a `kind` (a bool is no int), else BadRequest naming the field; None when it is absent
    (or null) and not `required`."""
    value = body.get(name)
    if value is None and not required:
        return None
    if value is None and name not in body:
        raise BadRequest(f"{name}: missing; expected {what}")
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise BadRequest(f"{name}: expected {what}, got {_json_type(value)}")
    return value


def _json_type(value: Any) -> str:
    names = {dict: "an object", list: "an array", str: "a string", int: "a number", float: "a number"}
    return json.dumps(value) if value is None or isinstance(value, bool) else names[type(value)]


_SECURITY_HEADERS = [(b"x-frame-options", b"DENY"), (b"x-content-type-options", b"nosniff"),
                     (b"referrer-policy", b"no-referrer")]  # the page's URLs carry the token: never sent on
_OURS = {k for k, _ in _SECURITY_HEADERS} | {b"content-security-policy"}


class Guard:
    """ASGI middleware around the whole app: every answer gets the security headers (a CSP of API_POLICY unless the
    route set its own); a body whose Content-Length passes BODY_LIMIT is refused (413) before a byte of it is read,
    one sent without a length is counted as it arrives and refused when it passes the limit; an error no route
    answered is logged once and answered with a one-line 500 (never a traceback for the client)."""

    def __init__(self, app, limit: int = BODY_LIMIT):
        self.app, self.limit = app, limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False

        async def guarded_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                headers = [(k, v) for k, v in message.get("headers", []) if k.lower() not in _OURS]
                policy = next((v for k, v in message.get("headers", []) if k.lower() == b"content-security-policy"),
                              API_POLICY.encode())
                message = {**message, "headers": [*headers, *_SECURITY_HEADERS, (b"content-security-policy", policy)]}
            await send(message)

        length = dict(scope.get("headers", [])).get(b"content-length")
        if length is not None:
            if not length.isdigit():
                return await _answer(guarded_send, 400, "Content-Length: not a number of bytes")
            if int(length) > self.limit:
                return await _answer(guarded_send, 413, f"request body: {int(length)} bytes, {self._over}: not read")
        received = 0

        async def counted_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise BodyTooLarge
            return message

        try:
            await self.app(scope, counted_receive, guarded_send)
        except BodyTooLarge:
            if not started:
                await _answer(guarded_send, 413, f"request body (sent without a length): {self._over}: "
                                                 "not read further")
        except Exception:
            if started:
                raise
            _log.exception("runner web: %s %s failed", scope.get("method"), scope.get("path"))
            await _answer(guarded_send, 500, "internal error in the runner (its log has the details)")

    @property
    def _over(self) -> str:
        return f"more than the {self.limit} bytes ({self.limit / (1 << 20):g} MiB) the runner takes"


async def _answer(send, status: int, error: str) -> None:
    """A one-line JSON error answered straight from the middleware (the connection closes after it)."""
    body = json.dumps({"error": error}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


_UPLOAD_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,80}\.toml")


def save_upload(folder: Path, name: str, text: str) -> tuple[Path, Any]:
    """An uploaded job file checked (as if it lay in `folder`: its relative paths resolve there) and written into
    `folder` as `name`, or as `STEM-SHA8.toml` when a different file has that name (a queued job's file is never
    changed under it); returns the file and its job."""
    from fabline.fileio import INPUT_LIMITS, atomic_output
    from fabline.jobs.jobfile import job_from_text

    if not _UPLOAD_NAME.fullmatch(name):
        raise FablineError(f"upload {name!r}: a job file's name is letters, digits, '.', '_' or '-' ending in .toml")
    data = text.encode("utf-8")
    if len(data) > INPUT_LIMITS["config"]:
        raise FablineError(f"upload {name}: {len(data)} bytes; a job file has at most {INPUT_LIMITS['config']}")
    path = folder.resolve() / name
    if path.exists() and (not path.is_file() or path.read_bytes() != data):
        path = path.with_name(f"{path.stem}-{hashlib.sha256(data).hexdigest()[:8]}.toml")
    spec = job_from_text(text, path, where=name)
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
    """The optional `from_line` (a file line to resume from) of an action's JSON body (none, or an object)."""
    if not (await request.body()).strip():
        return None
    value = field(await json_object(request, '{"from_line": 158}'), "from_line", int, "a file line number from 1",
                  required=False)
    if value is not None and not 1 <= value < _LARGEST_ID:
        raise BadRequest(f"from_line: expected a file line number from 1, got {value}")
    return value
