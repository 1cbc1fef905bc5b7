"""The runner's web page and API (Starlette): queue, machines, live sheet pictures, operator buttons.

Reads are open (the server binds to 127.0.0.1 by default); every state-changing request must carry the
token printed at start-up, as the `X-Fabline-Token` header or a `token` query parameter, or it gets 403.
Live updates go out as server-sent events: the whole snapshot whenever it changes.
"""

from __future__ import annotations

import asyncio
import hmac
import json
from importlib import resources
from pathlib import Path

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from fabline.errors import FablineError
from fabline.jobs.jobfile import load_job_file
from fabline.jobs.pictures import progress_svg
from fabline.jobs.queue import JobQueue

TOKEN_HEADER = "X-Fabline-Token"
ACTIONS = ("confirm", "pause", "resume", "cancel")


def create_app(db_path: str | Path, token: str, poll: float = 0.25) -> Starlette:
    """The web application over the queue at `db_path`; `token` guards every POST."""
    queue = JobQueue(db_path)
    page = resources.files("fabline.jobs").joinpath("static/index.html").read_text(encoding="utf-8")

    def authorised(request: Request) -> bool:
        given = request.headers.get(TOKEN_HEADER) or request.query_params.get("token") or ""
        return hmac.compare_digest(given.encode(), token.encode())

    async def index(request: Request) -> Response:
        return HTMLResponse(page)

    async def state(request: Request) -> Response:
        return JSONResponse(queue.snapshot())

    async def events(request: Request) -> Response:
        async def stream():
            last = None
            while not await request.is_disconnected():
                text = json.dumps(queue.snapshot(), separators=(",", ":"))
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
            sheets = queue.sheets(job_id)
            if not 0 <= k < len(sheets):
                raise FablineError(f"job {job_id}: no sheet {k + 1}")
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=404)
        sheet = sheets[k]
        svg = await asyncio.to_thread(progress_svg, sheet.program, sheet.done_lines, sheet.svg)
        return Response(svg, media_type="image/svg+xml", headers={"Cache-Control": "no-store"})

    async def act(request: Request) -> Response:
        if not authorised(request):
            return JSONResponse({"error": "forbidden: a valid token is required"}, status_code=403)
        job_id, action = int(request.path_params["job"]), request.path_params["action"]
        if action not in ACTIONS:
            return JSONResponse({"error": f"unknown action {action!r}"}, status_code=404)
        try:
            job = queue.confirm_sheet(job_id) if action == "confirm" else queue.request(job_id, action)
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)
        return JSONResponse({"id": job.id, "state": job.state, "status": job.describe()})

    async def submit(request: Request) -> Response:
        if not authorised(request):
            return JSONResponse({"error": "forbidden: a valid token is required"}, status_code=403)
        try:
            body = await request.json()
            spec = load_job_file(body["job_file"])
            job_id = queue.submit(spec.name, job_file=str(spec.path))
        except (KeyError, TypeError, ValueError):
            return JSONResponse({"error": "expected JSON {\"job_file\": PATH}"}, status_code=400)
        except FablineError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        return JSONResponse({"id": job_id})

    routes = [
        Route("/", index),
        Route("/api/state", state),
        Route("/api/events", events),
        Route("/api/jobs/{job:int}/sheets/{k:int}.svg", sheet_picture),
        Route("/api/jobs/{job:int}/{action}", act, methods=["POST"]),
        Route("/api/jobs", submit, methods=["POST"]),
    ]
    return Starlette(routes=routes)
