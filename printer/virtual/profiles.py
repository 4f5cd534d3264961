"""The firmware profiles the virtual printer can play: banners, M115 reports, line checks."""

from __future__ import annotations

from dataclasses import dataclass

FIRMWARES = ("marlin", "prusa", "buddy", "klipper", "rrf")


@dataclass(frozen=True)
class FirmwareProfile:
    """name: the firmware family. banner: lines printed at boot. m115: the M115 report.
    checks: "marlin" (N + checksum checked, resend), "rrf" (bad lines silently dropped)
    or "none" (Klipper). resend_ok: an ``ok`` follows ``Resend:``. advanced_ok: ``ok``
    carries ``N P B`` (ADVANCED_OK)."""

    name: str
    banner: tuple[str, ...]
    m115: tuple[str, ...]
    checks: str
    resend_ok: bool
    advanced_ok: bool



MARLIN_CAPS = (
    "Cap:SERIAL_XON_XOFF:0",
    "Cap:BINARY_FILE_TRANSFER:0",
    "Cap:EEPROM:1",
    "Cap:VOLUMETRIC:1",
    "Cap:AUTOREPORT_POS:0",
    "Cap:AUTOREPORT_TEMP:1",
    "Cap:PROGRESS:0",
    "Cap:PRINT_JOB:1",
    "Cap:AUTOLEVEL:1",
    "Cap:RUNOUT:0",
    "Cap:Z_PROBE:1",
    "Cap:LEVELING_DATA:1",
    "Cap:SOFTWARE_POWER:0",
    "Cap:EMERGENCY_PARSER:1",
    "Cap:HOST_ACTION_COMMANDS:0",
    "Cap:PROMPT_SUPPORT:0",
    "Cap:SDCARD:1",
    "Cap:THERMAL_PROTECTION:1",
    "Cap:MOTION_MODES:0",
    "Cap:ARCS:1",
    "Cap:CHAMBER_TEMPERATURE:0",
)

PROFILES = {
    "marlin": FirmwareProfile(
        "marlin",
        ("start", "echo:Marlin 2.1.2.1", "echo: Last Updated: 2023-07-23 | Author: (virtual)"),
        (
            "FIRMWARE_NAME:Marlin 2.1.2.1 (Jul 23 2023 10:00:00) "
            "SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:Virtual Marlin EXTRUDER_COUNT:1 "
            "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff",
            *MARLIN_CAPS,
        ),
        "marlin",
        True,
        False,
    ),
    "prusa": FirmwareProfile(
        "prusa",
        ("start", "echo: 3.14.1-8237", "echo:Free Memory: 1987  PlannerBufferBytes: 1392"),
        (
            "FIRMWARE_NAME:Prusa-Firmware 3.14.1 based on Marlin "
            "FIRMWARE_URL:https://github.com/prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:Prusa i3 MK3S EXTRUDER_COUNT:1 UUID:00000000-0000-0000-0000-000000000000",
            "Cap:AUTOREPORT_TEMP:1",
            "Cap:AUTOREPORT_FANS:1",
            "Cap:AUTOREPORT_POSITION:1",
            "Cap:EXTENDED_M20:1",
            "Cap:PRUSA_MMU2:1",
        ),
        "marlin",
        False,
        False,
    ),
    "buddy": FirmwareProfile(
        "buddy",
        ("start", "echo:Prusa-Firmware-Buddy 6.1.3"),
        (
            "FIRMWARE_NAME:Prusa-Firmware-Buddy 6.1.3+8542 (Github) "
            "SOURCE_CODE_URL:https://github.com/prusa3d/Prusa-Firmware-Buddy "
            "PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa-MK4 EXTRUDER_COUNT:1 "
            "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff",
            "Cap:SERIAL_XON_XOFF:0",
            "Cap:EEPROM:0",
            "Cap:AUTOREPORT_TEMP:1",
            "Cap:AUTOREPORT_POS:1",
            "Cap:EMERGENCY_PARSER:1",
            "Cap:PRUSA_MMU2:0",
        ),
        "marlin",
        True,
        True,
    ),
    "klipper": FirmwareProfile("klipper", (), (), "none", False, False),
    "rrf": FirmwareProfile(
        "rrf",
        (),
        (
            "FIRMWARE_NAME: RepRapFirmware for Duet 3 Mini 5+ FIRMWARE_VERSION: 3.5.1 "
            "ELECTRONICS: Duet 3 Mini5plus Ethernet FIRMWARE_DATE: 2024-04-19 14:40:46",
        ),
        "rrf",
        False,
        False,
    ),
}
