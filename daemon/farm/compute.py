"""The compute node's Celery worker: a child process of ``preflight run`` that dies
with it (``PR_SET_PDEATHSIG``), so a ``kill -9`` of the daemon takes its running task
down too and the broker hands that task to another worker (at-least-once).

``python -m daemon.farm.compute --config PATH`` runs the worker in the foreground.
"""

from __future__ import annotations

import argparse
import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

from daemon.config import Config, load_config, setup_logging

log = logging.getLogger("preflight.farm")

PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except OSError:
        pass


class ComputeWorker:
    """Keeps one Celery worker process running while the daemon runs."""

    def __init__(self, cfg: Config, stop: threading.Event) -> None:
        self.cfg = cfg
        self.stop = stop
        self.proc: subprocess.Popen | None = None
        self.starts = 0
        self.log_path = cfg.daemon.state_dir / "farm-compute.log"

    def check(self) -> None:
        """Start the worker, or start it again if it died."""
        if self.stop.is_set() or (self.proc is not None and self.proc.poll() is None):
            return
        if self.proc is not None:
            log.warning("farm: the compute worker exited (%s); starting it again",
                        self.proc.returncode)
        with open(self.log_path, "ab") as out:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "daemon.farm.compute", "--config",
                 self.cfg.source],
                stdout=out, stderr=out, stdin=subprocess.DEVNULL,
                preexec_fn=_die_with_parent)  # noqa: PLW1509
        self.starts += 1
        log.info("farm: compute worker started (pid %d, %d at once)", self.proc.pid,
                 self.cfg.farm.compute_workers)

    def close(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)  # warm shutdown: the running task finishes
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m daemon.farm.compute")
    parser.add_argument("--config", required=True, type=Path)
    args = parser.parse_args(argv)
    cfg = load_config(args.config)
    setup_logging(cfg.daemon.log_level)
    from daemon.farm.tasks import compute_queue, configure
    from daemon.worker import warm_up

    app = configure(cfg)
    cfg.daemon.state_dir.mkdir(parents=True, exist_ok=True)
    warm_up()
    node = cfg.farm.node or os.uname().nodename
    app.worker_main(["worker", "-Q", compute_queue(cfg), "-n", f"{node}@%h",
                     "--pool", "threads", "-c", str(cfg.farm.compute_workers),
                     "--without-gossip", "--without-mingle", "-l", cfg.daemon.log_level])
    return 0


if __name__ == "__main__":
    sys.exit(main())
