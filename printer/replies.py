"""Pure parsers for the lines a printer sends back (Marlin 2.x, Prusa MK3, Prusa Buddy,
Klipper, RepRapFirmware).

Nothing here touches a port: every function takes text and returns values, so the
whole protocol vocabulary is table-tested with real reply strings. Temperatures are
in °C, lengths in mm.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from printer.gcode import firmware_int

_NUM = r"-?\d+(?:\.\d+)?"

# Fatal conditions: the firmware has stopped and will not take more commands.
_FATAL_MARKERS = (
    "printer halted",
    "kill() called",
    "thermal runaway",
    "mintemp",
    "maxtemp",
    "heating failed",
    "printer stopped due to errors",
)

# Marlin's line-protocol errors: "Error:<reason>, Last Line: <n>".
_LINE_ERRORS = ("checksum mismatch", "line number is not", "no checksum", "no line number")


@dataclass(frozen=True)
class Reply:
    """One classified reply line.

    kind is one of: ``ok``, ``resend``, ``busy``, ``start``, ``fatal``, ``line_error``,
    ``error``, ``unknown_command``, ``temperature``, ``comment``, ``echo``, ``other``.
    ``number`` is the line number of a resend request, of an ADVANCED_OK ``N`` field,
    or the ``Last Line`` of a line error. ``planner_free``/``queue_free`` are the
    ADVANCED_OK ``P``/``B`` fields. ``temps`` maps a heater (``T``, ``T0``, ``B``...)
    to (current °C, target °C or None).
    """

    kind: str
    text: str
    number: int | None = None
    planner_free: int | None = None
    queue_free: int | None = None
    temps: dict[str, tuple[float, float | None]] = field(default_factory=dict)
    waiting: bool = False

    @property
    def is_temperature_ok(self) -> bool:
        """An ``ok`` that carries a temperature report (the reply to M105)."""
        return self.kind == "ok" and bool(self.temps)


_TEMP_RE = re.compile(rf"(?<![A-Za-z@])(T\d*|B|C|P|A):\s*({_NUM})(?:\s*/\s*({_NUM}))?")
_ADV_RE = re.compile(r"(?<![A-Za-z:])([NPB])(\d+)(?![\d.:])")
_RESEND_RE = re.compile(r"^(?:resend|rs)\s*:?\s*N?:?\s*(\d+)", re.IGNORECASE)
_LAST_LINE_RE = re.compile(r"last line\s*:?\s*(\d+)", re.IGNORECASE)
_UNKNOWN_RE = re.compile(r"unknown (?:command|g-?code|m-?code)\s*:?\s*\"?([^\"]*)\"?", re.I)


def parse_temperatures(text: str) -> dict[str, tuple[float, float | None]]:
    """Heater readings from an M105 reply or auto-report, in any of the common spacings.

    ``"T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0"`` -> ``{"T": (210.0, 210.0),
    "B": (60.0, 60.0)}``; ``T0:`` style keys are kept as reported. Power fields
    (``@:``, ``B@:``) and the wait field ``W:`` are not heaters and are skipped.
    """
    temps: dict[str, tuple[float, float | None]] = {}
    for key, current, target in _TEMP_RE.findall(text):
        if key in temps:
            continue
        temps[key] = (float(current), float(target) if target else None)
    return temps


def parse_reply(line: str) -> Reply:
    """Classify one line received from the printer (the line terminator already removed)."""
    text = line.strip()
    low = text.lower()
    if low == "ok" or low.startswith("ok ") or low.startswith("ok:"):
        rest = text[2:]
        temps = parse_temperatures(rest) if ":" in rest else {}
        number = planner = queue = None
        if not temps:
            for letter, value in _ADV_RE.findall(rest):
                if letter == "N":
                    number = firmware_int(value)
                elif letter == "P":
                    planner = firmware_int(value)
                else:
                    queue = firmware_int(value)
        return Reply("ok", text, number, planner, queue, temps)
    m = _RESEND_RE.match(text)
    if m:
        return Reply("resend", text, firmware_int(m.group(1)))
    if low == "start":
        return Reply("start", text)
    if low.startswith("!!"):
        return Reply("fatal", text)
    if "busy:" in low and (low.startswith("echo:") or low.startswith("busy")):
        return Reply("busy", text)
    if _UNKNOWN_RE.search(text) or "is not supported" in low:
        return Reply("unknown_command", text)
    if low.startswith("error"):
        if any(marker in low for marker in _FATAL_MARKERS):
            return Reply("fatal", text)
        m = _LAST_LINE_RE.search(text)
        if any(reason in low for reason in _LINE_ERRORS):
            return Reply("line_error", text, firmware_int(m.group(1)) if m else None)
        return Reply("error", text)
    if any(marker in low for marker in ("printer halted", "kill() called")):
        return Reply("fatal", text)
    temps = parse_temperatures(text)
    if temps and re.match(r"^(?:T\d*|B):", text):
        return Reply("temperature", text, temps=temps, waiting="W:" in text)
    if text.startswith("//"):
        return Reply("comment", text)
    if low.startswith("echo:"):
        return Reply("echo", text)
    return Reply("other", text)


def unknown_command_of(line: str) -> str | None:
    """The command named by an unknown-command reply, or None if the line is not one.

    ``'echo:Unknown command: "M862.1 Q"'`` -> ``"M862.1 Q"``;
    ``'// Unknown command:"M862.1"'`` -> ``"M862.1"``.
    """
    m = _UNKNOWN_RE.search(line)
    if m:
        return m.group(1).strip() or None
    m = re.search(r"(?:error|warning):\s*([GMT][\d.]+).*not supported", line, re.I)
    return m.group(1) if m else None


_KEY_RE = re.compile(r"(?:(?<=\s)|^)([A-Z][A-Z0-9_]{2,}):")


def parse_firmware_fields(text: str) -> dict[str, str]:
    """The ``KEY:value`` fields of an M115 reply line (Marlin, Prusa, Klipper, RRF).

    Values run until the next upper-case ``KEY:``; a leading ``ok`` (Klipper puts
    M115 on the ok line) is ignored.
    """
    body = text.strip()
    if body.lower().startswith("ok"):
        body = body[2:].lstrip()
    matches = list(_KEY_RE.finditer(body))
    fields: dict[str, str] = {}
    for i, m in enumerate(matches):
        end = matches[i + 1].start() if i + 1 < len(matches) else len(body)
        fields[m.group(1)] = body[m.end():end].strip()
    return fields


def parse_capability(text: str) -> tuple[str, bool] | None:
    """``"Cap:ADVANCED_OK:1"`` -> ``("ADVANCED_OK", True)``; None for other lines."""
    m = re.match(r"^\s*Cap:([A-Z0-9_]+):\s*(\d+)", text.strip())
    if not m:
        return None
    return m.group(1), m.group(2) != "0"


_XYZ = rf"\{{x:({_NUM}),y:({_NUM}),z:({_NUM})\}}"


def parse_area(text: str) -> dict[str, tuple[tuple[float, ...], tuple[float, ...]]]:
    """Marlin's M115 geometry report, ``area:{full:{min:{x:..},max:{..}},work:{..}}``.

    Returns ``{"full": (min_xyz, max_xyz), "work": (min_xyz, max_xyz)}`` (mm), with
    whichever of the two the line holds.
    """
    out = {}
    for name in ("full", "work"):
        m = re.search(rf"{name}:\{{min:{_XYZ},max:{_XYZ}\}}", text)
        if m:
            values = tuple(float(v) for v in m.groups())
            out[name] = (values[:3], values[3:])
    return out


_SOFT_RE = re.compile(
    rf"Min:\s*X\s*({_NUM})\s*Y\s*({_NUM})\s*Z\s*({_NUM})\s+Max:\s*X\s*({_NUM})\s*Y\s*({_NUM})"
    rf"\s*Z\s*({_NUM})"
)


def parse_soft_endstops(text: str) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """Marlin M211: ``"  Min:  X0.00 Y0.00 Z0.00   Max:  X250.00 Y210.00 Z220.00"``.

    Returns ((xmin, ymin, zmin), (xmax, ymax, zmax)) in mm, or None.
    """
    m = _SOFT_RE.search(text)
    if not m:
        return None
    values = tuple(float(v) for v in m.groups())
    return values[:3], values[3:]


def parse_axis_limits(text: str) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """RepRapFirmware M208: ``"Axis limits (mm) X0.0:230.0, Y0.0:210.0, Z0.0:200.0"``."""
    if "limits" not in text.lower():
        return None
    found = dict(
        (axis, (float(lo), float(hi)))
        for axis, lo, hi in re.findall(rf"\b([XYZ])\s*({_NUM})\s*:\s*({_NUM})", text)
    )
    if not all(axis in found for axis in "XYZ"):
        return None
    return tuple(found[a][0] for a in "XYZ"), tuple(found[a][1] for a in "XYZ")


def parse_filament_diameter(text: str) -> float | None:
    """The ``D`` value of an M200 report (``"echo:  M200 S0 D1.75"``), in mm, or None."""
    m = re.search(rf"M200\b[^;]*?\bD\s*({_NUM})", text)
    if not m:
        return None
    value = float(m.group(1))
    return value if 1.0 <= value <= 3.5 else None


def parse_nozzle_reply(text: str) -> float | None:
    """A nozzle diameter (mm) from the reply to a nozzle query, or None.

    Prusa MK3 ``M862.1 Q`` answers a bare ``0.40``; Prusa Buddy answers
    ``echo:  M862.1 T0 P0.40 A0 F0``; a Klipper query macro answers a ``//`` line
    such as ``// nozzle_diameter: 0.400``. Plausible values only (0.05..3 mm).
    """
    text = text.strip()
    value: float | None = None
    m = re.search(rf"M862\.1\b.*?\bP\s*({_NUM})", text)
    if m:
        value = float(m.group(1))
    elif re.fullmatch(_NUM, text):
        value = float(text)
    elif text.startswith("//") or text.lower().startswith("echo:"):
        m = re.search(rf"nozzle[_ a-z]*[:=]?\s*({_NUM})", text, re.I)
        if m:
            value = float(m.group(1))
        else:
            m = re.fullmatch(rf"(?://|echo:)\s*({_NUM})\s*(?:mm)?", text, re.I)
            if m:
                value = float(m.group(1))
    if value is None or not 0.05 <= value <= 3.0:
        return None
    return value


# --- host actions, waiting for the user, the position ---------------------------------

#: The host actions a printer asks of its host (Marlin HOST_ACTION_COMMANDS, Prusa MK3's
#: ``// action:``, Klipper's ``RESPOND TYPE=command``): pause/resume/cancel ask the host to
#: do it; paused/resumed say the firmware did it itself (M600, a filament runout).
HOST_ACTIONS = frozenset({"pause", "paused", "resume", "resumed", "cancel"})
_ACTION_RE = re.compile(r"^//\s*action:\s*([a-z_]+)\b\s*(.*)$", re.IGNORECASE)


def host_action(line: str) -> tuple[str, str] | None:
    """``"//action:pause"`` -> ``("pause", "")``; ``"// action:paused filament_runout"``
    -> ``("paused", "filament_runout")``. None for any other line, and for actions that
    ask nothing of a print (``prompt_begin``, ``notification``, ``out_of_filament``...)."""
    m = _ACTION_RE.match(line.strip())
    if m is None or m.group(1).lower() not in HOST_ACTIONS:
        return None
    return m.group(1).lower(), m.group(2).strip()


def waiting_for_user(line: str) -> bool:
    """True for Marlin's / Prusa's keep-alive while M600 (or M0/M1) waits for the user:
    ``echo:busy: paused for user`` or ``echo:busy: paused for input``."""
    low = line.strip().lower()
    return "busy:" in low and "paused for" in low


_POSITION_RE = re.compile(rf"(?<![A-Za-z0-9])([XYZE]):\s*({_NUM})")


def parse_position(text: str) -> dict[str, float] | None:
    """The logical position of an M114 reply (mm), the part before ``Count``.

    Marlin ``"X:10.00 Y:20.00 Z:0.20 E:1.23 Count X:800 Y:1600 Z:80"``, Klipper
    ``"X:10.000 Y:20.000 Z:0.200 E:1.230"``, RRF ``"X:10.000 Y:20.000 Z:0.200 E:1.230
    E0:1.2 Count 800 1600 80 Machine ..."``. None unless X, Y and Z are all there.
    """
    head = re.split(r"\bCount\b", text, maxsplit=1)[0]
    found: dict[str, float] = {}
    for axis, value in _POSITION_RE.findall(head):
        found.setdefault(axis, float(value))
    return found if all(a in found for a in "XYZ") else None


# ---------------------------------------------------------------- keep-alives
_PRUSA_WAIT_RE = re.compile(r"^T:\s*-?\d+(?:\.\d+)?\s+E:\s*\d+\b")
_HEATERS = re.compile(r"^(?:T\d*|B|C)$")


def keepalive_form(reply: Reply) -> str | None:
    """Which keep-alive form a reply line is, or None when it is not one.

    ``"busy"``: Marlin's ``echo:busy: processing`` (also ``busy: paused for user``).
    ``"prusa_wait"``: Prusa MK3's wait report, ``T:205.3 E:0 W:3`` (M109) or
    ``T:25.0 E:0 B:40.5`` (M190). ``"wait"``: a temperature line with ``W:`` (Marlin's
    ``T:25.00 /210.00 B:25.00 /60.00 @:0 B@:0 W:?``). ``"bare"``: a temperature line
    with targets and no power fields, as Klipper prints once a second while it waits
    (``B:41.0 /60.0 T0:120.3 /210.0``). A Marlin auto-report (it carries ``@:``) is none
    of these: it arrives whether or not the firmware is working on our lines.
    """
    if reply.kind == "busy":
        return "busy"
    if reply.kind != "temperature":
        return None
    text = reply.text
    if _PRUSA_WAIT_RE.match(text):
        return "prusa_wait"
    if reply.waiting:
        return "wait"
    if "@:" not in text and all(target is not None for _, target in reply.temps.values()):
        return "bare"
    return None


def heater_readings(temps: dict[str, tuple[float, float | None]]
                    ) -> dict[str, tuple[float, float | None]]:
    """The heaters of a temperature report, for display: hotends (``T``, ``T1``...), bed
    ``B`` and chamber ``C``; Klipper's lone ``T0`` becomes ``T``; Prusa's PINDA ``P`` and
    ambient ``A`` probes are dropped."""
    out = {key: value for key, value in temps.items() if _HEATERS.match(key)}
    if "T0" in out and "T" not in out:
        out["T"] = out.pop("T0")
    return out
