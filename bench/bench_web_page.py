"""Status page figures, run by bench_web.py against its daemon: the page's initial load
(size and time of what the browser fetches before any data), the SSE latency (an upload's
201 to the event that shows the job), and the layer preview's G-code reading rate."""

from __future__ import annotations

import http.client
import random
import re
import socket
import statistics
import time
from pathlib import Path
from typing import Any

#: What index.html loads at once (three.js is loaded only when a 3D view opens).
FIRST_LOAD_MODULES = ("/static/app.js", "/static/report.js", "/static/layers.js")
THREE = ("/static/vendor/three/three.module.js", "/static/vendor/three/three.core.js",
         "/static/vendor/three/addons/OrbitControls.js", "/static/viewer.js")


def _get(port: int, path: str, key: str | None = None, *, gzip: bool = False) -> bytes:
    """The body as sent (still compressed when ``gzip`` and the server compressed it)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    headers = {"X-Api-Key": key} if key else {}
    if gzip:
        headers["Accept-Encoding"] = "gzip"
    conn.request("GET", path, headers=headers)
    body = conn.getresponse().read()
    conn.close()
    return body


def bench_initial_load(port: int, key: str) -> None:
    t0 = time.monotonic()
    page = _get(port, "/")
    assets = re.findall(rb'(?:href|src)="(/static/[^"]+)"', page)
    size = len(page) + sum(len(_get(port, a.decode())) for a in assets)
    size += sum(len(_get(port, m)) for m in FIRST_LOAD_MODULES)
    size += len(_get(port, "/api/preflight/state", key))
    dt = time.monotonic() - t0
    three = sum(len(_get(port, m)) for m in THREE)
    sent = sum(len(_get(port, m, gzip=True)) for m in THREE)
    print(f"status page initial load (HTML, CSS, modules, first state): {size / 1024:.0f} KB "
          f"in {dt * 1000:.0f} ms over loopback; the 3D view adds {three / 1024:.0f} KB "
          f"({sent / 1024:.0f} KB sent gzipped; three.js, loaded when a report is opened)")


class _Events:
    def __init__(self, port: int, key: str) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=60)
        self.sock.sendall(f"GET /api/preflight/events?apikey={key} HTTP/1.1\r\nHost: x\r\n"
                          "\r\n".encode())
        self.buf = b""

    def wait_for(self, needle: bytes) -> float:
        while needle not in self.buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("the event stream closed")
            self.buf += chunk
        self.buf = b""
        return time.monotonic()


def bench_sse(run: Any, tries: int = 9) -> None:
    """``run``: bench_web.WebRun. Upload small G-code files (print=false) and time the
    201 to the event listing them."""
    events = _Events(run.port, run.key)
    events.wait_for(b"event: state")
    delays = []
    for i in range(tries):
        time.sleep(random.uniform(0.0, 0.5))  # not in step with the stream's looks
        path = run.root / f"sse{i}.gcode"
        path.write_text("G28\nG1 X10 Y10 E1 F1200\n")
        status, body, _ = run.upload(path, path.name, print_=False)
        t0 = time.monotonic()
        assert status == 201, (status, body)
        delays.append(events.wait_for(f'"name":"{path.name}"'.encode()) - t0)
    events.sock.close()
    print(f"SSE: upload's 201 -> the event showing the job: median "
          f"{statistics.median(delays) * 1000:.0f} ms, max {max(delays) * 1000:.0f} ms "
          f"({tries} uploads; the stream looks at the journal every 0.5 s)")


def bench_layers(gcode: Path) -> None:
    from daemon.web.toolpath import read_layers

    lines = sum(1 for _ in open(gcode, encoding="utf-8"))
    t0 = time.perf_counter()
    with open(gcode, encoding="utf-8") as f:
        layers = read_layers(f)
    dt = time.perf_counter() - t0
    print(f"layer preview: {lines} G-code lines read with printer.gcode.lex in {dt:.2f} s "
          f"({lines / dt / 1000:.0f} k lines/s, {len(layers.z)} layers)")
