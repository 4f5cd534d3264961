"""The one firmware table: what a printer's FIRMWARE_NAME says about it.

FIRMWARE_NAME (from M115) -> family (how the host talks to it) -> the G-code flavour
a slicer writes for it. Everything that needs either answer asks here.

====================  ==========  ==============
FIRMWARE_NAME holds   family      slicer flavour
====================  ==========  ==============
Klipper               klipper     klipper
RepRap(Firmware)      rrf         reprapfirmware
Prusa-Firmware-Buddy  buddy       marlin
Prusa-Firmware        prusa       marlin
Marlin                marlin      marlin
anything else         unknown     marlin
====================  ==========  ==============
"""

from __future__ import annotations

FAMILIES = ("marlin", "prusa", "buddy", "klipper", "rrf", "unknown")
#: The G-code dialects the slicers write.
SLICER_FLAVOURS = ("marlin", "klipper", "reprapfirmware")

# (what the lower-cased FIRMWARE_NAME contains, family): the first match wins, so the
# more specific Prusa-Firmware-Buddy comes before Prusa-Firmware.
_NAME_MARKERS = (
    ("klipper", "klipper"),
    ("reprap", "rrf"),
    ("prusa-firmware-buddy", "buddy"),
    ("prusa-firmware", "prusa"),
    ("marlin", "marlin"),
)

_FAMILY_FLAVOUR = {
    "marlin": "marlin",
    "prusa": "marlin",
    "buddy": "marlin",
    "klipper": "klipper",
    "rrf": "reprapfirmware",
    "unknown": "marlin",
}

# Other spellings of a flavour that a profile file or a caller may use.
_FLAVOUR_SPELLINGS = {"reprap": "reprapfirmware", "marlin2": "marlin", "": "marlin"}


def family_of(firmware_name: str) -> str:
    """marlin / prusa / buddy / klipper / rrf / unknown from a FIRMWARE_NAME value."""
    low = firmware_name.lower()
    for marker, family in _NAME_MARKERS:
        if marker in low:
            return family
    return "unknown"


def slicer_flavour(name: str | None) -> str | None:
    """The slicer flavour for a flavour, a family or a known spelling of either
    (``"rrf"`` -> ``"reprapfirmware"``, ``"buddy"`` -> ``"marlin"``); None for a name
    that is none of these."""
    key = str(name or "").strip().lower()
    if key in SLICER_FLAVOURS:
        return key
    return _FAMILY_FLAVOUR.get(key) or _FLAVOUR_SPELLINGS.get(key)


def slicer_flavour_for_firmware(firmware_name: str) -> str:
    """The flavour a slicer should write for the printer reporting ``firmware_name``."""
    return _FAMILY_FLAVOUR[family_of(firmware_name)]


# ---------------------------------------------------------------- long-running commands
#: Commands that may run for minutes before the firmware answers ``ok``: heating and
#: waiting (M109/M190/M191 with S or R, M116), homing, probing and levelling (G28, G29,
#: G32, G34), waiting for the moves to finish (M400), a filament change (M600), and
#: Klipper's macros that do the same. G4 counts when its dwell is long (see
#: :data:`LONG_DWELL_SECONDS`).
LONG_COMMANDS = frozenset({
    "M109", "M190", "M191", "M116", "G28", "G29", "G32", "G34", "M400", "M600",
    "M0", "M1", "M226", "M303", "TEMPERATURE_WAIT", "BED_MESH_CALIBRATE",
    "QUAD_GANTRY_LEVEL", "Z_TILT_ADJUST", "PRINT_START", "START_PRINT", "PID_CALIBRATE",
})
#: A G4 dwell at least this long is a long-running command.
LONG_DWELL_SECONDS = 1.0

#: What each family sends while it works on a long command (see :func:`keepalive_forms`):
#: ``busy`` (``echo:busy: processing``), ``wait`` (a temperature line with ``W:``),
#: ``prusa_wait`` (Prusa MK3's ``T:205.3 E:0 W:3`` / ``T:25.0 E:0 B:40.5``), ``bare``
#: (Klipper's ``B:41.0 /60.0 T0:120.3 /210.0``). RepRapFirmware sends nothing.
KEEPALIVE_FORMS = {
    "marlin": frozenset({"busy", "wait"}),
    "buddy": frozenset({"busy", "wait"}),
    "prusa": frozenset({"busy", "wait", "prusa_wait"}),
    "klipper": frozenset({"bare"}),
    "rrf": frozenset(),
    "unknown": frozenset({"busy", "wait"}),
}


#: Waits for a temperature: Klipper prints its bare report once a second during these.
HEAT_WAITS = frozenset({"M109", "M190", "M191", "M116", "TEMPERATURE_WAIT"})


def keepalives_promised(family: str, command: str) -> bool:
    """True when ``family`` prints keep-alives all through the long ``command``, so that
    silence means it finished (its ``ok`` lost) or died: Marlin, Prusa and Buddy (``W:``
    lines while heating, ``busy:`` otherwise, HOST_KEEPALIVE_FEATURE being on by default),
    Klipper while it waits for a temperature. RepRapFirmware, Klipper's homing and
    levelling, and unknown firmware may stay silent for the whole command."""
    if family in ("marlin", "prusa", "buddy"):
        return True
    return family == "klipper" and _word(command) in HEAT_WAITS


def _word(command: str) -> str | None:
    # the lexer is imported on first use: the slicer reads this table (its G-code
    # flavours) and never lexes, so `preflight slice` does not load it
    from printer.gcode import lex

    return lex(command).word


def heat_wait_break(family: str) -> str | None:
    """The command that ends a running heat-up wait at once (through the emergency
    parser, ahead of the queue): ``M108`` on Marlin, Prusa, Buddy and RepRapFirmware;
    None on Klipper, which has none, so a cancel's cool-down follows its wait."""
    return None if family == "klipper" else "M108"


def keepalive_forms(family: str) -> frozenset[str]:
    """The keep-alive line forms the ``family`` sends while a long command runs."""
    return KEEPALIVE_FORMS.get(family, KEEPALIVE_FORMS["unknown"])


def dwell_seconds(word: str | None, params: dict[str, float]) -> float:
    """The dwell of a G4 (``P`` ms, ``S`` s), 0 for any other command."""
    if word != "G4":
        return 0.0
    return params.get("P", 0.0) / 1000.0 + params.get("S", 0.0)


def long_command_wait(command: str) -> float | None:
    """None for an ordinary command; for a long-running one, the seconds it is known to
    take at least (a G4's dwell, else 0.0).

    ``"M190 S60"`` -> 0.0, ``"G4 S30"`` -> 30.0, ``"G4 P200"`` -> None, ``"G1 X5"`` -> None.
    """
    from printer.gcode import lex

    lexed = lex(command)
    word = lexed.word
    if word == "G4":
        params = {k: v for k, v in lexed.params if v is not None}
        dwell = dwell_seconds(word, params)
        return dwell if dwell >= LONG_DWELL_SECONDS else None
    return 0.0 if word in LONG_COMMANDS else None
