"""The Moonraker-compatible endpoints of the "Klipper (via Moonraker)" host type of
PrusaSlicer and OrcaSlicer. Moonraker wraps every HTTP answer in ``{"result": ...}``."""

from __future__ import annotations

from aiohttp import web

from daemon import __version__
from daemon.web import control
from daemon.web.common import BACKEND, json_body, printer_state
from daemon.web.uploads import Refused, accept

MOONRAKER_VERSION = f"v0.9.3-preflight-{__version__}"


async def server_info(request: web.Request) -> web.Response:
    # preflight queues uploads whatever the printer link is doing: always "ready"
    return web.json_response({"result": {
        "klippy_connected": True, "klippy_state": "ready", "components": ["file_manager"],
        "failed_components": [], "registered_directories": ["gcodes"], "warnings": [],
        "websocket_count": 0, "moonraker_version": MOONRAKER_VERSION,
        "api_version": [1, 5, 0], "api_version_string": "1.5.0"}})


async def upload(request: web.Request) -> web.Response:
    backend = request.app[BACKEND]
    up, taken, name = await accept(request, backend, "print", check_fields=_gcodes_root)
    print_requested = up.flag("print")
    return web.json_response({"result": {
        "item": {"path": name, "root": "gcodes"}, "print_started": print_requested,
        "print_queued": False, "action": "create_file", "preflight": taken}},
        status=201)


def _gcodes_root(fields: dict[str, str]) -> None:
    root = fields.get("root") or "gcodes"
    if root != "gcodes":
        raise Refused(400, f"root {root!r} is not writable (uploads go to gcodes)")


async def print_start(request: web.Request) -> web.Response:
    """``POST /printer/print/start?filename=...`` (or a JSON body): idempotent."""
    backend = request.app[BACKEND]
    filename = request.query.get("filename")
    if filename is None:
        filename = str((await json_body(request)).get("filename") or "")
    if not filename:
        raise Refused(400, "filename is required")
    found = control.job_by_name(backend.journal, filename)
    if found is None:
        raise Refused(404, f"no uploaded file named {filename!r}")
    await control.start_printing(backend.journal, found)
    return web.json_response({"result": "ok"})


def _print_control(action: str):
    async def handler(request: web.Request) -> web.Response:
        """``POST /printer/print/pause|resume|cancel``."""
        await control.control_print(request.app[BACKEND].journal, action)
        return web.json_response({"result": "ok"})
    return handler


async def printer_info(request: web.Request) -> web.Response:
    state = printer_state(request.app[BACKEND])
    info = state["info"]
    return web.json_response({"result": {
        "state": "ready" if state["operational"] else "startup",
        "state_message": state["message"] or state["text"], "hostname": "preflight",
        "software_version": info.get("firmware") or "unknown"}})


def add_routes(app: web.Application, upload_expect: object) -> None:
    app.router.add_get("/server/info", server_info)
    app.router.add_get("/printer/info", printer_info)
    app.router.add_route("POST", "/server/files/upload", upload, expect_handler=upload_expect)
    app.router.add_post("/printer/print/start", print_start)
    for action in ("pause", "resume", "cancel"):
        app.router.add_post(f"/printer/print/{action}", _print_control(action))
