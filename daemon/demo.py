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
    cfg = root / "preflight.toml"
    cfg.write_text(f"""# written by `preflight demo`
[spool]
path = "{root / 'spool'}"
settle_seconds = 1.0
close_grace_seconds = 0.2

[printer]
port = "virtual"
virtual_firmware = "prusa"        # reports its nozzle (M862.1 Q): epsilon comes from it
baud = 250000
virtual_speedup = {speedup}
reconnect_min_seconds = 0.5

[daemon]
state_dir = "{root / 'state'}"
auto_print = true
log_level = "INFO"

[web]
listen = ""                       # the demo is offline: no HTTP API
""")
    return cfg


def run_demo(*, keep: bool = False, speedup: float | None = None) -> int:
    from daemon.config import load_config
    from daemon.journal import Journal
    from daemon.report import report_text
    from daemon.service import daemon_alive

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
        code = _follow(proc, cfg, root, log_path, Journal, report_text, daemon_alive)
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


def _follow(proc, cfg, root: Path, log_path: Path, Journal, report_text, daemon_alive) -> int:
    start = time.monotonic()
    # 1. the daemon is up
    while True:
        if proc.poll() is not None:
            print(f"preflight: the daemon exited with status {proc.returncode}:\n"
                  f"{_tail(log_path)}", file=sys.stderr)
            return 1
        if cfg.journal_path.exists():
            j = Journal(cfg.journal_path, readonly=True)
            if daemon_alive(j.get_meta("status")):
                break
            j.close()
        if time.monotonic() - start > 60:
            print("preflight: the daemon did not start within 60 s", file=sys.stderr)
            return 1
        time.sleep(0.2)
    _say(f"daemon running (pid {proc.pid})")
    # 2. drop the broken model, the way a network copy does: write, then rename
    src = resources.files("daemon") / "data" / DEMO_MODEL
    part = cfg.spool.path / (DEMO_MODEL + ".part")
    with resources.as_file(src) as p:
        shutil.copyfile(p, part)
    os.rename(part, cfg.spool.path / DEMO_MODEL)
    _say(f"dropped {DEMO_MODEL} (a broken model: an open cube stuck to the side of a closed one)")
    # 3. follow the job through its recorded transitions (none is missed between polls)
    announced = 0
    job = None
    while time.monotonic() - start < DEMO_TIMEOUT:
        if proc.poll() is not None:
            _end_progress()
            print(f"preflight: the daemon died (status {proc.returncode}):\n{_tail(log_path)}",
                  file=sys.stderr)
            return 1
        jobs = j.jobs()
        if not jobs:
            time.sleep(0.2)
            continue
        job = jobs[-1]
        hist = j.history(job.id)
        for h in hist[announced:]:
            if announced and hist[announced - 1]["to_state"] == "printing":
                _end_progress()
            _announce(h["to_state"], job)
            announced += 1
        state = str(job.state)
        if state == "printing" and job.progress is not None:
            _progress("streaming to the printer", job.progress)
        if state in ("done", "failed", "cancelled", "interrupted") and (
                job.outputs or {}).get("report_txt"):
            break
        time.sleep(0.2)
    else:
        print(f"preflight: the demo did not finish within {DEMO_TIMEOUT:g} s", file=sys.stderr)
        return 1
    job = j.get(job.id)
    st = j.get_meta("status") or {}
    _say("")
    _say("---- report ----")
    sys.stdout.write(report_text(job, j.history(job.id)))
    outs = job.outputs or {}
    for k in ("input", "repaired", "gcode", "report_txt"):
        if k in outs:
            _say(f"  {k}: {outs[k]}")
    _say("")
    if str(job.state) != "done":
        print(f"preflight: the demo job ended {job.state}: {job.reason}", file=sys.stderr)
        return 1
    _say(f"demo finished in {time.monotonic() - start:.1f} s: the broken model was repaired, "
         f"sliced and printed on the virtual printer "
         f"({(st.get('printer') or {}).get('port')}).")
    return 0


def _announce(s: str, job) -> None:
    if s == "queued":
        _say(f"job {job.id}: queued; asking the printer for its nozzle")
    elif s == "repairing":
        _say(f"job {job.id}: repairing with epsilon = {job.epsilon:g} mm ({job.epsilon_source})")
    elif s == "slicing":
        rep = job.repair_report or {}
        b, a = rep.get("before") or {}, rep.get("after") or {}
        _say(f"job {job.id}: repaired - {rep.get('summary', '')}")
        _say(f"         triangles {b.get('triangles', '?')} -> {a.get('triangles', '?')}")
    elif s == "ready":
        sm = job.slice_summary or {}
        _say(f"job {job.id}: sliced - {sm.get('layers', '?')} layers, "
             f"{(sm.get('filament_mm') or 0) / 1000:.2f} m of filament, "
             f"estimated {sm.get('estimated_seconds', 0) / 60:.1f} min of printing")
    elif s == "printing":
        info = job.printer_info or {}
        _say(f"job {job.id}: streaming to the printer ({info.get('firmware', '?')})")
    elif s == "done":
        pr = job.print_result or {}
        _say(f"job {job.id}: printed - {pr.get('acked_lines')} lines acknowledged in "
             f"{pr.get('seconds', 0):.1f} s")
    else:
        _say(f"job {job.id}: {s} - {job.reason}")
