"""The printer CLI as a user runs it: a virtual printer in one process, the host in another."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from printer_helpers import program

from printer.gcode import clean_lines


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon", *args], capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture
def virtual_printer(tmp_path):
    """Start ``preflight virtual-printer`` with a link and a log; yield (link, log, proc)."""
    procs = []

    def start(*extra: str):
        link = tmp_path / f"ttyVIRTUAL{len(procs)}"
        log = tmp_path / f"executed{len(procs)}.log"
        proc = subprocess.Popen(
            [sys.executable, "-m", "daemon", "virtual-printer", "--speedup", "100000",
             "--baud", "250000", "--link", str(link), "--log", str(log), *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        procs.append(proc)
        slave = proc.stdout.readline().strip()
        assert slave.startswith("/dev/")
        assert os.readlink(link) == slave
        return str(link), log, proc

    yield start
    for proc in procs:
        proc.terminate()
        proc.wait(timeout=10)


def test_print_file_exactly_once(virtual_printer, tmp_path):
    port, log, _ = virtual_printer()
    gcode = tmp_path / "part.gcode"
    lines = program(300)
    gcode.write_text("\n".join(lines) + "\n")
    out = cli("print", str(gcode), "--port", port, "--baud", "250000")
    assert out.returncode == 0, out.stderr
    executed = log.read_text().splitlines()
    # the log also holds the host's handshake (M110/M115); the print is its tail
    assert executed[-len(clean_lines(lines)):] == clean_lines(lines)
    assert executed.count("G28") == 1


def test_printer_info_json(virtual_printer):
    port, _, _ = virtual_printer("--firmware", "buddy", "--nozzle", "0.6")
    out = cli("printer", "info", "--port", port, "--baud", "250000", "--json")
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    for key in ("firmware", "nozzle_diameter", "nozzle_source", "build_volume",
                "filament_diameter", "capabilities"):
        assert key in info
    assert info["nozzle_diameter"] == 0.6 and info["nozzle_source"] == "M862.1"
    assert info["build_volume"] == [250.0, 210.0, 220.0]


def test_print_fails_with_one_line_on_reset(virtual_printer, tmp_path):
    port, _, _ = virtual_printer("--reset-after", "20")
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(program(200)))
    out = cli("print", str(gcode), "--port", port, "--baud", "250000")
    assert out.returncode != 0
    assert out.stderr.startswith("preflight: ") and "reset" in out.stderr
    assert out.stderr.count("\n") == 1


def test_print_to_missing_port(tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\n")
    out = cli("print", str(gcode), "--port", str(tmp_path / "ttyACM9"))
    assert out.returncode != 0
    assert out.stderr == f"preflight: no serial port at {tmp_path / 'ttyACM9'} " \
        "(is the printer plugged in and switched on?)\n"


def test_sigint_cancels_with_cooldown(virtual_printer, tmp_path):
    port, log, _ = virtual_printer()
    gcode = tmp_path / "long.gcode"
    # slow moves (1 mm/s) so the print is still running when the signal comes
    gcode.write_text("G28\n" + "\n".join(f"G1 X{i % 2 * 50} F60" for i in range(2000)) + "\n")
    proc = subprocess.Popen([sys.executable, "-m", "daemon", "print", str(gcode), "--port",
                             port, "--baud", "250000"], stderr=subprocess.PIPE, text=True)
    for _ in range(200):
        if Path(log).exists() and "G28" in Path(log).read_text():
            break
        time.sleep(0.05)
    proc.send_signal(2)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0
    assert "cancelled" in err
    assert log.read_text().splitlines()[-4:] == ["M104 S0", "M140 S0", "M107", "M84"]


def test_progress_line_on_a_terminal(virtual_printer, tmp_path):
    port, _, _ = virtual_printer()
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(program(1500)) + "\n")
    master, slave = os.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "daemon", "print", str(gcode), "--port",
                             port, "--baud", "250000"], stderr=slave)
    os.close(slave)
    seen = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:
            break
        if not chunk:
            break
        seen += chunk
    os.close(master)
    assert proc.wait(timeout=60) == 0
    text = seen.decode()
    assert "\rprinting" in text and "lines/s" in text and "ETA" in text
    assert "100.0%" in text


def test_print_applies_the_daemon_policy(virtual_printer, tmp_path):
    """``preflight print`` refuses what the daemon refuses, before sending a line of it."""
    port, log, _ = virtual_printer()
    forbidden = tmp_path / "sd.gcode"
    forbidden.write_text("G28\nG1 X10 Y10\nM 28 evil.gco ; write to the SD card\nG1 X20\n")
    out = cli("print", str(forbidden), "--port", port, "--baud", "250000")
    assert out.returncode == 1
    assert "M28" in out.stderr and "--allow-firmware-commands" in out.stderr
    assert not log.exists() or "G28" not in log.read_text().split()
    # an arc whose end points are on the bed but whose sweep leaves it (X to 270 mm)
    arc = tmp_path / "arc.gcode"
    arc.write_text("G28\nG90\nG1 X220 Y50 Z1\nG3 X220 Y150 I0 J50\nG1 X10\n")
    out = cli("print", str(arc), "--port", port, "--baud", "250000")
    assert out.returncode == 1 and "X from" in out.stderr and "outside" in out.stderr
    assert "G28" not in log.read_text().splitlines()  # only the host's queries ran
    # the override sends a firmware command (M500 here) as written
    allowed = tmp_path / "save.gcode"
    allowed.write_text("G28\nG1 X10 Y10\nM500\nG1 X20\n")
    out = cli("print", str(allowed), "--port", port, "--baud", "250000",
              "--allow-firmware-commands")
    assert out.returncode == 0, out.stderr
    assert log.read_text().splitlines()[-4:] == ["G28", "G1 X10 Y10", "M500", "G1 X20"]
