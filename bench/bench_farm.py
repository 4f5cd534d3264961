"""Farm benchmark: compute throughput, dispatch latency, broker round-trips.

Starts a real ``redis-server`` on a free localhost port and real processes, and prints:

- jobs per minute for repair+slice of a batch of distinct small models (boxes of
  different sizes, one in three the shipped broken model scaled differently) through
  the farm's Celery compute queue, with 1 and then 2 compute workers (two compute
  nodes' worker processes, ``python -m daemon.farm.compute``); each run has its own
  artefact store, so nothing is reused; the ratio 2 : 1 is printed (on a 2-core machine
  shared with other work, expect well under 2);
- dispatch latency: from dropping a file into a node's spool to its first line at a free
  virtual printer (``preflight run`` farm nodes: one with a printer, one compute-only),
  for a G-code file (no compute) and a model (repair and slicing on the compute node);
- broker round-trips per job: Redis ``INFO commandstats`` calls counted over a batch
  printed end to end, minus the idle rate of the same nodes (heartbeats, polling)
  measured before it, also printed.

Usage: .venv/bin/python bench/bench_farm.py [--batch 50] [--printed 20]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "daemon"))
sys.path.insert(0, str(ROOT / "tests" / "farm"))

from daemon_helpers import (  # noqa: E402
    DaemonProc,
    box,
    broken_stl,
    drop,
    tiny_gcode,
    write_binary_stl,
)
from farm_helpers import RedisServer, farm_config  # noqa: E402

from daemon.config import load_config  # noqa: E402
from daemon.farm.artefacts import ArtefactStore  # noqa: E402
from daemon.farm.tasks import PREPARE, configure  # noqa: E402


def _models(folder: Path, count: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(count):
        path = folder / f"m{i:03d}.stl"
        if i % 3 == 2:
            broken_stl(path, scale=0.15 + 0.002 * i)
        else:
            write_binary_stl(path, *box((4.0 + 0.1 * i, 5.0, 3.0)))
        paths.append(path)
    return paths


def _command_calls(redis_url: str) -> int:
    import redis

    stats = redis.Redis.from_url(redis_url).info("commandstats")
    return sum(int(v["calls"]) for v in stats.values())


def compute_throughput(tmp: Path, redis: RedisServer, batch: int, workers: int) -> float:
    """Jobs per minute for ``batch`` distinct repair+slice tasks on ``workers`` compute
    worker processes (each its own node)."""
    art = tmp / f"artefacts-{workers}"
    procs = []
    cfg_paths = [farm_config(tmp / f"w{workers}-{i}", node=f"w{workers}-{i}",
                             broker=redis.url, artefacts=art, printers=None)
                 for i in range(workers)]
    store = ArtefactStore(art)
    cfg = load_config(cfg_paths[0])
    app = configure(cfg)
    keys = [store.put_input(p) for p in _models(tmp / "models", batch)]
    for path in cfg_paths:
        log = open(path.parent / "compute.log", "ab")  # noqa: SIM115
        procs.append(subprocess.Popen([sys.executable, "-m", "daemon.farm.compute",
                                       "--config", str(path)], stdout=log, stderr=log))
    time.sleep(3.0)  # the workers' start-up (imports, fork server) is not the batch's
    spec = {"epsilon": 0.4, "profile": {"orient": "if-needed", "layer_height": 0.3,
                                        "infill_percent": 10},
            "build_volume": [250.0, 210.0, 220.0], "flavour": "marlin",
            "filament_diameter": 1.75}
    started = time.monotonic()
    results = [app.send_task(PREPARE, args=[{**spec, "input": k, "name": f"{k[:8]}.stl"}])
               for k in keys]
    outcomes = [r.get(timeout=3600) for r in results]
    elapsed = time.monotonic() - started
    for p in procs:
        p.terminate()
        p.wait(timeout=60)
    failed = sum(not o.get("ok") for o in outcomes)
    per_minute = 60.0 * batch / elapsed
    print(f"  {workers} compute worker(s): {batch} models in {elapsed:.1f} s = "
          f"{per_minute:.1f} jobs/min ({failed} failed)")
    return per_minute


def _first_line_after(log: Path, offset: int, wait_for: str, timeout: float = 300) -> float:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if log.exists() and log.stat().st_size > offset:
            with open(log) as f:
                f.seek(offset)
                if wait_for in f.read():
                    return time.monotonic()
        time.sleep(0.01)
    raise TimeoutError(f"no {wait_for!r} in {log}")


def dispatch_and_round_trips(tmp: Path, redis: RedisServer, printed: int) -> None:
    art = tmp / "artefacts-dispatch"
    a = DaemonProc(farm_config(tmp / "a", node="a", broker=redis.url, artefacts=art,
                               printers=[{"name": "a04", "nozzle": 0.4}], compute=False))
    c = DaemonProc(farm_config(tmp / "c", node="c", broker=redis.url, artefacts=art,
                               printers=None))
    log = tmp / "a" / "a04.log"
    try:
        a.start()
        c.start()
        time.sleep(5.0)  # the virtual printer connected, the compute worker up
        for label, name, data, marker in (
                ("G-code file", "lat.gcode", tiny_gcode(["M117 latency"]).encode(),
                 "M117 latency"),
                ("model (repair+slice on the compute node)", "lat.stl", None, "G28")):
            if data is None:
                write_binary_stl(tmp / name, *box((7.3, 6.1, 4.2)))
                data = (tmp / name).read_bytes()
            offset = log.stat().st_size if log.exists() else 0
            t0 = time.monotonic()
            drop(a.cfg.spool.path, name, data)
            t1 = _first_line_after(log, offset, marker)
            print(f"  dispatch latency, {label}: drop -> first line at the free printer "
                  f"{t1 - t0:.2f} s")
            time.sleep(3.0)
        idle_s = 10.0
        calls0 = _command_calls(redis.url)
        time.sleep(idle_s)
        idle_rate = (_command_calls(redis.url) - calls0) / idle_s
        models = _models(tmp / "printed", printed)
        calls1 = _command_calls(redis.url)
        t0 = time.monotonic()
        for p in models:
            drop(a.cfg.spool.path, p.name, p.read_bytes())
        a.wait_for(lambda: sum(str(j.state) in ("done", "failed") for j in a.jobs())
                   >= printed + 2, what="the printed batch", timeout=3600, poll=0.5)
        elapsed = time.monotonic() - t0
        calls = _command_calls(redis.url) - calls1
        per_job = (calls - idle_rate * elapsed) / printed
        print(f"  broker: {idle_rate:.1f} commands/s idle (2 nodes: heartbeats, polling); "
              f"{calls} commands over a {printed}-job batch in {elapsed:.1f} s = "
              f"{per_job:.0f} round-trips per job beyond the idle rate")
    finally:
        a.stop()
        c.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=50)
    parser.add_argument("--printed", type=int, default=20)
    args = parser.parse_args()
    if shutil.which("redis-server") is None:
        print("bench_farm: redis-server is not installed (apt-get install redis-server)")
        return 1
    with tempfile.TemporaryDirectory(prefix="bench-farm-") as folder:
        tmp = Path(folder)
        redis = RedisServer(tmp / "redis").start()
        try:
            print(f"repair+slice throughput, {args.batch} distinct models:")
            one = compute_throughput(tmp, redis, args.batch, 1)
            two = compute_throughput(tmp, redis, args.batch, 2)
            print(f"  2 workers : 1 worker = {two / one:.2f}x")
            print("dispatch and broker load:")
            dispatch_and_round_trips(tmp, redis, args.printed)
        finally:
            redis.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
