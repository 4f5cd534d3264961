"""Who the printer is and what it can do: the M115 report and read-only capability queries.

Nozzle: Prusa's ``M862.1 Q``, a Klipper macro, else the configured or default value.
Build volume: RepRapFirmware's M208, Marlin's M211 soft endstops, the M115 ``area:``
report, else a Prusa model's nominal volume. Filament: M200. Temperatures: M105.
Never a command that changes anything (never ``M862.1 P``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from printer.firmware import family_of
from printer.info import PrinterInfo
from printer.replies import (
    parse_area,
    parse_axis_limits,
    parse_capability,
    parse_filament_diameter,
    parse_firmware_fields,
    parse_nozzle_reply,
    parse_soft_endstops,
    parse_temperatures,
)

if TYPE_CHECKING:
    from printer.host import PrinterHost

DEFAULT_NOZZLE = 0.4

# Prusa printers that do not answer M211: nominal build volumes (mm) by MACHINE_TYPE.
PRUSA_VOLUMES = {
    "prusa i3 mk3s": [250.0, 210.0, 210.0],
    "prusa i3 mk3": [250.0, 210.0, 210.0],
    "prusa i3 mk2.5s": [250.0, 210.0, 210.0],
    "prusa-mini": [180.0, 180.0, 180.0],
    "prusa-mk4": [250.0, 210.0, 220.0],
    "prusa-xl": [360.0, 360.0, 360.0],
}


@dataclass(frozen=True)
class Identity:
    """What an M115 report says: ``KEY:value`` fields, ``Cap:`` flags, the ``area:``."""

    fields: dict[str, str] = field(default_factory=dict)
    capabilities: dict[str, bool] = field(default_factory=dict)
    area: dict = field(default_factory=dict)

    @property
    def firmware(self) -> str:
        """FIRMWARE_NAME as reported ("" when the printer does not say)."""
        return self.fields.get("FIRMWARE_NAME", "")

    @property
    def family(self) -> str:
        """marlin / prusa / buddy / klipper / rrf / unknown (see printer.firmware)."""
        return family_of(self.firmware)


def read_identity(lines: list[str]) -> Identity:
    """The identity in the reply lines of M115."""
    fields: dict[str, str] = {}
    capabilities: dict[str, bool] = {}
    area: dict = {}
    for line in lines:
        capability = parse_capability(line)
        if capability:
            capabilities[capability[0]] = capability[1]
            continue
        if "area:" in line:
            area = parse_area(line)
            continue
        line_fields = parse_firmware_fields(line)
        if "FIRMWARE_NAME" in line_fields:
            fields = line_fields
    return Identity(fields, capabilities, area)


def extent(limits) -> list[float]:
    """[x, y, z] sizes (mm) of ((xmin, ymin, zmin), (xmax, ymax, zmax))."""
    low, high = limits
    return [round(float(h) - float(lo), 3) for lo, h in zip(low, high, strict=True)]


def _first_value(host: PrinterHost, command: str, parse) -> float | None:
    for line in host.query(command):
        value = parse(line)
        if value is not None:
            return value
    return None


def _nozzle(host: PrinterHost) -> tuple[float, str]:
    if host.flavour in ("prusa", "buddy", "marlin"):
        value = _first_value(host, "M862.1 Q", parse_nozzle_reply)
        if value is not None:
            return value, "M862.1"
    if host.nozzle_macro:
        value = _first_value(host, host.nozzle_macro, parse_nozzle_reply)
        if value is not None:
            return value, f"macro:{host.nozzle_macro}"
    if host.nozzle_fallback is not None:
        return float(host.nozzle_fallback), "config"
    return DEFAULT_NOZZLE, "default"


def _build_volume(host: PrinterHost) -> tuple[list[float] | None, str | None]:
    volume, source = None, None
    if host.flavour == "rrf":
        for line in host.query("M208"):
            limits = parse_axis_limits(line)
            if limits:
                volume, source = extent(limits), "M208"
    elif host.flavour != "klipper":
        for line in host.query("M211"):
            limits = parse_soft_endstops(line)
            if limits:
                volume, source = extent(limits), "M211"
    if volume is None and host.area:
        box = host.area.get("work") or host.area.get("full")
        volume, source = extent(box), "M115 area"
    if volume is None:
        machine = host.fields.get("MACHINE_TYPE", "").lower()
        if machine in PRUSA_VOLUMES:
            volume, source = list(PRUSA_VOLUMES[machine]), "machine type"
    return volume, source


def _filament(host: PrinterHost) -> tuple[float, str]:
    if host.flavour in ("marlin", "buddy", "prusa", "unknown"):
        found = None
        for line in host.query("M200"):
            value = parse_filament_diameter(line)
            if value is not None:
                found = value
        if found is not None:
            return found, "M200"
    return host.filament_fallback, "default"


def query_info(host: PrinterHost) -> PrinterInfo:
    """Ask the printer behind ``host`` what it is (read-only queries)."""
    nozzle, nozzle_source = _nozzle(host)
    volume, volume_source = _build_volume(host)
    filament, filament_source = _filament(host)
    temperatures: dict[str, list[float | None]] = {}
    for line in host.query("M105"):
        for key, (current, target) in parse_temperatures(line).items():
            temperatures[key] = [current, target]
    return PrinterInfo(
        firmware=host.firmware or "unknown",
        flavour=host.flavour,
        nozzle_diameter=round(float(nozzle), 3),
        nozzle_source=nozzle_source,
        build_volume=volume,
        build_volume_source=volume_source,
        filament_diameter=round(float(filament), 3),
        filament_source=filament_source,
        capabilities=dict(host.capabilities),
        fields=dict(host.fields),
        temperatures=temperatures,
    )
