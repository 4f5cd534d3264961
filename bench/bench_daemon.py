"""Daemon benchmark: drop-to-first-line latency, idle memory, jobs per minute.

Runs the real daemon (``preflight run``) as a subprocess against a virtual printer
served on a pty by this process (so the daemon's own memory is measured alone),
and prints:

- the start-up of a task child: from the daemon asking for it to the child's first
  progress line (a warm fork server; the fork server's own start once, separately);
- the latency from dropping a 20 mm cube into the spool to its first G-code line
  reaching the printer, split into detection, repair, slicing and stream start;
- the idle daemon's resident memory (RSS, and its peak);
- jobs per minute for a batch of small models (5-10 mm boxes, one in three
  broken), end to end (printed), and repair+slice only (auto_print off);
- fsyncs per minute while the daemon prints (SD-card wear): the daemon runs under
  ``strace -f -e trace=fsync,fdatasync`` (every thread, SQLite's own syncs included),
  and the calls between the job's printing and done transitions are counted.

Usage: .venv/bin/python bench/bench_daemon.py [--batch N] [--speedup X]
       .venv/bin/python bench/bench_daemon.py --only-fsyncs [--fsync-tree DIR ...]
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "daemon"))

from daemon_helpers import box  # noqa: E402

from daemon.config import load_config  # noqa: E402
from daemon.journal import Journal  # noqa: E402
from daemon.worker import FORK_SERVER, run_task  # noqa: E402
from printer.virtual import VirtualPrinter  # noqa: E402
from repair.io import write_stl  # noqa: E402

QUERY = {"M110", "M115", "M105", "M211", "M200", "M862.1", "M208", "M155"}


def broken_box(size):
    """A box turned inside out with one face duplicated: a typical broken export."""
    v, f = box(size)
    f = f[:, ::-1].copy()
    return v, np.vstack([f, f[:1]])


def config(root: Path, port: str, *, auto_print: bool, listen: str = "") -> Path:
    """A daemon config in ``root``; the web API is off unless ``listen`` is given."""
    p = root / "preflight.toml"
    p.write_text(tomli_w.dumps({
        "spool": {"path": str(root / "spool"), "settle_seconds": 1.0,
                  "close_grace_seconds": 0.05},
        "printer": {"port": port, "baud": 250000, "reconnect_min_seconds": 0.2,
                    "reconnect_max_seconds": 1.0},
        "daemon": {"state_dir": str(root / "state"), "auto_print": auto_print,
                   "log_level": "WARNING"},
        "web": {"listen": listen},
    }))
    return p


def rss_kb(pid: int) -> tuple[int, int]:
    st = Path(f"/proc/{pid}/status").read_text()
    get = {k.strip(): v for k, v in (line.split(":", 1) for line in st.splitlines())}
    return int(get["VmRSS"].split()[0]), int(get["VmHWM"].split()[0])


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def drop(spool: Path, name: str, v, f) -> float:
    part = spool / (name + ".part")
    write_stl(part, v, f)
    t = time.monotonic()
    os.rename(part, spool / name)
    return t


class Run:
    def __init__(self, auto_print: bool, speedup: float, *, prefix: tuple[str, ...] = (),
                 tree: Path = ROOT) -> None:
        self.root = Path(tempfile.mkdtemp(prefix="preflight-bench-"))
        self.prefix = prefix
        self.vp = VirtualPrinter(speedup=speedup, baud=250000, link=self.root / "tty")
        self.vp.start()
        self.cfg_path = config(self.root, str(self.root / "tty"), auto_print=auto_print)
        self.cfg = load_config(self.cfg_path)
        self.log = open(self.root / "daemon.log", "ab")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [*prefix, sys.executable, "-m", "daemon", "run", "--config", str(self.cfg_path)],
            stdout=self.log, stderr=self.log, cwd=tree)
        self.journal: Journal | None = None
        while True:
            if self.proc.poll() is not None:
                raise SystemExit(f"daemon died: {(self.root / 'daemon.log').read_text()}")
            if self.cfg.journal_path.exists():
                self.journal = self.journal or Journal(self.cfg.journal_path, readonly=True)
                st = self.journal.get_meta("status") or {}
                if (st.get("printer") or {}).get("state") == "connected":
                    break
            time.sleep(0.05)

    def job_lines(self) -> int:
        return sum(1 for c in self.vp.executed if c.split()[0] not in QUERY)

    def close(self) -> None:
        # Under strace, stop the daemon itself (strace exits when it does).
        for pid in child_pids(self.proc.pid) if self.prefix else [self.proc.pid]:
            os.kill(pid, signal.SIGTERM)
        self.proc.wait(timeout=60)
        self.vp.stop()
        self.log.close()
        shutil.rmtree(self.root, ignore_errors=True)


def bench_latency(speedup: float) -> None:
    r = Run(auto_print=True, speedup=speedup)
    try:
        time.sleep(2.0)
        rss, hwm = rss_kb(r.proc.pid)
        server = sum(rss_kb(c)[0] for c in child_pids(r.proc.pid))
        print(f"idle daemon memory: RSS {rss / 1024:.1f} MB (peak {hwm / 1024:.1f} MB), "
              f"printer connected, nothing to do; its fork server: RSS {server / 1024:.1f} MB")
        c0, w0 = cpu_seconds(r.proc.pid), time.monotonic()
        time.sleep(5.0)
        cpu = (cpu_seconds(r.proc.pid) - c0) / (time.monotonic() - w0)
        print(f"idle daemon CPU: {100 * cpu:.2f}% of one core")
        v, f = box((20.0, 20.0, 20.0))
        base = r.job_lines()
        t0 = drop(r.cfg.spool.path, "cube20.stl", v, f)
        wall0 = time.time()
        while r.job_lines() == base:
            time.sleep(0.001)
        t1 = time.monotonic()
        hist = r.journal.history(1)
        at = {h["to_state"]: h["at"] - wall0 for h in hist}
        print(f"latency, 20 mm cube dropped -> first line at the printer: {t1 - t0:.2f} s "
              f"(taken {at.get('queued', 0):.2f} s, repaired by {at.get('slicing', 0):.2f} s, "
              f"sliced by {at.get('ready', 0):.2f} s, printing from {at.get('printing', 0):.2f} s)")
        rss, hwm = rss_kb(r.proc.pid)
        print(f"daemon memory after one job: RSS {rss / 1024:.1f} MB (peak {hwm / 1024:.1f} MB)")
    finally:
        r.close()


def _first_line_seconds(root: Path, i: int) -> float:
    """Seconds from run_task's call to the child's first progress line."""
    first: list[float] = []
    t0 = time.monotonic()
    run_task("repair", {"in": str(root / "cube.stl"), "out": str(root / f"{i}.stl"),
                        "epsilon": 0.4}, work_dir=root / f"w{i}", timeout=120, memory_mb=2048,
             progress=lambda stage, fraction: first or first.append(time.monotonic()))
    return first[0] - t0


def child_pids(pid: int) -> list[int]:
    """The processes ``pid`` started (from any of its threads)."""
    return [int(c) for t in Path(f"/proc/{pid}/task").iterdir()
            for c in (t / "children").read_text().split()]


def bench_child_startup(runs: int) -> None:
    """From asking for a task child to its first progress line, on a 10 mm cube."""
    root = Path(tempfile.mkdtemp(prefix="preflight-bench-"))
    try:
        v, f = box((10.0, 10.0, 10.0))
        write_stl(root / "cube.stl", v, f)
        t0 = time.monotonic()
        FORK_SERVER.ensure_started()
        server_start = time.monotonic() - t0
        times = [_first_line_seconds(root, i) for i in range(runs)]
        rss, _ = rss_kb(FORK_SERVER.pid)
        print(f"child start-up per task (request -> the task's first line): median "
              f"{1000 * float(np.median(times)):.0f} ms, max {1000 * max(times):.0f} ms "
              f"over {runs} tasks (fork server: started once in {server_start:.2f} s, "
              f"RSS {rss / 1024:.0f} MB)")
    finally:
        FORK_SERVER.shutdown()
        shutil.rmtree(root, ignore_errors=True)


def bench_batch(n: int, auto_print: bool, speedup: float) -> None:
    r = Run(auto_print=auto_print, speedup=speedup)
    try:
        rng = np.random.default_rng(1)
        t0 = None
        for i in range(n):
            size = tuple(rng.uniform(5, 10, 3))
            v, f = broken_box(size) if i % 3 == 0 else box(size)
            t = drop(r.cfg.spool.path, f"part{i:03d}.stl", v, f)
            t0 = t0 if t0 is not None else t
        final = ("done", "failed") if auto_print else ("ready", "failed")
        while True:
            jobs = r.journal.jobs()
            if len(jobs) == n and all(str(j.state) in final for j in jobs):
                break
            time.sleep(0.05)
        dt = time.monotonic() - t0
        ok = sum(1 for j in jobs if str(j.state) != "failed")
        what = "repaired, sliced and printed" if auto_print else "repaired and sliced"
        print(f"batch of {n} small models {what}: {dt:.1f} s, {60 * n / dt:.1f} jobs/min "
              f"({ok} ok, {n - ok} failed)")
    finally:
        r.close()


def print_gcode(seconds: float) -> str:
    """A print of about ``seconds`` of real time at speed-up 1: a short bed heat-up (to
    40 °C, ~13 s) and 100 mm/s moves of 10 mm."""
    lines = ["M190 S40", "G28", "G90", "M83", "G1 Z0.3 F6000"]
    for i in range(int(max(seconds - 15.0, 10.0) * 10)):
        lines.append(f"G1 X{20 + 10 * (i % 2)} Y{20 + (i // 2) % 2 * 0.1:.1f} E0.3 F6000")
    return "\n".join([*lines, "M140 S0", "M84"]) + "\n"


def bench_fsyncs(seconds: float, tree: Path) -> None:
    """fsync + fdatasync calls of the daemon (all its threads and children) per minute
    while it prints, counted by strace between the job's printing and done transitions."""
    if not shutil.which("strace"):
        print("fsyncs during a print: strace not installed (apt-get install strace); skipped")
        return
    trace = Path(tempfile.mkdtemp(prefix="preflight-strace-")) / "fsync.log"
    r = Run(auto_print=True, speedup=1.0, tree=tree,
            prefix=("strace", "-f", "-ttt", "-e", "trace=fsync,fdatasync", "-o", str(trace)))
    try:
        spool = r.cfg.spool.path
        (spool / "print.gcode.part").write_text(print_gcode(seconds))
        os.rename(spool / "print.gcode.part", spool / "print.gcode")
        while not (r.journal.jobs() and str(r.journal.jobs()[0].state) in ("done", "failed",
                                                                             "interrupted")):
            time.sleep(0.2)
        job = r.journal.jobs()[0]
        at = {h["to_state"]: h["at"] for h in r.journal.history(job.id)}
        start, end = at["printing"], at.get(str(job.state))
        calls = [float(line.split()[1]) for line in trace.read_text().splitlines()
                 if "fsync(" in line or "fdatasync(" in line]
        during = sum(1 for t in calls if start < t < end)
        minutes = (end - start) / 60.0
        print(f"fsyncs during a {60 * minutes:.0f} s print ({job.state}, daemon from {tree}): "
              f"{during} = {during / minutes:.1f} per minute (strace -f, fsync + fdatasync; "
              f"{len(calls)} in the daemon's whole run)")
    finally:
        r.close()
        shutil.rmtree(trace.parent, ignore_errors=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=12)
    ap.add_argument("--speedup", type=float, default=1000.0,
                    help="virtual printer speed-up (moves, heating)")
    ap.add_argument("--fsync-seconds", type=float, default=70.0,
                    help="length of the print whose fsyncs are counted (0: skip)")
    ap.add_argument("--fsync-tree", type=Path, action="append", default=None,
                    help="count the fsyncs of the daemon in this checkout (repeatable; "
                    "default: this one), e.g. an export of main for a before/after")
    ap.add_argument("--only-fsyncs", action="store_true", help="run the fsync count only")
    a = ap.parse_args()
    if a.only_fsyncs:
        for tree in a.fsync_tree or [ROOT]:
            bench_fsyncs(a.fsync_seconds, tree)
        return 0
    print(f"preflight daemon benchmark ({os.cpu_count()} cores, virtual printer speed-up "
          f"{a.speedup:g}, 250000 baud)")
    bench_child_startup(10)
    bench_latency(a.speedup)
    bench_batch(a.batch, auto_print=False, speedup=a.speedup)
    bench_batch(a.batch, auto_print=True, speedup=a.speedup)
    if a.fsync_seconds:
        for tree in a.fsync_tree or [ROOT]:
            bench_fsyncs(a.fsync_seconds, tree)
    return 0


if __name__ == "__main__":
    sys.exit(main())
