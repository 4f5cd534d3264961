"""The unit file passes systemd-analyze verify; sd_notify reaches a real socket."""

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.notify import notify, watchdog_interval

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "preflight.service"


def test_unit_has_the_required_settings():
    text = UNIT.read_text()
    for line in ("Type=notify", "Restart=on-failure", "User=preflight",
                 "SupplementaryGroups=dialout", "ProtectSystem=strict", "NoNewPrivileges=true",
                 "PrivateTmp=true"):
        assert f"\n{line}\n" in text, line
    assert "\nWatchdogSec=" in text
    rw = [x for x in text.splitlines() if x.startswith("ReadWritePaths=")][0]
    assert "/var/spool/preflight" in rw and "/var/lib/preflight" in rw


def test_systemd_analyze_verify(tmp_path):
    exe = shutil.which("systemd-analyze")
    if exe is None:
        pytest.skip("systemd-analyze is not installed")
    # ExecStart must name an existing binary at verify time: point it at this install.
    preflight = Path(sys.executable).with_name("preflight")
    if not preflight.exists():
        pytest.skip("the preflight console script is not installed next to python")
    text = UNIT.read_text().replace("/opt/preflight/.venv/bin/preflight", str(preflight))
    unit = tmp_path / "preflight.service"
    unit.write_text(text)
    out = subprocess.run([exe, "verify", str(unit)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "preflight.service" not in out.stderr, out.stderr


def test_notify_datagram(tmp_path, monkeypatch):
    addr = str(tmp_path / "notify.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
        s.bind(addr)
        monkeypatch.setenv("NOTIFY_SOCKET", addr)
        assert notify("READY=1\nSTATUS=idle")
        assert s.recv(4096) == b"READY=1\nSTATUS=idle"
    monkeypatch.delenv("NOTIFY_SOCKET")
    assert notify("READY=1") is False


def test_watchdog_interval(monkeypatch):
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    assert watchdog_interval() is None
    monkeypatch.setenv("WATCHDOG_USEC", "60000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert watchdog_interval() == 30.0
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid() + 1))
    assert watchdog_interval() is None
