"""The daemon's HTTP server: aiohttp on its own event loop in its own thread.

It starts and stops with ``preflight run``. Failing to listen (the port is taken) is
logged and shown in the status, never fatal: the spool keeps working.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from typing import Any

from aiohttp import web
from aiohttp.abc import AbstractAccessLogger

from daemon.config import split_listen
from daemon.web import moonraker, octoprint, page
from daemon.web.auth import key_middleware, load_or_create_key
from daemon.web.common import API_KEY, BACKEND, refusals, upload_expect
from daemon.web.discovery import Advertiser, advertise_in_background
from daemon.web.uploads import remove_stale_temps

log = logging.getLogger("preflight.web")


def make_app(backend: Any, api_key: str) -> web.Application:
    """The application: key check first, then refusals as JSON, then the routes."""
    app = web.Application(middlewares=[key_middleware(api_key), refusals])
    app[BACKEND] = backend
    app[API_KEY] = api_key
    octoprint.add_routes(app, upload_expect)
    moonraker.add_routes(app, upload_expect)
    page.add_routes(app)
    return app


class AccessLog(AbstractAccessLogger):
    """One line per request without the query string: the page's event stream carries
    the API key as ``?apikey=`` (EventSource cannot send headers)."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        self.logger.debug('%s "%s %s" %d %.3f s', request.remote, request.method,
                          request.path, response.status, time)


class WebServer:
    """Runs :func:`make_app` for ``backend`` (the daemon) on ``[web] listen``."""

    def __init__(self, backend: Any) -> None:
        self.backend = backend
        self.listen = backend.cfg.web.listen
        self.port: int | None = None
        self.error: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self.advertiser: Advertiser | None = None

    def start(self) -> None:
        """Start listening; returns once the socket is bound (or binding failed)."""
        gone = remove_stale_temps(self.backend.cfg.spool.path)
        if gone:
            log.info("removed %d partial upload(s) left by an earlier run", gone)
        key = load_or_create_key(self.backend.cfg.daemon.state_dir)
        self._thread = threading.Thread(target=self._run, args=(key,), name="web", daemon=True)
        self._thread.start()
        self._started.wait()

    def _run(self, key: str) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve(key))
        except Exception as e:  # the port is taken, the address is wrong...
            self.error = f"cannot listen on {self.listen}: {e}"
            log.error("web server: %s", self.error)
            self._started.set()
            return
        self.advertiser = advertise_in_background((split_listen(self.listen) or ("", 0))[0],
                                                  self.port or 0)
        self._started.set()
        loop.run_forever()
        loop.run_until_complete(self._shutdown())
        loop.close()

    async def _serve(self, key: str) -> None:
        host, port = split_listen(self.listen) or ("", 0)
        # one line per request only when debugging: Cura polls every two seconds
        access = log if log.isEnabledFor(logging.DEBUG) else None  # with the key redacted
        # a stalled upload must not hold up the daemon's shutdown for long
        self._runner = web.AppRunner(make_app(self.backend, key), access_log=access,
                                     access_log_class=AccessLog, handle_signals=False,
                                     shutdown_timeout=3.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, host, port, reuse_address=True)
        await site.start()
        sockets = getattr(site._server, "sockets", None) or []
        self.port = sockets[0].getsockname()[1] if sockets else port
        log.info("web API on http://%s:%d (OctoPrint- and Moonraker-compatible)", host,
                 self.port)

    async def _shutdown(self) -> None:
        if self._runner is not None:
            await self._runner.cleanup()

    def stop(self) -> None:
        if self.advertiser is not None:
            self.advertiser.close()
        if self._loop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=30)

    def status(self) -> dict[str, Any]:
        host = (split_listen(self.listen) or ("", 0))[0]
        shown = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
        adv = self.advertiser
        mdns = None if adv is None else {"name": adv.name, "addresses": adv.addresses,
                                         "registered": adv.registered, "error": adv.error}
        return {"listen": self.listen, "port": self.port, "error": self.error,
                "url": f"http://{shown}:{self.port}" if self.port else None, "mdns": mdns}
