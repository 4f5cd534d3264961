"""Real-time heat-ups over a real pty: the host waits for M190/M109 as long as the
physics needs, on every firmware family, and still recovers a lost ``ok`` in seconds.

The virtual printer heats with its real-time model (a bed to 60 °C in about 35 s and
a hotend to 210 °C in about 45 s of printer time), sped up for the default run with
the host's timeouts scaled by the same factor; the heat-up then lasts several times
as long as the host's old give-up time (its timeout times its tries). The slow test
runs with the host's real timeouts (4 s, 4 retries: 20 s) and a heat-up of 40 s of
wall time.
"""

from __future__ import annotations

import time

import pytest
from printer_helpers import assert_exactly_once, streamed

from printer.gcode import clean_lines
from printer.host import PrinterHost
from printer.virtual import Faults, VirtualPrinter

FIRMWARES = ("marlin", "prusa", "klipper", "rrf")
SPEEDUP = 20.0  # printer seconds per wall second in the default run
#: The host's timeouts scaled like the printer's clock: 0.25 s is 5 s of printer time.
SCALED_HOST = {"timeout": 0.25, "retries": 2, "resend_settle": 0.002, "handshake_timeout": 3.0}


def heat_program(firmware: str, moves: int = 40) -> list[str]:
    """A print's start as a slicer writes it for ``firmware``: bed, then hotend, then
    home and prime; then moves with a few M400 waits; then cool down."""
    start = ["M140 S60", "M190 S60", "M104 S210", "M109 S210"]
    if firmware == "rrf":
        start += ["M116"]  # RepRapFirmware start code waits for all heaters again
    lines = [f"; start for {firmware}", *start, "G28", "G90", "M82", "G92 E0", "G1 Z0.2 F3000"]
    e = 0.0
    for i in range(moves):
        e += 0.02
        lines.append(f"G1 X{20 + (i * 7) % 30} Y{20 + (i * 11) % 30} E{e:.3f} F9000")
        if i % 20 == 19:
            lines.append("M400")
    return lines + ["M104 S0", "M140 S0", "M84"]


class Recorder:
    """The stream's temperature reports, with the wall time they came."""

    def __init__(self) -> None:
        self.readings: list[tuple[float, dict]] = []

    def __call__(self, readings: dict) -> None:
        self.readings.append((time.monotonic(), readings))

    def bed(self) -> list[tuple[float, float | None]]:
        return [r["B"] for _, r in self.readings if "B" in r]

    def hotend(self) -> list[tuple[float, float | None]]:
        return [r["T"] for _, r in self.readings if "T" in r]


def stream_heat(firmware: str, *, speedup: float, host_kw: dict, faults: Faults | None = None,
                long_command_timeout: float = 900.0):
    lines = heat_program(firmware)
    record = Recorder()
    with VirtualPrinter(firmware, speedup=speedup, baud=250000,
                        keepalive=1.0 / speedup) as vp:
        with PrinterHost(vp.port, vp.baud, long_command_timeout=long_command_timeout,
                         **host_kw) as host:
            if faults is not None:
                vp.faults = faults
            started = time.monotonic()
            result = host.stream(lines, temperatures=record)
            seconds = time.monotonic() - started
        assert_exactly_once(vp, lines)
        unnumbered = [c for n, c in vp.executed_numbered if n is None]
        stats = dict(vp.stats)
    return result, seconds, record, unnumbered, stats


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_real_time_heat_up_prints_every_line_once(firmware):
    result, seconds, record, unnumbered, _ = stream_heat(
        firmware, speedup=SPEEDUP, host_kw=SCALED_HOST)
    # The premise: ~80 s of printer time of heating, several times what the host used to
    # wait before giving up (timeout x (retries + 1)), here in wall time.
    give_up = SCALED_HOST["timeout"] * (SCALED_HOST["retries"] + 1)
    assert seconds > 3 * give_up
    if firmware in ("rrf", "klipper"):
        # Silent waits (RRF's heat-ups, Klipper's G28 and M400): at most one probe M105
        # each, never a retry; RRF's seconds-long silent heat-ups always get one.
        assert result.timeouts == unnumbered.count("M105")
        assert result.timeouts >= 1 or firmware == "klipper"
    else:
        assert result.timeouts == 0 and "M105" not in unnumbered
    if firmware != "rrf":
        # The keep-alives carried the heat-up to the caller: rising, with the target.
        bed = [c for c, target in record.bed() if target == 60.0]
        hotend = [c for c, target in record.hotend() if target == 210.0]
        assert len(bed) >= 10 and len(hotend) >= 10
        assert bed[0] < 40.0 and max(bed) >= 55.0
        assert hotend[0] < 150.0 and max(hotend) >= 200.0


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_lost_ok_next_to_long_commands_is_recovered_quickly(firmware):
    lines = clean_lines(heat_program(firmware))
    # Lose the ok of M109 itself, of the line before the first M400, and of that M400.
    m109 = lines.index("M109 S210") + 1
    m400 = lines.index("M400") + 1
    faults = Faults(drop_ok_at=frozenset({m109, m400 - 1, m400}))
    # A host that mistook the lost ok for a running long command would wait for
    # long_command_timeout and fail; the ordinary recovery takes a few timeouts.
    result, _, _, _, stats = stream_heat(firmware, speedup=SPEEDUP, host_kw=SCALED_HOST,
                                         faults=faults, long_command_timeout=120.0)
    assert stats["oks_dropped"] >= 2
    assert result.timeouts >= 1


def test_firmware_that_dies_while_heating_is_detected():
    """Klipper stops sending its temperature lines mid heat-up and never answers again:
    the ordinary recovery gives up after its retries, not after long_command_timeout."""
    from printer.errors import PrinterTimeout

    lines = heat_program("klipper")
    with VirtualPrinter("klipper", speedup=SPEEDUP, baud=250000, keepalive=0.05) as vp:
        with PrinterHost(vp.port, vp.baud, **SCALED_HOST) as host:
            def die(readings: dict) -> None:
                if readings.get("B", (0, 0))[0] > 40.0:
                    vp.machine.halted = True  # silent from now on, answers nothing

            with pytest.raises(PrinterTimeout, match="stopped answering"):
                host.stream(lines, temperatures=die)
        assert len(streamed(vp)) < len(clean_lines(lines))


@pytest.mark.slow
@pytest.mark.parametrize("firmware", ["klipper", "rrf"])
def test_heat_up_with_the_hosts_real_timeouts(firmware):
    """The host's defaults (4 s timeout, 4 retries: it used to give up after 20 s) and
    a heat-up of ~40 s of wall time."""
    result, seconds, _, _, _ = stream_heat(firmware, speedup=2.0, host_kw={})
    assert seconds > 25.0
    assert result.lines == len(clean_lines(heat_program(firmware)))
