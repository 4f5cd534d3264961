"""``preflight demo``: the whole product in one command, on the embedded defaults.

Starts the real daemon (``preflight run``) on a temporary spool with the built-in
virtual printer, drops the shipped broken model (``daemon/data/``) into the
spool, follows the job through the journal (repaired, with what was fixed;
sliced; streamed with progress), prints the report and exits 0.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from daemon.config import Config
    from daemon.journal import Job, Journal

DEMO_MODEL = "open_cube_stuck_to_side.stl"
DEMO_TIMEOUT = 900.0  # s: give up (and say so) rather than hang


def _say(msg: str) -> None:
    print(msg, flush=True)


_last_quarter = [-1]


def _progress(label: str, fraction: float) -> None:
    line = f"  {label} {100 * fraction:5.1f}%"
    if sys.stderr.isatty():
        sys.stderr.write("\r" + line)
        sys.stderr.flush()
    elif int(fraction * 4) > _last_quarter[0]:  # not a terminal: a line per quarter
        _last_quarter[0] = int(fraction * 4)
        print(line, flush=True)


def _end_progress() -> None:
    if sys.stderr.isatty():
        sys.stderr.write("\n")


def write_demo_config(root: Path, *, speedup: float) -> Path:
    """The demo's config: a temporary spool and state folder, the virtual printer playing
    a Prusa (it reports its nozzle with M862.1 Q, so epsilon comes from the printer)."""
    import tomli_w

    cfg = root / "preflight.toml"
    cfg.write_text("# written by `preflight demo`\n" + tomli_w.dumps({
        "spool": {"path": str(root / "spool"), "settle_seconds": 1.0,
                  "close_grace_seconds": 0.2},
        "printer": {"port": "virtual", "virtual_firmware": "prusa", "baud": 250000,
                    "virtual_speedup": speedup, "reconnect_min_seconds": 0.5},
        "daemon": {"state_dir": str(root / "state"), "auto_print": True, "log_level": "INFO"},
        "web": {"listen": ""},  # the demo is offline: no HTTP API
    }))
    return cfg


def run_demo(*, keep: bool = False, speedup: float | None = None) -> int:
    from daemon.config import load_config

    root = Path(tempfile.mkdtemp(prefix="preflight-demo-"))
    cfg_path = write_demo_config(root, speedup=speedup or 1000.0)
    cfg = load_config(cfg_path)
    log_path = root / "daemon.log"
    _say(f"preflight demo: temporary spool {cfg.spool.path}, virtual printer, log {log_path}")
    with open(log_path, "ab") as log:
        proc = subprocess.Popen([sys.executable, "-m", "daemon", "run", "--config", str(cfg_path)],
                                stdout=log, stderr=log, stdin=subprocess.DEVNULL)
    code = 1
    try:
        code = _follow(proc, cfg, log_path)
    except KeyboardInterrupt:
        _end_progress()
        print("preflight: demo interrupted", file=sys.stderr)
        code = 130
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if keep or code != 0:
            _say(f"kept {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)
    return code


def _tail(path: Path, n: int = 5) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


class DemoFailed(Exception):
    """The demo cannot go on; the message says why."""


def _follow(proc: subprocess.Popen, cfg: Config, log_path: Path) -> int:
    from daemon.report import report_text

    start = time.monotonic()
    try:
        journal = _wait_for_daemon(proc, cfg, log_path, start)
        _say(f"daemon running (pid {proc.pid})")
        _drop_demo_model(cfg.spool.path)
        job = _watch_job(proc, journal, log_path, start)
    except DemoFailed as e:
        _end_progress()
        print(f"preflight: {e}", file=sys.stderr)
        return 1
    status = journal.get_meta("status") or {}
    _say("")
    _say("---- report ----")
    sys.stdout.write(report_text(job, journal.history(job.id)))
    outputs = job.outputs or {}
    for key in ("input", "repaired", "gcode", "report_txt"):
        if key in outputs:
            _say(f"  {key}: {outputs[key]}")
    _say("")
    if str(job.state) != "done":
        print(f"preflight: the demo job ended {job.state}: {job.reason}", file=sys.stderr)
        return 1
    _say(f"demo finished in {time.monotonic() - start:.1f} s: the broken model was repaired, "
         f"sliced and printed on the virtual printer "
         f"({(status.get('printer') or {}).get('port')}).")
    return 0


def _wait_for_daemon(proc: subprocess.Popen, cfg: Config, log_path: Path,
                     start: float) -> Journal:
    """The daemon's journal, once the daemon says it runs."""
    from daemon.journal import Journal
    from daemon.service import daemon_alive

    while True:
        if proc.poll() is not None:
            raise DemoFailed(f"the daemon exited with status {proc.returncode}:\n"
                             f"{_tail(log_path)}")
        if cfg.journal_path.exists():
            journal = Journal(cfg.journal_path, readonly=True)
            if daemon_alive(journal.get_meta("status")):
                return journal
            journal.close()
        if time.monotonic() - start > 60:
            raise DemoFailed("the daemon did not start within 60 s")
        time.sleep(0.2)


def _drop_demo_model(spool: Path) -> None:
    """Drop the broken model the way a network copy does: write, then rename."""
    model = resources.files("daemon") / "data" / DEMO_MODEL
    part = spool / (DEMO_MODEL + ".part")
    with resources.as_file(model) as path:
        shutil.copyfile(path, part)
    os.rename(part, spool / DEMO_MODEL)
    _say(f"dropped {DEMO_MODEL} (a broken model: an open cube stuck to the side of a closed one)")


def _watch_job(proc: subprocess.Popen, journal: Journal, log_path: Path, start: float) -> Job:
    """Announce the job's recorded transitions (none is missed between polls) until it
    has ended and its reports are written; return it."""
    announced = 0
    while time.monotonic() - start < DEMO_TIMEOUT:
        if proc.poll() is not None:
            raise DemoFailed(f"the daemon died (status {proc.returncode}):\n{_tail(log_path)}")
        jobs = journal.jobs()
        if not jobs:
            time.sleep(0.2)
            continue
        job = jobs[-1]
        history = journal.history(job.id)
        for step in history[announced:]:
            if announced and history[announced - 1]["to_state"] == "printing":
                _end_progress()
            _announce(step["to_state"], job)
            announced += 1
        state = str(job.state)
        if state == "printing" and job.progress is not None:
            _progress("streaming to the printer", job.progress)
        if state in ("done", "failed", "cancelled", "interrupted") and (
                job.outputs or {}).get("report_txt"):
            latest = journal.get(job.id)
            assert latest is not None
            return latest
        time.sleep(0.2)
    raise DemoFailed(f"the demo did not finish within {DEMO_TIMEOUT:g} s")


def _announce(state: str, job: Job) -> None:
    if state == "queued":
        _say(f"job {job.id}: queued; asking the printer for its nozzle")
    elif state == "repairing":
        _say(f"job {job.id}: repairing with epsilon = {job.epsilon:g} mm ({job.epsilon_source})")
    elif state == "slicing":
        report = job.repair_report or {}
        before, after = report.get("before") or {}, report.get("after") or {}
        _say(f"job {job.id}: repaired - {report.get('summary', '')}")
        _say(f"         triangles {before.get('triangles', '?')} -> "
             f"{after.get('triangles', '?')}")
    elif state == "ready":
        summary = job.slice_summary or {}
        _say(f"job {job.id}: sliced - {summary.get('layers', '?')} layers, "
             f"{(summary.get('filament_mm') or 0) / 1000:.2f} m of filament, "
             f"estimated {summary.get('estimated_seconds', 0) / 60:.1f} min of printing")
    elif state == "printing":
        info = job.printer_info or {}
        _say(f"job {job.id}: streaming to the printer ({info.get('firmware', '?')})")
    elif state == "done":
        result = job.print_result or {}
        _say(f"job {job.id}: printed - {result.get('acked_lines')} lines acknowledged in "
             f"{result.get('seconds', 0):.1f} s")
    else:
        _say(f"job {job.id}: {state} - {job.reason}")
