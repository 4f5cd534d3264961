"""Shared pieces of the web server: the app key for the daemon, JSON bodies, the
printer's state in OctoPrint's flags, and the error and expect handlers."""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from aiohttp import web

from daemon.web.auth import UNAUTHORISED, key_ok
from daemon.web.uploads import Refused, check_declared_size, size_limit

log = logging.getLogger("preflight.web")

#: The daemon (cfg, journal, spool, printer) the handlers act on.
BACKEND: web.AppKey[Any] = web.AppKey("backend", object)
API_KEY: web.AppKey[str] = web.AppKey("api_key", str)

MAX_JSON_BYTES = 64 * 1024


def refusal(status: int, reason: str) -> web.Response:
    return web.json_response({"error": reason}, status=status)


async def json_body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object; 400 if it is not one."""
    if request.content_length is not None and request.content_length > MAX_JSON_BYTES:
        raise Refused(413, "the JSON body is too large")
    raw = await request.content.read(MAX_JSON_BYTES + 1)
    if len(raw) > MAX_JSON_BYTES:
        raise Refused(413, "the JSON body is too large")
    if not raw.strip():
        return {}
    try:
        body = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        raise Refused(400, "the body is not valid JSON") from None
    if not isinstance(body, dict):
        raise Refused(400, "the JSON body must be an object")
    return body


@web.middleware
async def refusals(request: web.Request,
                   handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
                   ) -> web.StreamResponse:
    """Turn :class:`Refused` into a JSON answer; log anything unexpected as a 500 so a
    hostile request costs one answer, never the daemon."""
    try:
        return await handler(request)
    except Refused as e:
        log.info("%s %s -> %d: %s", request.method, request.path, e.status, e.reason)
        return refusal(e.status, e.reason)
    except web.HTTPException:
        raise
    except (ConnectionResetError, OSError) as e:
        log.info("%s %s: connection lost: %s", request.method, request.path, e)
        raise
    except Exception as e:
        log.exception("%s %s", request.method, request.path)
        return refusal(500, f"internal error: {type(e).__name__}")


async def upload_expect(request: web.Request) -> web.StreamResponse | None:
    """``Expect: 100-continue``: check the key and the declared size before the client
    sends the body, and answer 100 Continue only if both pass."""
    if request.version < (1, 1) or request.headers.get("Expect", "").lower() != "100-continue":
        if request.headers.get("Expect"):
            return refusal(417, "only Expect: 100-continue is understood")
        return None
    if not key_ok(request, request.app[API_KEY]):
        return refusal(401, UNAUTHORISED)
    backend = request.app[BACKEND]
    try:
        check_declared_size(request, size_limit(backend.cfg), backend.cfg.spool.path)
    except Refused as e:
        return refusal(e.status, e.reason)
    await request.writer.write(b"HTTP/1.1 100 Continue\r\n\r\n")
    return None


TEMPERATURE_NAMES = {"T": "tool0", "T0": "tool0", "T1": "tool1", "B": "bed", "C": "chamber"}


def temperatures(raw: Any) -> dict[str, dict[str, Any]]:
    """Temperatures as ``{"tool0": {"actual", "target"}}`` from the printer's
    ``{"T": [actual, target]}`` (M105's letters) or from that shape already."""
    out: dict[str, dict[str, Any]] = {}
    for key, reading in (raw.items() if isinstance(raw, dict) else ()):
        name = TEMPERATURE_NAMES.get(str(key), str(key))
        if isinstance(reading, dict):
            out[name] = {"actual": reading.get("actual"), "target": reading.get("target")}
        elif isinstance(reading, (list, tuple)) and reading:
            out[name] = {"actual": reading[0],
                         "target": reading[1] if len(reading) > 1 else None}
    return out


def _temperature(info: dict[str, Any]) -> dict[str, Any]:
    known = set(TEMPERATURE_NAMES.values())
    return {name: {**t, "offset": 0}
            for name, t in temperatures(info.get("temperatures")).items() if name in known}


def printer_state(backend: Any) -> dict[str, Any]:
    """The printer link's state as OctoPrint's flags (temperatures as of the connection:
    the link does not poll them during a print)."""
    st = backend.printer.status() or {}
    link = st.get("state")
    printing = link == "printing"
    paused = link == "paused"
    operational = link in ("connected", "printing", "paused")
    text = "Printing" if printing else "Paused" if paused else (
        "Operational" if operational else "Offline" if link != "connecting" else "Connecting")
    return {"text": text, "operational": operational,
            "ready": operational and not printing and not paused,
            "printing": printing, "paused": paused, "pausing": False, "cancelling": False,
            "error": False, "closedOrError": not operational, "message": st.get("message"),
            "temperature": _temperature(st.get("info") or {}), "info": st.get("info") or {}}
