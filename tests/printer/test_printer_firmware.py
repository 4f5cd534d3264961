"""The firmware table: real FIRMWARE_NAME values -> family -> slicer flavour."""

import pytest

from printer.firmware import (
    FAMILIES,
    SLICER_FLAVOURS,
    family_of,
    slicer_flavour,
    slicer_flavour_for_firmware,
)
from printer.replies import parse_firmware_fields

# M115 lines as each firmware prints them
M115 = [
    ("FIRMWARE_NAME:Marlin 2.1.2.1 (Jul 23 2023 10:00:00) SOURCE_CODE_URL:github.com/"
     "MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ender-3 V2 EXTRUDER_COUNT:1",
     "marlin", "marlin"),
    ("FIRMWARE_NAME:Prusa-Firmware 3.14.1 based on Marlin FIRMWARE_URL:https://github.com/"
     "prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa i3 MK3S EXTRUDER_COUNT:1",
     "prusa", "marlin"),
    ("FIRMWARE_NAME:Prusa-Firmware-Buddy 6.1.3+8542 (Github) SOURCE_CODE_URL:https://github.com"
     "/prusa3d/Prusa-Firmware-Buddy PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa-MK4",
     "buddy", "marlin"),
    ("ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.12.0-85-gd785b396", "klipper", "klipper"),
    ("FIRMWARE_NAME: RepRapFirmware for Duet 3 Mini 5+ FIRMWARE_VERSION: 3.5.1 ELECTRONICS: "
     "Duet 3 Mini5plus Ethernet FIRMWARE_DATE: 2024-04-19 14:40:46", "rrf", "reprapfirmware"),
    ("FIRMWARE_NAME:Repetier_1.0.3 COMPILED:Jan 1 2020 PROTOCOL_VERSION:1.0", "unknown",
     "marlin"),
]


@pytest.mark.parametrize(("line", "family", "flavour"), M115)
def test_family_and_flavour_from_real_m115(line, family, flavour):
    name = parse_firmware_fields(line)["FIRMWARE_NAME"]
    assert family_of(name) == family
    assert slicer_flavour_for_firmware(name) == flavour
    assert slicer_flavour(family) == flavour


def test_every_family_has_a_flavour():
    assert {slicer_flavour(f) for f in FAMILIES} <= set(SLICER_FLAVOURS)


@pytest.mark.parametrize(("spelling", "flavour"), [
    ("rrf", "reprapfirmware"), ("reprap", "reprapfirmware"), ("RepRapFirmware", "reprapfirmware"),
    ("marlin2", "marlin"), ("", "marlin"), (None, "marlin"), (" Klipper ", "klipper"),
    ("makerbot", None),
])
def test_spellings(spelling, flavour):
    assert slicer_flavour(spelling) == flavour
