"""Helpers for the farm tests: a real redis-server on a free localhost port, and farm
daemon configs (real ``preflight run`` processes with virtual printers)."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import tomli_w

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))

from daemon_helpers import FAST_PROFILE  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RedisServer:
    """``redis-server`` on 127.0.0.1:port with an append-only file fsynced at every
    write, so a stop and a restart keep every key (as a farm's broker would)."""

    def __init__(self, folder: Path) -> None:
        self.binary = shutil.which("redis-server")
        self.folder = folder
        self.port = free_port()
        self.proc: subprocess.Popen | None = None
        folder.mkdir(parents=True, exist_ok=True)

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> RedisServer:
        assert self.binary
        log = open(self.folder / "redis.log", "ab")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [self.binary, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "yes", "--appendfsync", "always", "--dir", str(self.folder),
             "--daemonize", "no", "--protected-mode", "yes"],
            stdout=log, stderr=log, stdin=subprocess.DEVNULL)
        log.close()
        end = time.monotonic() + 30
        while time.monotonic() < end:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5) as s:
                    s.sendall(b"PING\r\n")
                    if s.recv(16).startswith(b"+PONG"):
                        return self
            except OSError:
                time.sleep(0.05)
        raise AssertionError("redis-server did not start")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()  # SIGTERM: redis writes its append-only file and exits
            self.proc.wait(timeout=30)


def farm_config(folder: Path, *, node: str, broker: str, artefacts: Path,
                printers: list[dict] | None, compute: bool = True,
                claim_timeout: float = 60.0, task_timeout: float = 900.0,
                speedup: float = 5000.0, listen: str = "") -> Path:
    """A farm node's config in ``folder``: ``printers`` is a list of
    ``{"name", "nozzle"[, "volume"]}`` (virtual printers, each logging to ``folder/<name>.log``),
    None for a compute-only node; ``listen``: its HTTP API's host:port ("" none)."""
    folder.mkdir(parents=True, exist_ok=True)
    config: dict = {
        "spool": {"path": str(folder / "spool"), "settle_seconds": 0.5,
                  "close_grace_seconds": 0.1},
        "daemon": {"state_dir": str(folder / "state"), "log_level": "DEBUG"},
        "limits": {"repair_timeout": 120, "slice_timeout": 120},
        "web": {"listen": listen},
        "profile": FAST_PROFILE,
        "farm": {"broker": broker, "name": "test", "node": node, "compute": compute,
                 "artefacts": str(artefacts), "claim_timeout": claim_timeout,
                 "task_timeout": task_timeout},
    }
    tables = [{"name": p["name"], "port": "virtual", "baud": 250000,
               "nozzle_diameter": p["nozzle"], "virtual_speedup": speedup,
               "virtual_log": str(folder / f"{p['name']}.log"),
               "reconnect_min_seconds": 0.2, "reconnect_max_seconds": 1.0,
               **({"virtual_build_volume": p["volume"]} if "volume" in p else {})}
              for p in printers or []]
    add_printers(config, tables)
    path = folder / "preflight.toml"
    path.write_text(tomli_w.dumps(config))
    return path


def add_printers(config: dict, tables: list[dict]) -> None:
    """``[[printers]]`` tables; none: a compute-only node."""
    if tables:
        config["printers"] = tables


# --- what happened -------------------------------------------------------------------------

def print_blocks(log: Path) -> list[tuple[str, ...]]:
    """The prints a virtual printer's log shows: the commands after each ``M110 N0`` (the
    line-number reset a stream starts with), up to the next one."""
    if not log.exists():
        return []
    blocks: list[tuple[str, ...]] = []
    current: list[str] | None = None
    for line in log.read_text().splitlines():
        if line == "M110 N0":
            if current:
                blocks.append(tuple(current))
            current = []
        elif current is not None:
            current.append(line)
    if current:
        blocks.append(tuple(current))
    return blocks


def local_farm_jobs(daemon) -> list[dict]:
    """The farm jobs a node's printers claimed: fid, printer, the local job's state..."""
    from daemon.farm.ledger import FarmLedger

    return FarmLedger(daemon.journal, create=False).claims()
