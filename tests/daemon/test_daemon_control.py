"""Print control end to end: the real daemon, the CLI, and a virtual printer on a real
pty that the test holds (so it can make the printer cancel, halt or run out of filament)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest
from daemon_helpers import DaemonProc, drop, tiny_gcode, write_config

from printer.gcode import clean_lines
from printer.virtual import Faults, VirtualPrinter

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "printer"))
from printer_helpers import streamed  # noqa: E402


def job_state(d: DaemonProc, name: str) -> str | None:
    return d.states().get(name)


def run_of(vp: VirtualPrinter, before: int) -> list[tuple[int, str]]:
    """The numbered lines the printer ran since ``before`` lines had run (one stream)."""
    return streamed(vp)[before:]


def print_with_event(d: DaemonProc, vp: VirtualPrinter, name: str, event: str, end: str):
    """Drop a file; the printer does ``event`` after its 30th line; wait for ``end``.
    Returns the job and the numbered lines the printer ran for it."""
    before = len(streamed(vp))
    vp.faults = Faults(events=((vp.machine.numbered_done + 30, event),))
    drop(d.cfg.spool.path, name, tiny_gcode(moves=300).encode())
    d.wait_for(lambda: job_state(d, name) == end, what=end)
    job = next(j for j in d.jobs() if j.source_name == name)
    return job, run_of(vp, before)


@pytest.fixture
def daemon_and_printer(tmp_path):
    link = tmp_path / "ttyPRINTER"
    vp = VirtualPrinter("marlin", speedup=10, baud=250000, link=link, keepalive=0.2)
    vp.start()
    d = DaemonProc(write_config(tmp_path, port=str(link)))
    try:
        d.start()
        yield d, vp
    finally:
        d.stop()
        vp.stop()


def test_pause_resume_cancel_halt_through_the_daemon(daemon_and_printer):
    d, vp = daemon_and_printer
    spool = d.cfg.spool.path

    # 1. pause and resume from the CLI: the printer runs the file exactly once
    text = tiny_gcode(moves=600)
    drop(spool, "paused.gcode", text.encode())
    d.wait_for(lambda: job_state(d, "paused.gcode") == "printing", what="printing")
    job = next(j for j in d.jobs() if j.source_name == "paused.gcode")
    d.wait_for(lambda: len(streamed(vp)) > 20, what="lines running")
    out = d.cli("jobs", "pause", str(job.id))
    assert out.returncode == 0, out.stderr
    d.wait_for(lambda: job_state(d, "paused.gcode") == "paused", what="paused")
    held = len(streamed(vp))
    time.sleep(0.5)
    assert len(streamed(vp)) == held < len(clean_lines(text.splitlines()))
    assert vp.machine.motion.position["Y"] == 200.0  # parked (Y max - 10)
    assert "paused" in d.cli("status").stdout
    out = d.cli("jobs", "resume", str(job.id))
    assert out.returncode == 0, out.stderr
    d.wait_for(lambda: job_state(d, "paused.gcode") == "done", what="done")
    ran = run_of(vp, 0)
    assert [c for _, c in ran] == clean_lines(text.splitlines())
    assert [n for n, _ in ran] == list(range(1, len(ran) + 1))
    history = [h["to_state"] for h in d.journal.history(job.id)]
    assert history[-3:] == ["paused", "printing", "done"]

    # 2. the printer says //action:cancel: the job ends cancelled, heaters off
    job, ran = print_with_event(d, vp, "printer_cancel.gcode", "//action:cancel", "cancelled")
    assert "cancelled by the printer (//action:cancel)" in job.reason
    assert vp.machine.heaters.target == {"T": 0.0, "B": 0.0}
    assert 30 <= len(ran) < len(clean_lines(tiny_gcode(moves=300).splitlines()))

    # 3. a kill() halt: failed with the firmware's words, never sent again
    job, ran = print_with_event(d, vp, "halted.gcode", "kill", "failed")
    assert "Error:Printer halted. kill() called!" in job.reason
    before = len(streamed(vp))
    time.sleep(2.0)  # the daemon reconnects meanwhile; nothing is re-sent
    assert job_state(d, "halted.gcode") == "failed"
    assert len(ran) == 30 and len(streamed(vp)) == before
    out = d.cli("jobs", "resume", str(job.id))
    assert out.returncode != 0 and "only a paused job" in out.stderr


def test_moonraker_pause_resume_cancel_and_octoprint_emergency_stop(web_daemon, tmp_path):
    from web_helpers import request

    d, port, key = web_daemon(speedup=20)
    headers = {"X-Api-Key": key}
    nothing = request(port, "POST", "/printer/print/pause", headers=headers)
    assert nothing.status == 409 and "no print to pause" in nothing.json()["error"]
    drop(d.cfg.spool.path, "long.gcode", tiny_gcode(moves=3000).encode())
    d.wait_for(lambda: job_state(d, "long.gcode") == "printing", what="printing")
    ans = request(port, "POST", "/printer/print/pause", headers=headers)
    assert ans.status == 200 and ans.json() == {"result": "ok"}
    d.wait_for(lambda: job_state(d, "long.gcode") == "paused", what="paused")
    assert "G1 X10 Y200 F6000" in (tmp_path / "printer.log").read_text().splitlines()
    ans = request(port, "POST", "/printer/print/resume", headers=headers)
    assert ans.status == 200, ans.body
    d.wait_for(lambda: job_state(d, "long.gcode") == "printing", what="printing again")
    ans = request(port, "POST", "/printer/print/cancel", headers=headers)
    assert ans.status == 200, ans.body
    d.wait_for(lambda: job_state(d, "long.gcode") == "cancelled", what="cancelled")
    log = (tmp_path / "printer.log").read_text().splitlines()
    assert log[-4:] == ["M104 S0", "M140 S0", "M107", "M84"]
    # OctoPrint's emergency stop: M112 through /api/printer/command; other G-code refused
    drop(d.cfg.spool.path, "stopped.gcode", tiny_gcode(moves=3000).encode())
    d.wait_for(lambda: job_state(d, "stopped.gcode") == "printing", what="printing")
    json_headers = {**headers, "Content-Type": "application/json"}
    ans = request(port, "POST", "/api/printer/command", headers=json_headers,
                  body=b'{"commands": ["G28"]}')
    assert ans.status == 409 and "only M112" in ans.json()["error"]
    ans = request(port, "POST", "/api/printer/command", headers=json_headers,
                  body=b'{"command": "M112"}')
    assert ans.status == 204, ans.body
    d.wait_for(lambda: job_state(d, "stopped.gcode") == "failed", what="failed")
    job = next(j for j in d.jobs() if j.source_name == "stopped.gcode")
    assert "emergency stop (M112)" in job.reason and "reset" in job.reason
