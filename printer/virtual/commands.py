"""What each command does on the virtual printer: the state it changes, the replies it
sends and what it waits for (a planner slot, an empty planner, a time, a temperature).

:func:`begin` returns the command's execution state, a dict the firmware's
``progress`` advances: ``replies`` (sent when it finishes), ``move`` (seconds of
motion to plan), ``drain`` (wait for the planner to empty), ``until`` / ``busy_for``
(a wait, with ``busy`` keepalives), ``heat`` (wait for these heaters; ``cooling_too``:
M109/M190 R waits for a cooler target too), ``ok_extra``.
"""

from __future__ import annotations

import json
import re
from typing import TYPE_CHECKING

from printer.gcode import GcodeLine, lex

if TYPE_CHECKING:
    from printer.virtual.firmware import FirmwareModel

KNOWN = frozenset(
    "M84 M18 M17 M106 M107 M110 M220 M221 M204 M205 M201 M203 M92 M117 M73 M300 M420 "
    "M500 M501 M502 M503 M851 M900 M104 M140 M21 M75 M76 M77 M80 M81 G21 G20 T0 M601 "
    "M602 M201 M907 M862.3 M862.5 M862.6 M115 M486".split()
)
_STANDARD_WORD = re.compile(r"[GMT]\d+(\.\d+)?")


def begin(model: FirmwareModel, command: str, now: float) -> dict:
    """Work out what executing ``command`` means: replies, and what it waits for."""
    lexed = lex(command)
    word = lexed.word or ""
    params = {letter: value for letter, value in lexed.params if value is not None}
    state: dict = {"replies": []}
    if _motion(model, word, params, state, now) or _heating(model, word, params, state, now):
        return state
    replies = _report(model, word, lexed, params)
    if replies is None:
        replies = [] if is_known(model, word) else [unknown_reply(model, command, word)]
    state["replies"] = replies
    if word == "M105":
        state["ok_extra"] = model.temperatures().strip()
    elif word == "M115" and model.firmware == "klipper":
        state["ok_extra"] = "FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.12.0-virtual"
    return state


def _motion(model: FirmwareModel, word: str, params: dict[str, float], state: dict,
            now: float) -> bool:
    """Moves, dwells, homing and positioning modes; False for any other command."""
    motion = model.motion
    if word in ("G0", "G1", "G2", "G3"):
        state["move"] = motion.move_seconds(params, model.settings.speedup)
    elif word == "G4":
        seconds = params.get("P", 0.0) / 1000.0 + params.get("S", 0.0)
        state["until"] = now + seconds / model.settings.speedup
        state["drain"] = True
    elif word in ("G28", "G29"):
        state["drain"] = True
        state["until"] = None
        state["busy_for"] = model.faults.busy_seconds or 5.0 / model.settings.speedup
        if word == "G28":
            for axis in "XYZ":
                motion.position[axis] = 0.0
    elif word in ("G90", "G91"):
        motion.relative = motion.relative_e = word == "G91"
    elif word in ("M82", "M83"):
        motion.relative_e = word == "M83"
    elif word == "G92":
        for axis in "XYZE":
            if axis in params:
                motion.position[axis] = params[axis]
    elif word == "M400":
        state["drain"] = True
    else:
        return False
    return True


def _heating(model: FirmwareModel, word: str, params: dict[str, float], state: dict,
             now: float) -> bool:
    """Heater targets, waits for them and the temperature auto-report."""
    heaters = model.heaters
    if word in ("M104", "M109", "M140", "M190"):
        heater = "T" if word in ("M104", "M109") else "B"
        heaters.target[heater] = params.get("S", params.get("R", 0.0))
        if word in ("M109", "M190"):
            state["heat"] = (heater,)
            state["cooling_too"] = "R" in params and "S" not in params
    elif word == "M116":
        state["heat"] = ("T", "B")
    elif word == "M155":
        model.autoreport = params.get("S", 0.0)
        model.next_report = now + model.autoreport
    else:
        return False
    return True


def _report(model: FirmwareModel, word: str, lexed: GcodeLine,
            params: dict[str, float]) -> list[str] | None:
    """The reply lines of a query, or None when ``word`` is not one this firmware answers."""
    firmware = model.firmware
    x, y, z = model.settings.build_volume
    if word == "M105":
        return []  # the report rides on the ok
    if word == "M114":
        return [model.motion.report()]
    if word == "M115":
        if firmware == "klipper":
            return []
        return [*model.profile.m115, *([area_line(model)] if firmware in ("marlin", "buddy")
                                       else [])]
    if word == "M211" and firmware in ("marlin", "buddy") and not params:
        return ["echo:; Soft Endstops:", "echo:  M211 S1 ; ON",
                f"echo:    Min:  X0.00 Y0.00 Z0.00   Max:  X{x:.2f} Y{y:.2f} Z{z:.2f}"]
    if word == "M409" and firmware == "rrf":
        return [object_model_reply(model, lexed.raw)]
    if word == "M208" and firmware == "rrf" and not params:
        return [f"Axis limits (mm) X0.0:{x:.1f}, Y0.0:{y:.1f}, Z0.0:{z:.1f}"]
    if word == "M200" and firmware in ("marlin", "buddy"):
        if "D" in params:
            model.filament_diameter = params["D"]
            return []
        return ["echo:; Filament settings (Disabled):",
                f"echo:  M200 S0 D{model.filament_diameter:.2f}"]
    if word == "M862.1" and firmware == "prusa":
        return [f"{model.settings.nozzle:.2f}"] if lexed.has("Q") else []
    if word == "M862.1" and firmware == "buddy":
        return [f"echo:  M862.1 T0 P{model.settings.nozzle:.2f} A0 F0"] if lexed.has("Q") else []
    if firmware == "klipper" and word == model.settings.nozzle_macro:
        return [f"// nozzle_diameter: {model.settings.nozzle:.3f}"]
    return None


def object_model_reply(model: FirmwareModel, command: str) -> str:
    """RepRapFirmware 3's one-line JSON answer to ``M409 K"key"``; only ``move.axes`` has
    a result here (the build volume as the axis limits), other keys answer null."""
    found = re.search(r'K\s*"([^"]*)"', command)
    key = found.group(1) if found else ""
    result = None
    if key == "move.axes":
        result = [{"acceleration": 1000.0, "babystep": 0, "current": 800, "drivers": [f"0.{i}"],
                   "homed": False, "jerk": 900.0, "letter": letter, "max": limit,
                   "maxProbed": False, "microstepping": {"interpolated": True, "value": 16},
                   "min": 0, "minProbed": False, "speed": 6000.0, "stepsPerMm": 80.0,
                   "userPosition": 0, "visible": True, "workplaceOffsets": [0] * 9}
                  for i, (letter, limit) in enumerate(zip("XYZ", model.settings.build_volume,
                                                          strict=True))]
    return json.dumps({"key": key, "flags": "", "result": result}, separators=(",", ":"))


def is_known(model: FirmwareModel, word: str) -> bool:
    """True for a command this firmware runs silently (an ``ok`` and nothing else)."""
    if word in KNOWN:
        return True
    if model.firmware == "klipper":
        return word in ("M110", "M112") or word.startswith("SET_") or word in (
            "PRINT_START", "PRINT_END", "BED_MESH_CALIBRATE", "TURN_OFF_HEATERS"
        )
    if word in ("M862.1", "M211", "M200", "M208"):
        return False
    return bool(_STANDARD_WORD.fullmatch(word))


def unknown_reply(model: FirmwareModel, command: str, word: str) -> str:
    """The line this firmware prints for a command it does not know."""
    if model.firmware == "klipper":
        return f'// Unknown command:"{word}"'
    if model.firmware == "rrf":
        return f"Error: {word}: Command is not supported"
    return f'echo:Unknown command: "{command}"'


def area_line(model: FirmwareModel) -> str:
    """Marlin's M115 ``area:`` report of the build volume."""
    x, y, z = model.settings.build_volume
    box = f"min:{{x:0.00,y:0.00,z:0.00}},max:{{x:{x:.2f},y:{y:.2f},z:{z:.2f}}}"
    return f"area:{{full:{{{box}}},work:{{{box}}}}}"
