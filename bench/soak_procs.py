"""The soak's processes: the real daemon and the virtual printer, each its own process.

The printer runs as ``preflight virtual-printer`` so that killing the daemon leaves it
(and its log of executed commands) alone, and killing the printer is an unplug: its
pty disappears, as a USB serial device does. The daemon's resident memory is sampled
from ``/proc/<pid>/status`` across its restarts.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]
# The installed entry point beside this interpreter (``.venv/bin/preflight``), else the module.
_SCRIPT = Path(sys.executable).parent / "preflight"
PREFLIGHT = [str(_SCRIPT)] if _SCRIPT.is_file() else [sys.executable, "-m", "daemon"]
BAUD = 250000


def write_config(run: Path, link: Path) -> Path:
    """A daemon config for the soak: the spool, state and printer link inside ``run``;
    small fast prints, and no web API."""
    path = run / "preflight.toml"
    path.write_text(tomli_w.dumps({
        "spool": {"path": str(run / "spool"), "settle_seconds": 1.0, "close_grace_seconds": 0.3},
        "printer": {"port": str(link), "baud": BAUD, "reconnect_min_seconds": 0.2,
                    "reconnect_max_seconds": 1.0},
        "daemon": {"state_dir": str(run / "state"), "auto_print": True, "log_level": "INFO",
                   "workers": 1},
        "limits": {"repair_timeout": 120, "slice_timeout": 120, "max_attempts": 3},
        "web": {"listen": ""},
        "profile": {"layer_height": 0.3, "first_layer_height": 0.3, "perimeters": 1,
                    "top_layers": 1, "bottom_layers": 1, "infill_percent": 0, "skirts": 0},
    }))
    return path


def rss_kb(pid: int) -> int | None:
    """The process's resident memory in kB, or None if it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError):
        return None
    return None


@dataclass
class Sample:
    at: float          # seconds since the soak started
    life: int          # which daemon start (0, 1, ...)
    age: float         # seconds since that daemon started
    kb: int


@dataclass
class Processes:
    """Starts, kills and restarts the daemon and the printer of one soak run."""

    run: Path
    config: Path
    link: Path
    executed_log: Path
    started: float = field(default_factory=time.monotonic)
    daemon: subprocess.Popen | None = None
    printer: subprocess.Popen | None = None
    printer_faults: list[str] = field(default_factory=list)
    daemon_started: float = 0.0
    lives: int = 0
    samples: list[Sample] = field(default_factory=list)

    def _log(self, name: str):
        return open(self.run / name, "ab")  # noqa: SIM115 - the child keeps it

    def start_printer(self, faults: list[str], seed: int) -> None:
        """Plug a virtual printer in (with ``faults`` CLI options); wait for its link."""
        self.printer_faults = list(faults)
        with self._log("printer.log") as log:
            self.printer = subprocess.Popen(
                [*PREFLIGHT, "virtual-printer", "--firmware", "marlin", "--speedup", "1000",
                 "--baud", str(BAUD), "--link", str(self.link), "--log",
                 str(self.executed_log), "--seed", str(seed), *faults],
                stdout=log, stderr=log, stdin=subprocess.DEVNULL, cwd=ROOT)
        end = time.monotonic() + 30
        while not self.link.exists():
            if self.printer.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"the virtual printer did not start (see {self.run})")
            time.sleep(0.02)

    def unplug_printer(self) -> None:
        """Pull the plug: SIGKILL the printer (its pty vanishes); udev drops the link."""
        if self.printer is not None:
            _kill(self.printer, signal.SIGKILL)
            self.printer = None
        self.link.unlink(missing_ok=True)

    def start_daemon(self) -> None:
        with self._log("daemon.log") as log:
            self.daemon = subprocess.Popen(
                [*PREFLIGHT, "run", "--config", str(self.config)],
                stdout=log, stderr=log, stdin=subprocess.DEVNULL, cwd=ROOT)
        self.daemon_started = time.monotonic()
        self.lives += 1

    def kill_daemon(self) -> None:
        """``kill -9`` the daemon (its repair/slice children die with it)."""
        if self.daemon is not None:
            _kill(self.daemon, signal.SIGKILL)
            self.daemon = None

    def daemon_alive(self) -> bool:
        return self.daemon is not None and self.daemon.poll() is None

    def sample_rss(self) -> None:
        if not self.daemon_alive() or time.monotonic() - self.daemon_started < 2.0:
            return  # not yet the daemon: the interpreter is still starting
        kb = rss_kb(self.daemon.pid)
        if kb is not None:
            now = time.monotonic()
            self.samples.append(Sample(now - self.started, self.lives - 1,
                                       now - self.daemon_started, kb))

    def stop_all(self) -> int | None:
        """Stop the daemon gracefully (SIGTERM, then SIGKILL), then unplug the printer.
        Returns the daemon's exit status (None if it was not running)."""
        status = None
        if self.daemon is not None:
            status = _kill(self.daemon, signal.SIGTERM, wait=60)
            self.daemon = None
        if self.printer is not None:
            _kill(self.printer, signal.SIGTERM, wait=10)
            self.printer = None
        return status


def _kill(proc: subprocess.Popen, sig: int, wait: float = 10.0) -> int | None:
    """Send ``sig`` and reap the process (SIGKILL if it outlives ``wait``)."""
    if proc.poll() is None:
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            pass
    try:
        return proc.wait(timeout=wait)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(timeout=10)


def env_ok() -> None:
    """Make ``python -m daemon`` import this tree's packages whatever the cwd."""
    path = os.environ.get("PYTHONPATH", "")
    if str(ROOT) not in path.split(os.pathsep):
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), path) if p)
