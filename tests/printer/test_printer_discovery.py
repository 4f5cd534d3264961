"""Port discovery over real ptys: a virtual printer run as its own process, found at
250000 baud in a folder of links laid out like /dev/serial/by-id; ports that answer
garbage, nothing, or are no serial port at all are reported with a reason."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import threading
import time
import tty

import pytest
import tomli_w

from printer.discovery import candidate_ports, discover, remember, remembered_choice
from printer.discovery import default_host as probe_hosts
from printer.virtual import Faults, VirtualPrinter


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon", *args], capture_output=True,
                          text=True, timeout=300)


@pytest.fixture
def printer_process(tmp_path):
    """``preflight virtual-printer`` at 250000 baud in another process, linked as
    ``by-id/usb-Virtual_Marlin-if00``; yields the link."""
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    link = by_id / "usb-Virtual_Marlin-if00"
    proc = subprocess.Popen(
        [sys.executable, "-m", "daemon", "virtual-printer", "--baud", "250000",
         "--speedup", "1000", "--link", str(link)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    slave = proc.stdout.readline().strip()
    assert slave.startswith("/dev/"), proc.stderr.read()
    yield link
    proc.terminate()
    proc.wait(timeout=10)


def test_printer_list_finds_a_printer_it_did_not_start_at_250000_baud(printer_process,
                                                                      tmp_path):
    acm = tmp_path / "ttyACM0"
    os.symlink(os.readlink(printer_process), acm)  # the same device under a second name
    out = cli("printer", "list", "--scan", str(tmp_path / "by-id" / "*"),
              "--scan", str(tmp_path / "ttyACM*"))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 1, lines  # one device, one line: the by-id name is kept
    line = lines[0]
    assert line.startswith(f"{printer_process} -> /dev/")
    assert ": taken: Marlin 2.1.2.1" in line and "at 250000 baud" in line
    # 115200 is tried first; the printer's reply at the wrong speed is noise
    assert "garbage at 115200" in line
    # without --scan it looks where the daemon's config says, and exits 1 if nothing
    config = tmp_path / "preflight.toml"
    config.write_text(tomli_w.dumps({"printer": {"scan": [str(tmp_path / "ttyACM*")]},
                                     "daemon": {"state_dir": str(tmp_path / "state")}}))
    out = cli("printer", "list", "--config", str(config), "--baud", "250000")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"{acm} -> /dev/") and ": taken: Marlin" in out.stdout
    (tmp_path / "empty").mkdir()
    config.write_text(tomli_w.dumps({"printer": {"scan": [str(tmp_path / "empty" / "*")]}}))
    out = cli("printer", "list", "--config", str(config))
    assert out.returncode == 1
    assert out.stdout.strip() == f"no printer found: no serial port matches {tmp_path}/empty/*"


def test_candidates_that_answer_garbage_or_nothing_are_reported(tmp_path):
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    noisy = VirtualPrinter(baud=115200, faults=Faults(garbage=True),
                           link=by_id / "usb-Noisy-if00")
    noisy.start()
    master, slave = os.openpty()  # a serial port with nothing behind it
    tty.setraw(slave)
    os.symlink(os.ttyname(slave), by_id / "usb-Silent-if00")
    (tmp_path / "notes.txt").write_text("not a serial port\n")
    os.symlink(tmp_path / "notes.txt", by_id / "usb-File-if00")
    try:
        found = discover([str(by_id / "*")], (115200, 57600), make_host=probe_hosts(1.5),
                         scan_all=True)
    finally:
        noisy.stop()
        os.close(master)
        os.close(slave)
    reasons = {os.path.basename(c.path): c for c in found.candidates}
    assert set(reasons) == {"usb-Noisy-if00", "usb-Silent-if00", "usb-File-if00"}
    assert found.chosen is None and found.host is None
    assert "only garbage at 115200, 57600 baud" in reasons["usb-Noisy-if00"].reason
    assert "no answer to M110/M115 at 115200, 57600 baud" in reasons["usb-Silent-if00"].reason
    assert "cannot open" in reasons["usb-File-if00"].reason
    assert all("\n" not in c.line() and ": not taken: " in c.line() for c in found.candidates)
    assert found.summary().startswith("no printer found on 3 port(s): ")


def test_the_remembered_port_is_tried_first_at_its_baud(tmp_path):
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    first = VirtualPrinter(baud=57600, link=by_id / "usb-A-if00")
    second = VirtualPrinter(firmware="prusa", baud=57600, link=by_id / "usb-B-if00")
    first.start()
    second.start()
    try:
        assert [p for p, _ in candidate_ports([str(by_id / "*")])] == [
            str(by_id / "usb-A-if00"), str(by_id / "usb-B-if00")]
        found = discover([str(by_id / "*")], (57600,), make_host=probe_hosts(3.0),
                         scan_all=True)
        assert found.chosen.path == str(by_id / "usb-A-if00")
        assert "another printer was taken first" in found.candidates[1].reason
        remember(tmp_path / "state", found.chosen)
        # next time B is remembered (e.g. the user moved the cable): B first, at 57600
        remember(tmp_path / "state", found.candidates[1])
        choice = remembered_choice(tmp_path / "state")
        assert choice == {"port": str(by_id / "usb-B-if00"), "baud": 57600,
                          "firmware": found.candidates[1].firmware}
        again = discover([str(by_id / "*")], (115200, 57600), remembered=choice,
                         make_host=probe_hosts(3.0), keep_open=True)
        try:
            assert again.chosen.path == str(by_id / "usb-B-if00")
            assert again.chosen.firmware.startswith("Prusa-Firmware")
            assert "garbage" not in again.chosen.reason  # 57600 tried first: no detour
            assert len(again.candidates) == 1  # found at once: A was not probed
            assert again.host.query("M105")[-1].startswith("ok")  # handed over open
        finally:
            again.host.close()
    finally:
        first.stop()
        second.stop()


class BootingBoard(threading.Thread):
    """A board that reboots as the port opens: its bootloader swallows what arrives
    for ``boot`` seconds, then it prints ``start`` and answers M110 and M115 (a test
    double of the serial side of an Arduino-style printer board)."""

    def __init__(self, link, boot: float) -> None:
        super().__init__(daemon=True)
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.slave = slave
        os.symlink(os.ttyname(slave), link)
        self.boot = boot
        self.heard_before_start: list[bytes] = []
        self.stop = threading.Event()

    def run(self) -> None:
        booted_at = time.monotonic() + self.boot
        booted = False
        pending = b""
        while not self.stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not booted and time.monotonic() >= booted_at:
                os.write(self.master, b"start\necho:Marlin 2.1.2 booted\n")
                booted = True
            if not ready:
                continue
            data = os.read(self.master, 1024)
            if not booted:
                self.heard_before_start.append(data)  # lost in the bootloader
                continue
            pending += data
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                if b"M115" in line:
                    os.write(self.master, b"FIRMWARE_NAME:Marlin 2.1.2 (booting board)\nok\n")
                elif line.strip():
                    os.write(self.master, b"ok\n")

    def close(self) -> None:
        self.stop.set()
        self.join(timeout=5)
        os.close(self.master)
        os.close(self.slave)


def test_a_board_that_resets_on_open_is_waited_for(tmp_path):
    """The greeting sent while the board boots is lost; after ``start`` it is sent
    again (then M110), and the board is found."""
    board = BootingBoard(tmp_path / "ttyACM0", boot=1.5)
    board.start()
    try:
        found = discover([str(tmp_path / "ttyACM*")], (115200,), make_host=probe_hosts(6.0))
    finally:
        board.close()
    assert board.heard_before_start, "the host spoke before the board had booted"
    assert found.chosen is not None, found.summary()
    assert found.chosen.firmware == "Marlin 2.1.2 (booting board)"
