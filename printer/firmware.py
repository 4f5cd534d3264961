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
