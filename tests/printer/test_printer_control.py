"""Print control over a real pty against the virtual printer: pause/resume, cancel,
emergency stop, the printer's host actions and firmware halts; and their reply parsers."""

from __future__ import annotations

import threading
import time

import pytest
from printer_helpers import FAST, HOST, assert_exactly_once, assert_prefix_once, program, streamed

from printer.control import ParkSettings, PrintControl
from printer.errors import EmergencyStopped, PrinterHalted, StreamCancelled
from printer.gcode import clean_lines, lex
from printer.host import PrinterHost
from printer.replies import host_action, parse_position, parse_reply, waiting_for_user
from printer.virtual import Faults, VirtualPrinter

# --- the parsers, on real reply strings ----------------------------------------------------

@pytest.mark.parametrize("line, expected", [
    ("//action:pause", ("pause", "")),                      # Marlin HOST_ACTION_COMMANDS
    ("//action:paused", ("paused", "")),
    ("//action:resumed", ("resumed", "")),
    ("//action:cancel", ("cancel", "")),
    ("//action:paused filament_runout", ("paused", "filament_runout")),
    ("// action:pause", ("pause", "")),                     # Prusa MK3
    ("// action:resume", ("resume", "")),
    ("// action:cancel", ("cancel", "")),                   # Klipper RESPOND TYPE=command
    ("//action:prompt_begin FilamentRunout T0", None),      # a prompt asks nothing of a print
    ("//action:notification Heating...", None),
    ("//action:out_of_filament T0", None),
    ("// Klipper state: Ready", None),
    ("echo:busy: processing", None),
    ("ok", None),
])
def test_host_actions(line, expected):
    assert host_action(line) == expected


@pytest.mark.parametrize("line, waiting", [
    ("echo:busy: paused for user", True), ("echo:busy: paused for input", True),
    ("busy: paused for user", True), ("echo:busy: processing", False),
    ("T:210.0 /210.0 B:60.0 /60.0 W:?", False),
])
def test_waiting_for_user(line, waiting):
    assert waiting_for_user(line) is waiting


@pytest.mark.parametrize("line, expected", [
    ("X:10.00 Y:20.00 Z:0.20 E:1.23 Count X:800 Y:1600 Z:80",
     {"X": 10.0, "Y": 20.0, "Z": 0.2, "E": 1.23}),
    ("X:0.00 Y:0.00 Z:0.15 E:0.00 Count X: 0.00 Y:0.00 Z:0.15 E:0.00",   # Prusa MK3
     {"X": 0.0, "Y": 0.0, "Z": 0.15, "E": 0.0}),
    ("X:117.500 Y:-3.000 Z:5.200 E:-2.000",                              # Klipper
     {"X": 117.5, "Y": -3.0, "Z": 5.2, "E": -2.0}),
    ("X:10.000 Y:20.000 Z:0.200 E:1.230 E0:1.2 Count 800 1600 80 Machine 10.000 20.000 0.200 "
     "Bed comp 0.000", {"X": 10.0, "Y": 20.0, "Z": 0.2, "E": 1.23}),     # RepRapFirmware
    ("ok T:210.0 /210.0", None),
    ("X:10 Y:20", None),
])
def test_parse_position(line, expected):
    assert parse_position(line) == expected


@pytest.mark.parametrize("line", [
    "Error:Printer halted. kill() called!",
    "Error:Thermal Runaway, system stopped! Heater_ID: 0",
    "Error:Thermal Runaway, system stopped! Heater_ID: bed",
    "Error:Heating failed, system stopped! Heater_ID: 0",
    "Error:MINTEMP triggered, system stopped! Heater_ID: 0",
    "Error:MAXTEMP triggered, system stopped! Heater_ID: bed",
    "!! Shutdown due to M112 command",
    "!! Heater extruder not heating at expected rate",
    "Printer halted. kill() called!",
])
def test_firmware_halts_are_fatal(line):
    assert parse_reply(line).kind == "fatal"


# --- over the pty ---------------------------------------------------------------------------

def run_stream(vp, lines, control, *, at=None, action=None, mode="buffered"):
    """Stream ``lines`` in a thread; ask ``action`` once ``at`` lines are acknowledged.
    Returns (thread, box) where box holds the result or the exception."""
    box: dict = {}
    asked = []

    def progress(done, total):
        if at is not None and done >= at and not asked:
            asked.append(done)
            control.ask(action)

    def go():
        try:
            with PrinterHost(vp.port, vp.baud, mode=mode, **HOST) as host:
                box["result"] = host.stream(lines, progress=progress, control=control)
        except Exception as exc:  # noqa: BLE001 - handed to the test
            box["error"] = exc

    thread = threading.Thread(target=go, daemon=True)
    thread.start()
    return thread, box


def wait_until(predicate, patience=30.0):
    end = time.monotonic() + patience
    while not predicate() and time.monotonic() < end:
        time.sleep(0.01)
    return predicate()


def pause_point(commands, upto):
    """The logical X, Y, Z, E after ``commands[:upto]`` (the test program is absolute)."""
    pos = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
    for command in commands[:upto]:
        lexed = lex(command)
        if lexed.word in ("G1", "G0", "G92"):
            for axis in "XYZE":
                if lexed.value(axis) is not None:
                    pos[axis] = lexed.value(axis)
    return pos


@pytest.mark.parametrize("firmware, mode", [("marlin", "buffered"), ("prusa", "ping-pong"),
                                            ("klipper", "buffered"), ("rrf", "ping-pong")])
def test_pause_parks_keeps_heat_and_resume_prints_the_file_exactly_once(firmware, mode):
    lines = program(300)
    commands = clean_lines(lines)
    states = []
    control = PrintControl(ParkSettings(build_volume=(250, 210, 220)),
                           on_state=lambda state, why: states.append((state, why)))
    with VirtualPrinter(firmware, **FAST) as vp:
        thread, box = run_stream(vp, lines, control, at=120, action="pause", mode=mode)
        assert wait_until(lambda: control.state == "paused"), box
        held = len(streamed(vp))
        time.sleep(0.3)
        assert len(streamed(vp)) == held and held < len(commands)  # nothing more is sent
        machine = vp.machine
        assert machine.heaters.target == {"T": 200.0, "B": 60.0}   # temperatures kept
        assert machine.motion.position["X"] == 10.0 and machine.motion.position["Y"] == 200.0
        here = pause_point(commands, held)
        assert machine.motion.position["Z"] == pytest.approx(here["Z"] + 20.0)
        assert machine.motion.position["E"] == pytest.approx(here["E"] - 2.0)  # retracted
        control.ask("resume")
        thread.join(60)
        assert "result" in box, box
        assert_exactly_once(vp, lines)
        # between the pause and the next line of the file: back to the pause point, E too
        executed = list(vp.executed_numbered)
        resumed_at = next(i for i, (n, _) in enumerate(executed) if n == held + 1)
        between = [c for n, c in executed[:resumed_at] if n is None][-8:]
        assert f"G1 X{here['X']:.3f} Y{here['Y']:.3f} F6000" in between
        assert f"G1 Z{here['Z']:.3f} F600" in between
        assert f"G92 E{here['E']:.5f}" in between
        feed = next(lex(c).value("F") for c in reversed(commands[:held]) if lex(c).has("F"))
        assert between[-3:] == ["G90", "M82", f"G1 F{feed:g}"]  # the file's modes again
    assert [s for s, _ in states] == ["paused", "printing"]


def test_cancel_parks_switches_heaters_off_and_sends_nothing_more():
    lines = program(300)
    control = PrintControl(ParkSettings(build_volume=(250, 210, 220)))
    with VirtualPrinter("marlin", **FAST) as vp:
        thread, box = run_stream(vp, lines, control, at=100, action="cancel")
        thread.join(60)
        assert isinstance(box.get("error"), StreamCancelled), box
        done = assert_prefix_once(vp, lines)
        time.sleep(0.3)
        assert len(streamed(vp)) == done < len(clean_lines(lines))
        assert vp.machine.heaters.target == {"T": 0.0, "B": 0.0}
        tail = vp.executed[-8:]
        assert tail[-4:] == ["M104 S0", "M140 S0", "M107", "M84"]
        assert any(c.startswith("G1 X10 Y200") for c in tail)  # parked first
    assert control.cancelled_by == "the user"


def test_cancel_while_paused_is_final():
    lines = program(300)
    control = PrintControl()
    with VirtualPrinter("marlin", **FAST) as vp:
        thread, box = run_stream(vp, lines, control, at=50, action="pause")
        assert wait_until(lambda: control.state == "paused")
        control.ask("cancel")
        thread.join(60)
        assert isinstance(box.get("error"), StreamCancelled)
        assert vp.machine.heaters.target == {"T": 0.0, "B": 0.0}
        assert_prefix_once(vp, lines)


def test_emergency_stop_sends_m112_at_once():
    lines = program(300)
    control = PrintControl()
    with VirtualPrinter("marlin", **FAST) as vp:
        thread, box = run_stream(vp, lines, control, at=100, action="stop")
        thread.join(60)
        assert isinstance(box.get("error"), EmergencyStopped), box
        assert "M112" in str(box["error"])
        assert wait_until(lambda: vp.machine.halted)
        assert vp.machine.heaters.target == {"T": 0.0, "B": 0.0}
        assert_prefix_once(vp, lines)


def test_action_cancel_from_the_printer_ends_the_stream_cancelled():
    lines = program(300)
    control = PrintControl()
    with VirtualPrinter("marlin", faults=Faults(events=((80, "//action:cancel"),)),
                        **FAST) as vp:
        thread, box = run_stream(vp, lines, control)
        thread.join(60)
        assert isinstance(box.get("error"), StreamCancelled), box
        assert control.cancelled_by == "the printer (//action:cancel)"
        assert vp.machine.heaters.target == {"T": 0.0, "B": 0.0}
        assert 80 <= assert_prefix_once(vp, lines) < len(clean_lines(lines))


def test_action_pause_from_the_printer_pauses_until_resumed():
    lines = program(300)
    control = PrintControl()
    with VirtualPrinter("marlin", faults=Faults(events=((80, "//action:pause"),)),
                        **FAST) as vp:
        thread, box = run_stream(vp, lines, control)
        assert wait_until(lambda: control.state == "paused"), box
        assert control.paused_by == "the printer (//action:pause)"
        control.ask("resume")
        thread.join(60)
        assert "result" in box, box
        assert_exactly_once(vp, lines)


@pytest.mark.parametrize("event, words", [
    ("kill", "Error:Printer halted. kill() called!"),
    ("thermal_runaway", "Error:Thermal Runaway, system stopped! Heater_ID: 0"),
])
def test_a_firmware_halt_fails_the_stream_with_the_firmwares_words(event, words):
    lines = program(300)
    with VirtualPrinter("marlin", faults=Faults(events=((80, event),)), **FAST) as vp:
        thread, box = run_stream(vp, lines, PrintControl())
        thread.join(60)
        assert isinstance(box.get("error"), PrinterHalted), box
        assert words in str(box["error"])
        assert assert_prefix_once(vp, lines) == 80


def test_filament_runout_the_firmware_handles_holds_the_stream_then_goes_on():
    """``//action:paused`` ... ``//action:resumed``: the host sends nothing meanwhile and
    moves nothing itself; the file still runs exactly once."""
    lines = program(300)
    states = []
    control = PrintControl(on_state=lambda state, why: states.append(state))
    faults = Faults(events=((80, "runout:1.0"),))
    with VirtualPrinter("marlin", faults=faults, **FAST) as vp:
        thread, box = run_stream(vp, lines, control)
        thread.join(60)
        assert "result" in box, box
        assert_exactly_once(vp, lines)
        assert not any(c.startswith("G1 X10 Y200") for c in vp.executed)  # no host park
    assert states[0] == "waiting" or states[0] == "paused"
    assert "paused" in states and states[-1] == "printing"


@pytest.mark.parametrize("commands, relative, relative_e, feed, tracked", [
    (["G90", "M82", "G92 E0", "G1 X10 Y20 Z0.2 E1.5 F1800", "G1 X12 E1.75"],
     False, False, 1800.0, {"X": 12.0, "Y": 20.0, "Z": 0.2, "E": 1.75}),
    (["G90", "M83", "G1 X10 Y20 Z0.3 F600", "G1 X11 E0.4", "G1 X12 E0.4 F1200"],
     False, True, 1200.0, {"X": 12.0, "Y": 20.0, "Z": 0.3}),
    (["G28", "G91", "G1 Z5", "G1 X10 E1"], True, True, None, {}),       # homed: unknown
    (["G90", "G1 X5 Y5 Z1", "G91", "G1 X2 Y-1", "M82"], True, False, None,
     {"X": 7.0, "Y": 4.0, "Z": 1.0}),
    (["G1 X1 Y1 Z1", "g 92 x0 e5", "G1 X+2"], False, False, None,
     {"X": 2.0, "Y": 1.0, "Z": 1.0, "E": 5.0}),
])
def test_modal_state_follows_the_sent_gcode(commands, relative, relative_e, feed, tracked):
    from printer.control import modal_state

    assert modal_state(commands, len(commands)) == (relative, relative_e, feed, tracked)


def test_resume_restores_relative_modes_and_never_moves_to_an_unknown_point():
    from printer.control import PausePoint, pause_moves, resume_moves

    park = ParkSettings(build_volume=(250, 210, 220))
    point = PausePoint({"X": 12.0, "Y": 20.0, "Z": 215.0, "E": 3.25}, True, True, 900.0)
    assert pause_moves(point, park) == ["M83", "G1 E-2 F2400", "G90", "G1 Z220.000 F600",
                                        "G1 X10 Y200 F6000"]  # the lift is capped at Z max
    assert resume_moves(point, park) == [
        "G90", "G1 X12.000 Y20.000 F6000", "G1 Z215.000 F600", "M83", "G1 E2 F2400",
        "G92 E3.25000", "G91", "M83", "G1 F900"]
    unknown = PausePoint(None, False, False, None)
    assert pause_moves(unknown, park) == ["M83", "G1 E-2 F2400"]
    assert resume_moves(unknown, park) == ["M83", "G1 E2 F2400", "G90", "M82"]


@pytest.mark.parametrize("firmware", ["marlin", "rrf"])
def test_cancel_during_a_heat_up_ends_the_wait_and_cools_down_at_once(firmware):
    """A cancel while M190 waits (real-time heating: the bed needs ~35 s) must not sit
    behind the wait: M108 ends it, then the cool-down runs; nothing after M190 runs."""
    lines = ["M140 S60", "M190 S60", *program(50)]
    control = PrintControl()
    with VirtualPrinter(firmware, speedup=1.0, baud=1_000_000, keepalive=0.05) as vp:
        thread, box = run_stream(vp, lines, control, mode="ping-pong")
        assert wait_until(lambda: "M190 S60" in vp.executed or (
            vp.machine.current is not None and "heat" in vp.machine.current))
        time.sleep(0.5)
        control.ask("cancel")
        thread.join(60)
        assert isinstance(box.get("error"), StreamCancelled), box
        assert vp.machine.heaters.target == {"T": 0.0, "B": 0.0}
        assert vp.machine.heaters.current["B"] < 50.0  # the wait was ended, not sat out
        assert "M108" in vp.executed
        assert not any(c.startswith("G1 X") and "E" in c for c in vp.executed)
