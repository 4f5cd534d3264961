"""Opening the port, the handshake and capability queries, against real ptys."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from printer_helpers import FAST, HOST

from printer.errors import PortBusy, PortNotFound, PortPermission, PrinterTimeout, WrongBaud
from printer.host import PrinterHost
from printer.virtual import Faults, VirtualPrinter


def test_missing_port(tmp_path):
    with pytest.raises(PortNotFound, match="no serial port at .*ttyNOPE") as info:
        PrinterHost(str(tmp_path / "ttyNOPE"), **HOST).connect()
    assert "\n" not in str(info.value)


def test_dangling_link_is_missing(tmp_path):
    link = tmp_path / "usb-gone"
    os.symlink(tmp_path / "nothing", link)
    with pytest.raises(PortNotFound):
        PrinterHost(str(link), **HOST).connect()


@pytest.mark.skipif(os.geteuid() == 0, reason="root may open any device")
def test_permission_denied():
    with VirtualPrinter(**FAST) as vp:
        os.chmod(vp.slave_path, 0o000)
        with pytest.raises(PortPermission, match="permission denied .*dialout"):
            PrinterHost(vp.port, vp.baud, **HOST).connect()


def test_permission_denied_message_as_root_too(tmp_path, monkeypatch):
    """Root bypasses file modes, so also drive the error path through pyserial's own
    failure for a path that refuses opening (a directory is not a tty)."""
    import serial

    def refuse(*args, **kwargs):
        raise serial.SerialException(13, "could not open port: [Errno 13] Permission denied")

    monkeypatch.setattr(serial, "Serial", refuse)
    port = tmp_path / "ttyUSB0"
    port.touch()
    with pytest.raises(PortPermission, match="permission denied"):
        PrinterHost(str(port), **HOST).connect()


def test_port_busy_in_same_process():
    with VirtualPrinter(**FAST) as vp, PrinterHost(vp.port, vp.baud, **HOST):
        with pytest.raises(PortBusy, match="busy"):
            PrinterHost(vp.port, vp.baud, **HOST).connect()


def test_port_busy_from_another_process():
    with VirtualPrinter(**FAST) as vp, PrinterHost(vp.port, vp.baud, **HOST):
        out = subprocess.run(
            [sys.executable, "-m", "daemon", "printer", "info", "--port", vp.port],
            capture_output=True, text=True, timeout=60,
        )
    assert out.returncode != 0
    assert out.stderr.startswith("preflight: ") and "busy" in out.stderr
    assert out.stderr.count("\n") == 1


def test_garbage_means_wrong_baud():
    with VirtualPrinter(faults=Faults(garbage=True), **FAST) as vp:
        host = PrinterHost(vp.port, vp.baud, **dict(HOST, handshake_timeout=1.5))
        with pytest.raises(WrongBaud, match="baud rate is probably wrong"):
            host.connect()


def test_baud_mismatch_on_the_tty_means_wrong_baud():
    with VirtualPrinter(baud=57600, speedup=1e6) as vp:
        host = PrinterHost(vp.port, 115200, **dict(HOST, handshake_timeout=1.5))
        with pytest.raises(WrongBaud, match="115200 baud"):
            host.connect()


def test_silence_is_a_timeout_that_mentions_baud(tmp_path):
    master, slave = os.openpty()
    try:
        host = PrinterHost(os.ttyname(slave), **dict(HOST, handshake_timeout=1.0))
        with pytest.raises(PrinterTimeout, match="baud rate"):
            host.connect()
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    ("firmware", "kwargs", "nozzle", "source", "volume", "volume_source", "filament_source"),
    [
        ("marlin", {}, 0.4, "default", [250.0, 210.0, 220.0], "M211", "M200"),
        ("marlin", {"nozzle_fallback": 0.6}, 0.6, "config", [250.0, 210.0, 220.0], "M211",
         "M200"),
        ("prusa", {}, 0.6, "M862.1", [250.0, 210.0, 210.0], "machine type", "default"),
        ("buddy", {}, 0.6, "M862.1", [250.0, 210.0, 220.0], "M211", "M200"),
        ("klipper", {"nozzle_macro": "NOZZLE_DIAMETER"}, 0.6, "macro:NOZZLE_DIAMETER", None,
         None, "default"),
        ("klipper", {}, 0.4, "default", None, None, "default"),
        ("rrf", {"nozzle_fallback": 0.8}, 0.8, "config", [250.0, 210.0, 220.0],
         'M409 K"move.axes"', "default"),
    ],
)
def test_query_info(firmware, kwargs, nozzle, source, volume, volume_source, filament_source):
    with VirtualPrinter(firmware, nozzle=0.6, **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST, **kwargs) as host:
        info = host.query_info().to_dict()
    assert info["flavour"] == firmware
    assert info["nozzle_diameter"] == nozzle and info["nozzle_source"] == source
    assert info["build_volume"] == volume and info["build_volume_source"] == volume_source
    assert info["filament_diameter"] == 1.75 and info["filament_source"] == filament_source
    for key in ("firmware", "capabilities"):
        assert key in info
    # read-only: a nozzle check that could open a dialog on a Prusa is never sent
    assert not [c for c in vp.executed if c.upper().startswith("M862.1 P")]


def test_build_volume_follows_the_printer():
    with VirtualPrinter("marlin", build_volume=(300, 300, 400), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        assert host.area["work"][1] == (300.0, 300.0, 400.0)
        info = host.query_info()
    assert info.build_volume == [300.0, 300.0, 400.0]


def test_unknown_command_to_marlin_is_graceful():
    with VirtualPrinter("marlin", **FAST) as vp, PrinterHost(vp.port, vp.baud, **HOST) as host:
        reply = host.query("M862.1 Q")
        assert reply[-1] == "ok"
        assert 'Unknown command: "M862.1 Q"' in reply[0]
