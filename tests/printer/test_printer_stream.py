"""Integration: the host against the virtual printer over a real pty, in every firmware
mode, with every fault. Each test checks the printer's own executed-command log."""

from __future__ import annotations

import os
import threading

import pytest
from printer_helpers import FAST, HOST, assert_exactly_once, assert_prefix_once, program, streamed

from printer.errors import (
    PrinterDisconnected,
    PrinterHalted,
    PrinterReset,
    PrinterTimeout,
    StreamCancelled,
)
from printer.gcode import clean_line, clean_lines
from printer.host import PrinterHost
from printer.virtual import Faults, VirtualPrinter

FIRMWARES = ["marlin", "prusa", "buddy", "klipper", "rrf"]


@pytest.mark.parametrize("mode", ["ping-pong", "buffered"])
@pytest.mark.parametrize("firmware", FIRMWARES)
def test_clean_stream_exactly_once(firmware, mode):
    lines = program(200)
    with VirtualPrinter(firmware, **FAST) as vp, PrinterHost(vp.port, vp.baud, mode=mode,
                                                             **HOST) as host:
        result = host.stream(lines)
        assert result.mode == mode
        assert result.resends == 0 and result.timeouts == 0
        assert_exactly_once(vp, lines)


def test_auto_mode_is_buffered_for_known_firmware_and_uses_advanced_ok():
    lines = program(200)
    with VirtualPrinter("marlin", advanced_ok=True, **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        assert host.advanced_ok
        result = host.stream(lines)
        assert result.mode == "buffered"
        assert_exactly_once(vp, lines)


@pytest.mark.parametrize("firmware", ["marlin", "prusa", "buddy"])
@pytest.mark.parametrize("mode", ["ping-pong", "buffered"])
def test_corruption_is_resent_without_duplicates(firmware, mode):
    lines = program(300)
    faults = Faults(corrupt=0.01, seed=7)
    with VirtualPrinter(firmware, faults=faults, **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, mode=mode, **HOST) as host:
        result = host.stream(lines)
        assert vp.stats["line_errors"] > 0 and result.resends > 0
        assert_exactly_once(vp, lines)


def test_rrf_silent_drop_is_recovered_by_timeout():
    lines = program(150)
    with VirtualPrinter("rrf", faults=Faults(corrupt=0.002, seed=5), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        result = host.stream(lines)
        assert vp.stats["silent_drops"] > 0
        assert result.timeouts > 0
        assert_exactly_once(vp, lines)


@pytest.mark.parametrize("firmware", FIRMWARES)
@pytest.mark.parametrize("mode", ["ping-pong", "buffered"])
def test_lost_ok_never_duplicates(firmware, mode):
    lines = program(200)
    with VirtualPrinter(firmware, faults=Faults(drop_ok=0.03, seed=11), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, mode=mode, **HOST) as host:
        result = host.stream(lines)
        assert vp.stats["oks_dropped"] > 0
        # With ADVANCED_OK (Buddy) the next ok's N covers a lost one: no timeout needed.
        assert result.timeouts > 0 or (host.advanced_ok and mode == "buffered")
        assert_exactly_once(vp, lines)


def test_lost_ok_for_executed_line_is_not_replayed_ping_pong():
    """The subtle case: the line ran, only its ok was lost. The host's probe carries the
    same line number, Marlin rejects it as already seen, and nothing runs twice."""
    lines = ["G28", "G1 X1 F3000", "G1 X2", "G1 X3"]
    with VirtualPrinter("marlin", faults=Faults(drop_ok=0.5, seed=2), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, mode="ping-pong", **HOST) as host:
        result = host.stream(lines)
        assert vp.stats["oks_dropped"] > 0 and result.timeouts > 0
        assert vp.stats["line_errors"] > 0  # the probe was refused as a duplicate
        assert_exactly_once(vp, lines)


@pytest.mark.parametrize("firmware", ["marlin", "prusa", "buddy", "rrf"])
def test_busy_keepalive_extends_the_timeout(firmware):
    lines = program(50)
    fast = dict(FAST, keepalive=0.05)
    with VirtualPrinter(firmware, faults=Faults(busy_seconds=1.0), **fast) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        result = host.stream(lines)
        assert_exactly_once(vp, lines)
        if firmware == "rrf":
            assert result.timeouts > 0  # RRF sends no busy: the tickle bridges the wait
        else:
            assert result.timeouts == 0
            assert not [c for n, c in vp.executed_numbered if n is None and c == "M105"]


def test_klipper_long_command_without_keepalive_survives():
    lines = program(30)
    with VirtualPrinter("klipper", faults=Faults(busy_seconds=1.0), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        host.stream(lines)
        assert_exactly_once(vp, lines)


@pytest.mark.parametrize("firmware", ["marlin", "prusa", "buddy", "rrf"])
def test_reset_mid_job_aborts_with_clear_error(firmware):
    lines = program(200)
    with VirtualPrinter(firmware, faults=Faults(reset_after=40), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        with pytest.raises(PrinterReset, match="reset itself"):
            host.stream(lines)
        assert assert_prefix_once(vp, lines) == 40


def test_klipper_mcu_loss_is_fatal():
    lines = program(100)
    with VirtualPrinter("klipper", faults=Faults(reset_after=20), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        with pytest.raises(PrinterHalted, match="Lost communication"):
            host.stream(lines)
        assert assert_prefix_once(vp, lines) == 20


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_unplug_gives_disconnected(firmware):
    lines = program(200)
    with VirtualPrinter(firmware, faults=Faults(disconnect_after=30), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        with pytest.raises(PrinterDisconnected, match="lost the printer|disappeared"):
            host.stream(lines)
        assert assert_prefix_once(vp, lines) == 30


def test_replug_on_new_pty_through_the_link(tmp_path):
    link = tmp_path / "usb-Virtual_Printer-if00"
    lines = program(100)
    faults = Faults(disconnect_after=10, reconnect_after=0.3)
    with VirtualPrinter("marlin", faults=faults, link=link, **FAST) as vp:
        assert os.readlink(link) == vp.slave_path
        with PrinterHost(str(link), vp.baud, **HOST) as host:
            with pytest.raises(PrinterDisconnected):
                host.stream(lines)
        before = len(streamed(vp))
        for _ in range(200):  # the printer comes back after 0.3 s
            if vp.generation == 2:
                break
            threading.Event().wait(0.05)
        assert vp.generation == 2
        assert os.readlink(link) == vp.slave_path
        with PrinterHost(str(link), vp.baud, **HOST) as host:
            host.stream(lines)
        again = streamed(vp)[before:]
        assert [n for n, _ in again] == list(range(1, len(again) + 1))
        assert [c for _, c in again] == [c for c in map(clean_line, lines) if c]


def test_printer_that_stops_answering_fails_after_bounded_retries():
    lines = program(200)
    with VirtualPrinter("marlin", **FAST) as vp:
        with PrinterHost(vp.port, vp.baud, retries=2, **HOST) as host:
            def mute(done, total):
                if done >= 1:
                    vp.faults = Faults(drop_ok=1.0)  # from now on the printer never says ok

            with pytest.raises(PrinterTimeout, match="stopped answering") as err:
                host.stream(lines, progress=mute)
        assert_prefix_once(vp, lines)
        # The error tells the caller how far the job got onto the wire, so a daemon
        # never treats a job whose lines the firmware may have run as "not started".
        ran = sum(1 for n, _ in vp.executed_numbered if n is not None and n >= 1)
        assert err.value.lines_sent >= ran >= 1



def test_cancel_sends_cooldown_and_motors_off():
    lines = program(400)
    cancel = threading.Event()

    def progress(done, total):
        if done >= 50:
            cancel.set()

    with VirtualPrinter("marlin", **dict(FAST, baud=115200)) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        with pytest.raises(StreamCancelled, match="heaters off"):
            host.stream(lines, progress=progress, cancel=cancel)
        ran = assert_prefix_once(vp, lines)
        assert 50 <= ran < 400
        tail = [c for n, c in vp.executed_numbered if n is None][-4:]
        assert tail == ["M104 S0", "M140 S0", "M107", "M84"]


def test_emergency_stop_halts_and_next_stream_fails():
    with VirtualPrinter("marlin", **FAST) as vp, PrinterHost(vp.port, vp.baud, **HOST) as host:
        host.emergency_stop()
        with pytest.raises(PrinterHalted, match="kill"):
            host.stream(program(10))
        assert vp.executed[-1] == "M112"


def test_progress_reaches_total():
    lines = program(100)
    seen = []
    with VirtualPrinter("buddy", **FAST) as vp, PrinterHost(vp.port, vp.baud, **HOST) as host:
        host.stream(lines, progress=lambda d, t: seen.append((d, t)))
    total = seen[-1][1]
    assert seen[-1] == (total, total)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)


@pytest.mark.slow
def test_20000_lines_with_corruption_and_lost_oks():
    lines = [f"G1 X{i % 200}.{i % 10} Y{(i * 7) % 200}.5 E{i * 0.01:.3f} F6000"
             for i in range(20000)]
    faults = Faults(corrupt=0.01, drop_ok=0.005, seed=20000)
    # buffered, the harder case: up to 4 lines in flight, so every error has echoes
    with VirtualPrinter("marlin", faults=faults, **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, mode="buffered",
                        **dict(HOST, timeout=0.1, nudge=0.03)) as host:
        result = host.stream(lines)
        assert result.lines == 20000
        assert vp.stats["bytes_corrupted"] > 1000 and vp.stats["oks_dropped"] > 50
        assert_exactly_once(vp, lines)


def test_temperature_auto_reports_do_not_hide_a_lost_ok():
    """M155 reports arrive all the time; they must not count as the printer answering."""
    lines = program(150)
    with VirtualPrinter("marlin", faults=Faults(drop_ok=0.03, seed=4), **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        host.query("M155 S0.05")
        result = host.stream(lines)
        assert result.timeouts > 0
        assert_exactly_once(vp, lines)


@pytest.mark.parametrize("mode", ["ping-pong", "buffered"])
def test_rejected_m110_is_sent_again_before_the_next_stream(mode):
    # Found by the soak (bench/soak.py) on a noisy line: the M110 that starts a stream
    # was rejected (Error + Resend + ok) and the host took that ok as the M110's, so the
    # printer still expected the previous print's next line number and refused every
    # line of the new print, while the host counted lines as delivered.
    first, second = program(20), program(30)
    with VirtualPrinter("marlin", **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, mode=mode, **HOST) as host:
        host.stream(first)
        executed_before = len(streamed(vp))
        host._serial.write(b"X")  # a noise byte glued to the front of the next line
        result = host.stream(second)
        assert result.lines == len(clean_lines(second))
        again = streamed(vp)[executed_before:]
        assert [n for n, _ in again] == list(range(1, len(clean_lines(second)) + 1))
        assert [c for _, c in again] == clean_lines(second)
