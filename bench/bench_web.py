"""Web API benchmark: upload throughput and memory, and upload-to-first-line latency.

Runs the real daemon (``preflight run``) with its web API on a free loopback port,
against a virtual printer served on a pty by this process, and prints:

- the idle daemon's resident memory with the web API off, for comparison (importing
  asyncio and aiohttp is most of the difference);
- the throughput of a 200 MB G-code upload (``POST /api/files/local``, print=false)
  over loopback, with the daemon's resident memory (VmRSS sampled every 10 ms) at idle
  and at its peak while the body streams to disk;
- how long the G-code check that follows takes, and the daemon's peak memory then;
- the time from the ``201 Created`` of a 20 mm cube STL uploaded with print=true to
  its first G-code line at the printer (repair and slicing included);
- the status page's initial load (bytes, time), the SSE latency (201 to the event
  showing the job) and the layer preview's G-code reading rate (``bench_web_page.py``).

Usage: .venv/bin/python bench/bench_web.py [--mb 200] [--speedup X]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench_daemon import QUERY, ROOT, box, config, rss_kb
from bench_web_page import bench_initial_load, bench_layers, bench_sse

from daemon.config import load_config
from daemon.journal import Journal
from daemon.web.auth import read_key
from printer.virtual import VirtualPrinter
from repair.io import write_stl


class WebRun:
    """The daemon with ``[web] listen = "127.0.0.1:0"`` (or ``listen``) and a virtual printer."""

    def __init__(self, speedup: float, listen: str = "127.0.0.1:0") -> None:
        self.root = Path(tempfile.mkdtemp(prefix="preflight-bench-web-"))
        self.vp = VirtualPrinter(speedup=speedup, baud=250000, link=self.root / "tty")
        self.vp.start()
        self.cfg_path = config(self.root, str(self.root / "tty"), auto_print=False,
                               listen=listen)
        self.cfg = load_config(self.cfg_path)
        self.log = open(self.root / "daemon.log", "ab")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "daemon", "run", "--config", str(self.cfg_path)],
            stdout=self.log, stderr=self.log, cwd=ROOT)
        self.j: Journal | None = None
        while True:
            if self.proc.poll() is not None:
                raise SystemExit(f"daemon died: {(self.root / 'daemon.log').read_text()}")
            if self.cfg.journal_path.exists():
                self.j = self.j or Journal(self.cfg.journal_path, readonly=True)
                st = self.j.get_meta("status") or {}
                if (st.get("printer") or {}).get("state") == "connected" and (
                        not listen or (st.get("web") or {}).get("port")):
                    self.port = int((st.get("web") or {}).get("port") or 0)
                    break
            time.sleep(0.05)
        self.key = read_key(self.cfg.daemon.state_dir) or ""

    def job_lines(self) -> int:
        return sum(1 for c in self.vp.executed if c.split()[0] not in QUERY)

    def upload(self, path: Path, name: str, *, print_: bool) -> tuple[int, dict, float]:
        """Stream ``path`` as PrusaSlicer does; returns (status, JSON, seconds)."""
        boundary = "-" * 24 + secrets.token_hex(8)
        head = (f'--{boundary}\r\nContent-Disposition: form-data; name="print"\r\n\r\n'
                f'{"true" if print_ else "false"}\r\n--{boundary}\r\nContent-Disposition: '
                f'form-data; name="path"\r\n\r\n\r\n--{boundary}\r\nContent-Disposition: '
                f'form-data; name="file"; filename="{name}"\r\nContent-Type: '
                f'application/octet-stream\r\n\r\n').encode()
        tail = f"\r\n--{boundary}--\r\n".encode()
        size = len(head) + path.stat().st_size + len(tail)
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=600)
        t0 = time.monotonic()
        conn.putrequest("POST", "/api/files/local")
        for k, v in (("X-Api-Key", self.key), ("Content-Length", str(size)),
                     ("Content-Type", f"multipart/form-data; boundary={boundary}")):
            conn.putheader(k, v)
        conn.endheaders()
        conn.send(head)
        with open(path, "rb") as fh:
            while chunk := fh.read(1 << 20):
                conn.send(chunk)
        conn.send(tail)
        resp = conn.getresponse()
        body = json.loads(resp.read() or b"{}")
        dt = time.monotonic() - t0
        conn.close()
        return resp.status, body, dt

    def close(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(timeout=120)
        self.vp.stop()
        self.log.close()
        shutil.rmtree(self.root, ignore_errors=True)


class RssSampler(threading.Thread):
    """The daemon's peak VmRSS, sampled every 10 ms until stopped."""

    def __init__(self, pid: int) -> None:
        super().__init__(daemon=True)
        self.pid = pid
        self.peak_kb = 0
        self.halt = threading.Event()

    def run(self) -> None:
        while not self.halt.is_set():
            self.peak_kb = max(self.peak_kb, rss_kb(self.pid)[0])
            time.sleep(0.01)


def write_gcode(path: Path, megabytes: float) -> int:
    """A G-code file of about ``megabytes`` MB (10^6 bytes): moves zig-zagging on a bed."""
    lines = [f"G1 X{20 + (i % 200) * 0.5:.3f} Y{20 + (i // 200) * 0.5:.3f} E0.04210 F1800\n"
             for i in range(40000)]
    block = ("G28\nG90\nM83\n" + "".join(lines)).encode()
    target = int(megabytes * 1e6)
    with open(path, "wb") as fh:
        written = 0
        while written < target:
            piece = block[: target - written]
            fh.write(piece)
            written += len(piece)
    return written


def bench_upload(r: WebRun, megabytes: float) -> None:
    g = r.root / "big.gcode"
    size = write_gcode(g, megabytes)
    time.sleep(1.0)
    idle = rss_kb(r.proc.pid)[0]
    sampler = RssSampler(r.proc.pid)
    sampler.start()
    status, body, dt = r.upload(g, "big.gcode", print_=False)
    sampler.halt.set()
    sampler.join()
    g.unlink()
    assert status == 201, (status, body)
    print(f"upload of a {size / 1e6:.0f} MB G-code file over loopback: {dt:.2f} s, "
          f"{size / 1e6 / dt:.0f} MB/s (201 Created, job {body['preflight']['job']})")
    print(f"daemon memory: idle RSS {idle / 1024:.1f} MB, peak during the upload "
          f"{sampler.peak_kb / 1024:.1f} MB (+{(sampler.peak_kb - idle) / 1024:.1f} MB)")
    job_id = body["preflight"]["job"]
    t0 = time.monotonic()
    while str(r.j.get(job_id).state) not in ("ready", "failed"):
        time.sleep(0.1)
    print(f"then the G-code check (the spool's pipeline, after the 201): "
          f"{time.monotonic() - t0:.1f} s to {r.j.get(job_id).state}, daemon peak RSS "
          f"{rss_kb(r.proc.pid)[1] / 1024:.1f} MB")


def bench_latency(r: WebRun) -> None:
    v, f = box((20.0, 20.0, 20.0))
    stl = r.root / "cube20.stl"
    write_stl(stl, v, f)
    base = r.job_lines()
    status, body, _ = r.upload(stl, "cube20.stl", print_=True)
    t0 = time.monotonic()
    assert status == 201, (status, body)
    while r.job_lines() == base:
        time.sleep(0.001)
    print(f"latency, 20 mm cube STL: 201 Created -> first line at the printer: "
          f"{time.monotonic() - t0:.2f} s (repair and slicing included)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=200.0, help="size of the G-code upload (MB)")
    ap.add_argument("--speedup", type=float, default=1000.0, help="virtual printer speed-up")
    args = ap.parse_args()
    print(f"preflight web API benchmark ({os.cpu_count()} cores)")
    r = WebRun(args.speedup, listen="")
    time.sleep(1.0)
    print(f"idle daemon without the web API ([web] listen = \"\"): RSS "
          f"{rss_kb(r.proc.pid)[0] / 1024:.1f} MB")
    r.close()
    r = WebRun(args.speedup)
    try:
        bench_upload(r, args.mb)
        r.close()
        r = WebRun(args.speedup)  # a fresh daemon: no 200 MB G-code check running
        bench_latency(r)
        bench_initial_load(r.port, r.key)
        bench_sse(r)
        gcode = r.root / "layers.gcode"
        write_gcode(gcode, 5.0)
        bench_layers(gcode)
    finally:
        r.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
