"""The live status page: ``/`` and its static files (public: they hold no data), and the
authenticated JSON, binary and event-stream endpoints it reads (``/api/preflight/...``).

The handlers are thin: the snapshot of the daemon comes from :mod:`daemon.web.snapshot`,
meshes and G-code layers from :mod:`daemon.web.previews`, and job actions go through the
daemon's request path (:func:`daemon.web.control.ask_daemon`), as ``preflight jobs`` does.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

from aiohttp import web

from daemon.web import control, previews, snapshot
from daemon.web.common import BACKEND
from daemon.web.uploads import Refused

STATIC = Path(__file__).resolve().parent / "static"

#: How often the event stream looks at the journal, and how long it stays quiet at most
#: (a comment line keeps proxies and the browser from closing an idle stream).
WATCH_SECONDS = 0.5
KEEPALIVE_SECONDS = 15.0

#: Set when the server shuts down: open event streams end at once instead of holding up
#: the daemon's stop.
CLOSING: web.AppKey[asyncio.Event] = web.AppKey("streams_closing", asyncio.Event)

#: The job actions of the page, and the daemon request each one is.
ACTIONS = ("print", "cancel", "requeue", "pause", "resume")


async def index(request: web.Request) -> web.FileResponse:
    return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})


async def state(request: web.Request) -> web.Response:
    return web.json_response(snapshot.snapshot(request.app[BACKEND]))


async def events(request: web.Request) -> web.StreamResponse:
    """``text/event-stream``: a ``state`` event with the whole snapshot at once, then one
    each time it changes (looked at every :data:`WATCH_SECONDS`)."""
    backend, closing = request.app[BACKEND], request.app[CLOSING]
    response = web.StreamResponse(headers={"Content-Type": "text/event-stream",
                                           "Cache-Control": "no-cache",
                                           "X-Accel-Buffering": "no"})
    await response.prepare(request)
    await response.write(b"retry: 2000\n\n")
    last, mark, quiet_since = None, None, time.monotonic()
    try:
        while not closing.is_set():
            # the whole snapshot only when a job or the printer changed, or to update the
            # ETA of a print (it changes with the clock)
            printers = backend.printers.status()
            now_mark = (backend.journal.change_mark(), printers)
            current = last
            if now_mark != mark or any(p.get("state") == "printing" for p in printers):
                mark = now_mark
                current = json.dumps(snapshot.snapshot(backend), separators=(",", ":"))
            if current != last:
                last, quiet_since = current, time.monotonic()
                await response.write(f"event: state\ndata: {current}\n\n".encode())
            elif time.monotonic() - quiet_since >= KEEPALIVE_SECONDS:
                quiet_since = time.monotonic()
                await response.write(b": keep-alive\n\n")
            try:
                await asyncio.wait_for(closing.wait(), WATCH_SECONDS)
            except TimeoutError:
                pass
    except (ConnectionResetError, asyncio.CancelledError):
        pass
    return response


async def _close_streams(app: web.Application) -> None:
    app[CLOSING].set()


def _job(request: web.Request):
    backend = request.app[BACKEND]
    try:
        job_id = int(request.match_info["job"])
    except ValueError:
        raise Refused(400, "the job id must be a number") from None
    job = backend.journal.get(job_id)
    if job is None:
        raise Refused(404, f"there is no job {job_id}")
    return backend, job


async def job_detail(request: web.Request) -> web.Response:
    backend, job = _job(request)
    return web.json_response(snapshot.job_detail(backend, job))


async def mesh(request: web.Request) -> web.Response:
    """The input or repaired mesh of a job, as binary triangles with a label per face
    (the layout is :func:`daemon.web.previews.mesh_bytes`)."""
    backend, job = _job(request)
    which = request.match_info["which"]
    if which not in ("input", "repaired"):
        raise Refused(404, "the mesh is 'input' or 'repaired'")
    loop = asyncio.get_running_loop()
    body = await loop.run_in_executor(None, previews.mesh_bytes, backend.cfg, job, which)
    return web.Response(body=body, content_type="application/octet-stream",
                        headers={"Cache-Control": "private, max-age=60"})


async def layers(request: web.Request) -> web.Response:
    """The G-code's layers: ``{"layers": [{"z", "paths": [[type, x0, y0, x1, y1, ...]]}]}``
    for the layers asked (``?from=&count=``), and the list of all layer heights."""
    backend, job = _job(request)
    try:
        first = int(request.query.get("from", "0"))
        count = int(request.query.get("count", "1"))
    except ValueError:
        raise Refused(400, "from and count must be numbers") from None
    loop = asyncio.get_running_loop()
    parsed = await loop.run_in_executor(None, previews.gcode_layers, job)
    return web.json_response(parsed.window(first, max(1, min(count, 50))))


async def action(request: web.Request) -> web.Response:
    """``POST /api/preflight/jobs/{job}/{action}``: the daemon's answer, as it gave it."""
    backend, job = _job(request)
    what = request.match_info["action"]
    if what not in ACTIONS:
        raise Refused(404, f"unknown action {what!r} (known: {', '.join(ACTIONS)})")
    ok, message = await control.ask_daemon(backend.journal, job.id, what)
    return web.json_response({"ok": ok, "message": message}, status=200 if ok else 409)


def add_routes(app: web.Application) -> None:
    app[CLOSING] = asyncio.Event()
    app.on_shutdown.append(_close_streams)
    app.router.add_get("/", index)
    app.router.add_static("/static/", STATIC, append_version=False)
    app.router.add_get("/api/preflight/state", state)
    app.router.add_get("/api/preflight/events", events)
    app.router.add_get("/api/preflight/jobs/{job}", job_detail)
    app.router.add_get("/api/preflight/jobs/{job}/mesh/{which}", mesh)
    app.router.add_get("/api/preflight/jobs/{job}/layers", layers)
    app.router.add_post("/api/preflight/jobs/{job}/{action}", action)
