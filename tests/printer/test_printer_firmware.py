"""The firmware table: real FIRMWARE_NAME values -> family -> slicer flavour."""

import pytest

from printer.firmware import (
    FAMILIES,
    SLICER_FLAVOURS,
    family_of,
    keepalive_forms,
    keepalives_promised,
    long_command_wait,
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


@pytest.mark.parametrize(
    ("command", "wait"),
    [
        ("M109 S210", 0.0), ("M109 R180", 0.0), ("M190 S60", 0.0), ("M190 R40", 0.0),
        ("M191 S45", 0.0), ("M116", 0.0), ("M116 P0", 0.0), ("G28", 0.0), ("G28 X Y", 0.0),
        ("G29", 0.0), ("G29 P1", 0.0), ("G32", 0.0), ("G34", 0.0), ("M400", 0.0),
        ("M600", 0.0), ("m 190 s60", 0.0), ("G4 S30", 30.0), ("G4 P2500", 2.5),
        ("G4 S1", 1.0), ("TEMPERATURE_WAIT SENSOR=extruder MINIMUM=200", 0.0),
        ("BED_MESH_CALIBRATE", 0.0),
        ("G4 P200", None), ("G4", None), ("G1 X10 Y10 E0.5", None), ("M104 S210", None),
        ("M140 S60", None), ("M105", None), ("G92 E0", None), ("M106 S255", None),
    ],
)
def test_long_commands(command, wait):
    assert long_command_wait(command) == wait


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_says_what_keeps_a_long_command_alive(family):
    forms = keepalive_forms(family)
    assert forms <= {"busy", "wait", "prusa_wait", "bare"}
    assert (not forms) == (family == "rrf")  # RepRapFirmware is silent while it waits
    assert ("bare" in forms) == (family == "klipper")


@pytest.mark.parametrize(
    ("family", "command", "promised"),
    [
        ("marlin", "M190 S60", True), ("marlin", "G28", True), ("prusa", "M109 S210", True),
        ("buddy", "G29", True), ("klipper", "M190 S60", True), ("klipper", "M109 S210", True),
        ("klipper", "TEMPERATURE_WAIT SENSOR=extruder MINIMUM=200", True),
        ("klipper", "G28", False), ("klipper", "BED_MESH_CALIBRATE", False),
        ("rrf", "M190 S60", False), ("rrf", "M116", False), ("unknown", "M109 S200", False),
    ],
)
def test_which_long_commands_come_with_keepalives(family, command, promised):
    assert keepalives_promised(family, command) == promised
