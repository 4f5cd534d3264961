"""A print that starts with a real-time heat-up, through the real daemon: live
temperatures in its status while the printer heats, samples in the journal and the
job's report."""

from __future__ import annotations

import pytest
from daemon_helpers import DaemonProc, drop, tiny_gcode, write_config


@pytest.fixture
def daemon(tmp_path):
    made: list[DaemonProc] = []
    yield lambda cfg: made.append(DaemonProc(cfg)) or made[-1]
    for d in made:
        d.stop()


@pytest.mark.parametrize("firmware", ["klipper"])
def test_heat_up_temperatures_reach_status_journal_and_report(tmp_path, daemon, firmware):
    from printer.virtual import VirtualPrinter

    link = tmp_path / "ttyHEAT"
    # 10x: ~80 s of printer time of heating, 8 s of wall time
    vp = VirtualPrinter(firmware, speedup=10, baud=250000, link=link, keepalive=0.1)
    vp.start()
    try:
        d = daemon(write_config(tmp_path, port=str(link))).start()
        d.wait_for(lambda: (d.status().get("printer") or {}).get("state") == "connected",
                   what="printer connected")
        drop(d.cfg.spool.path, "heat.gcode",
             tiny_gcode(extra=[]).replace("G28\n", "M190 S60\nM109 S210\nG28\n").encode())
        seen = d.wait_for(
            lambda: ((t := (d.status().get("printer") or {}).get("temperatures"))
                     and t.get("B", [0, 0])[1] == 60.0 and 30.0 < t["B"][0] < 59.0 and t),
            what="live bed temperature while heating")
        assert seen["B"][1] == 60.0
        shown = d.cli("status").stdout
        assert "temperatures: hotend " in shown and "/60 °C" in shown, shown
        job = d.wait_for(lambda: (j := d.journal.get(1)) and str(j.state) == "done" and j,
                         what="printed")
        samples = d.journal.temperatures(1)
        assert samples and all("B" in s and "at" in s for s in samples)
        summary = job.print_result["temperatures"]
        assert summary["samples"] == len(samples)
        assert summary["peak"]["B"] >= 59.0 and summary["peak"]["T"] >= 200.0
        d.wait_for(lambda: (p := d.status().get("printer") or {}).get("state") == "connected"
                   and p.get("temperatures") is None, what="no live temperatures after it")
    finally:
        vp.stop()
