"""The OctoPrint-compatible endpoints PrusaSlicer, OrcaSlicer, SuperSlicer and Cura's
OctoPrint Connection plugin call, in the shapes OctoPrint answers with."""

from __future__ import annotations

from typing import Any
from urllib.parse import quote

from aiohttp import web

from daemon import __version__
from daemon.web import control
from daemon.web.common import BACKEND, json_body, printer_state
from daemon.web.uploads import Refused, accept
from printer.gcode import lex

OCTOPRINT_VERSION = "1.10.0"


async def version(request: web.Request) -> web.Response:
    # PrusaSlicer accepts a host only when "text" starts with "OctoPrint" and "api" is present
    return web.json_response({"api": "0.1", "server": OCTOPRINT_VERSION,
                              "text": f"OctoPrint {OCTOPRINT_VERSION} (preflight {__version__})"})


async def login(request: web.Request) -> web.Response:
    return web.json_response({"name": "preflight", "active": True, "admin": True,
                              "user": True, "groups": ["admins", "users"], "permissions": [],
                              "needs": {"role": ["admin", "user"]}, "session": None})


async def settings(request: web.Request) -> web.Response:
    return web.json_response({
        "api": {"enabled": True, "allowCrossOrigin": False},
        "appearance": {"name": "preflight"},
        "feature": {"sdSupport": False, "keyboardControl": False},
        "folder": {"uploads": "local"},
        "plugins": {},
        "webcam": {"webcamEnabled": False, "streamUrl": "", "snapshotUrl": ""},
    })


def _profile(backend: Any) -> dict[str, Any]:
    info = (backend.printer.status() or {}).get("info") or backend.printer.last_info() or {}
    bv = info.get("build_volume") or [None, None, None]
    return {"id": "_default", "name": "preflight", "model": info.get("machine_type")
            or info.get("firmware") or "preflight", "current": True, "default": True,
            "heatedBed": True, "heatedChamber": False, "color": "default",
            "volume": {"width": bv[0], "depth": bv[1], "height": bv[2], "formFactor":
                       "rectangular", "origin": "lowerleft", "custom_box": False},
            "extruder": {"count": 1, "nozzleDiameter": info.get("nozzle_diameter")
                         or backend.cfg.printer.nozzle_diameter, "sharedNozzle": False,
                         "offsets": [[0.0, 0.0]]},
            "axes": {a: {"inverted": False, "speed": 6000 if a != "z" else 200}
                     for a in ("x", "y", "z", "e")}}


async def printer_profiles(request: web.Request) -> web.Response:
    return web.json_response({"profiles": {"_default": _profile(request.app[BACKEND])}})


async def printer(request: web.Request) -> web.Response:
    state = printer_state(request.app[BACKEND])
    if not state["operational"]:
        raise Refused(409, f"Printer is not operational: {state['message'] or state['text']}")
    flags = {k: state[k] for k in ("operational", "ready", "printing", "paused", "pausing",
                                   "cancelling", "error", "closedOrError")}
    flags.update(sdReady=False, finishing=False, resuming=False)
    return web.json_response({"state": {"text": state["text"], "flags": flags, "error": ""},
                              "temperature": state["temperature"],
                              "sd": {"ready": False}})


async def job(request: web.Request) -> web.Response:
    backend = request.app[BACKEND]
    current = control.current_job(backend.journal)
    summary = control.job_summary(backend.journal, current)
    state = printer_state(backend)
    printing = summary["state"] in ("printing", "paused")
    progress = summary["progress"] if printing else None
    return web.json_response({
        "job": {"file": {"name": summary["name"], "path": summary["name"],
                         "display": summary["name"], "origin": "local" if current else None,
                         "size": None, "date": int(current.created) if current else None},
                "estimatedPrintTime": None, "averagePrintTime": None, "lastPrintTime": None,
                "filament": None, "user": "preflight" if current else None},
        "progress": {"completion": 100.0 * progress if progress is not None else None,
                     "filepos": None, "printTime": _secs(summary["elapsed"]),
                     "printTimeLeft": _secs(summary["left"]),
                     "printTimeLeftOrigin": "linear" if summary["left"] is not None else None},
        "state": state["text"],
        "preflight": {"job": summary.get("id"), "state": summary["state"]},
    })


def _secs(value: float | None) -> int | None:
    return None if value is None else int(round(value))


async def job_command(request: web.Request) -> web.Response:
    body = await json_body(request)
    action = body.get("action")
    await control.job_command(request.app[BACKEND].journal, str(body.get("command", "")),
                              str(action) if action is not None else None)
    return web.Response(status=204)


async def printer_command(request: web.Request) -> web.Response:
    """``POST /api/printer/command``: only the emergency stop (M112) of the print on the
    printer; other G-code is not sent behind the journal's back."""
    body = await json_body(request)
    commands = body.get("commands") or [body.get("command")]
    if not isinstance(commands, list) or not commands:
        raise Refused(400, "commands must be a list of G-code lines")
    words = {lex(str(c or "")).word for c in commands}
    if words != {"M112"}:
        raise Refused(409, "only M112 (emergency stop) is accepted here: preflight sends the "
                           "printer nothing but its jobs' G-code")
    await control.control_print(request.app[BACKEND].journal, "stop")
    return web.Response(status=204)


async def upload(request: web.Request) -> web.Response:
    backend = request.app[BACKEND]
    up, taken, name = await accept(request, backend, "print")
    base = f"{request.scheme}://{request.host}"
    resource = f"{base}/api/files/local/{quote(name)}"
    effective_print = up.flag("print")
    return web.json_response({
        "done": True,
        "files": {"local": {"name": name, "path": name, "display": name, "origin": "local",
                            "refs": {"resource": resource,
                                     "download": f"{base}/downloads/files/local/{quote(name)}"}}},
        "effectivePrint": effective_print,
        "effectiveSelect": up.flag("select") or effective_print,
        "preflight": taken,
    }, status=201, headers={"Location": resource})


async def file_command(request: web.Request) -> web.Response:
    """``POST /api/files/local/<path>`` with ``{"command": "select", "print": true}``."""
    backend = request.app[BACKEND]
    body = await json_body(request)
    if body.get("command") != "select":
        raise Refused(400, f"unknown file command {body.get('command')!r} (known: select)")
    found = control.job_by_name(backend.journal, request.match_info["path"])
    if found is None:
        raise Refused(404, f"no uploaded file named {request.match_info['path']!r}")
    if body.get("print") in (True, "true"):
        await control.start_printing(backend.journal, found)
    return web.Response(status=204)


async def file_info(request: web.Request) -> web.Response:
    backend = request.app[BACKEND]
    found = control.job_by_name(backend.journal, request.match_info["path"])
    if found is None:
        raise Refused(404, f"no uploaded file named {request.match_info['path']!r}")
    return web.json_response({"name": found.name, "path": found.name, "display": found.name,
                              "origin": "local", "type": "machinecode" if found.kind == "gcode"
                              else "model", "date": int(found.created),
                              "preflight": {"job": found.id, "state": str(found.state)}})


def add_routes(app: web.Application, upload_expect: Any) -> None:
    app.router.add_get("/api/version", version)
    app.router.add_post("/api/login", login)
    app.router.add_get("/api/settings", settings)
    app.router.add_get("/api/printerprofiles", printer_profiles)
    app.router.add_get("/api/printer", printer)
    app.router.add_post("/api/printer/command", printer_command)
    app.router.add_get("/api/job", job)
    app.router.add_post("/api/job", job_command)
    app.router.add_route("POST", "/api/files/local", upload, expect_handler=upload_expect)
    app.router.add_post("/api/files/local/{path:.+}", file_command)
    app.router.add_get("/api/files/local/{path:.+}", file_info)
