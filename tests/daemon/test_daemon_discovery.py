"""The daemon with ``[printer] port = "auto"`` (the default): with no printer it keeps
running, says so and leaves jobs ready; it finds a printer plugged in later, and finds
it again after an unplug, on another port and at another baud rate."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib

import tomli_w
from daemon_helpers import DaemonProc, drop, tiny_gcode, write_config

from daemon.journal import JobState
from printer.gcode import clean_lines


def plug_in(link, log, baud: int) -> subprocess.Popen:
    """A printer in its own process, appearing at ``link`` (like a by-id name)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "daemon", "virtual-printer", "--baud", str(baud),
         "--speedup", "2000", "--link", str(link), "--log", str(log)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().startswith("/dev/"), proc.stderr.read()
    return proc


def test_auto_port_waits_for_a_printer_and_finds_it_again_after_an_unplug(tmp_path):
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    cfg_path = write_config(tmp_path, port="auto", profile=False)
    config = tomllib.loads(cfg_path.read_text())
    config["printer"].update(scan=[str(by_id / "*")], probe_seconds=2.0)
    cfg_path.write_text(tomli_w.dumps(config))
    d = DaemonProc(cfg_path).start()
    procs = []
    try:
        first = tiny_gcode(moves=30)
        drop(d.cfg.spool.path, "first.gcode", first.encode())
        d.wait_for(lambda: (d.status().get("printer") or {}).get("state") == "waiting"
                   and d.states().get("first.gcode") == "ready", what="no printer yet")
        message = d.status()["printer"]["message"]
        assert message.startswith("no printer found: no serial port matches"), message
        out = d.cli("status")
        assert "printer: auto - waiting: no printer found" in out.stdout, out.stdout
        assert d.states()["first.gcode"] == "ready"  # never done against nothing

        procs.append(plug_in(by_id / "usb-Virtual_A-if00", tmp_path / "a.log", 250000))
        d.wait_for(lambda: d.states()["first.gcode"] == "done", what="printed on A")
        status = d.wait_for(lambda: (s := d.status()["printer"]).get("discovery") and s,
                            what="the status shows the scan")
        assert status["port"] == str(by_id / "usb-Virtual_A-if00")
        assert any(": taken: Marlin" in line for line in status["discovery"])
        executed = (tmp_path / "a.log").read_text().splitlines()
        assert executed[-len(clean_lines(first.splitlines())):] == clean_lines(first.splitlines())
        report = d.wait_for(lambda: next(d.cfg.done_dir.glob("first*.report.txt"), None),
                            what="the report").read_text()
        assert "build volume 250 x 210 x 220 mm (from M211)" in report  # names its source
        remembered = json.loads((d.cfg.daemon.state_dir / "printer_port.json").read_text())
        assert remembered["port"] == str(by_id / "usb-Virtual_A-if00")
        assert remembered["baud"] == 250000

        procs.pop().terminate()  # unplugged: its link goes away
        d.wait_for(lambda: "printer: auto - waiting: no printer found" in d.cli("status").stdout,
                   what="the unplug is noticed while idle, and said")
        procs.append(plug_in(by_id / "usb-Virtual_B-if00", tmp_path / "b.log", 115200))
        second = tiny_gcode(moves=40)
        drop(d.cfg.spool.path, "second.gcode", second.encode())
        job = d.wait_for(lambda: next((j for j in d.jobs() if j.source_name == "second.gcode"
                                       and j.state in (JobState.DONE, JobState.INTERRUPTED,
                                                       JobState.FAILED)), None),
                         what="second job ends")
        assert job.state == JobState.DONE, job.reason
        executed = (tmp_path / "b.log").read_text().splitlines()
        assert executed[-len(clean_lines(second.splitlines())):] == clean_lines(
            second.splitlines())
        d.wait_for(lambda: d.status()["printer"]["port"] == str(by_id / "usb-Virtual_B-if00"),
                   what="the status shows the new port")
        assert d.states()["first.gcode"] == "done"
        assert d.stop() == 0
    finally:
        for proc in procs:
            proc.terminate()
            proc.wait(timeout=10)
        if d.alive():
            d.stop()
