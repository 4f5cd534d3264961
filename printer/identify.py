"""Who the printer is and what it can do: the M115 report and read-only capability queries.

Nozzle: Prusa's ``M862.1 Q``; for Klipper its API socket or ``printer.cfg``
(:mod:`printer.klipper_api`), then a Klipper macro; else the configured or default value.
Build volume: RepRapFirmware's object model (``M409 K"move.axes"``), else its M208;
Klipper's stepper limits (API socket or ``printer.cfg``); Marlin's M211 soft endstops,
the M115 ``area:`` report, else a Prusa model's nominal volume. Filament: M200.
Temperatures: M105. Every value comes with its source. Never a command that changes
anything (never ``M862.1 P``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from printer.firmware import family_of
from printer.info import PrinterInfo
from printer.klipper_api import DEFAULT_SOCKET, KlipperCapabilities, klipper_capabilities
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


def _nozzle(host: PrinterHost, klipper: KlipperCapabilities | None) -> tuple[float, str]:
    if host.flavour in ("prusa", "buddy", "marlin"):
        value = _first_value(host, "M862.1 Q", parse_nozzle_reply)
        if value is not None:
            return value, "M862.1"
    if klipper is not None and klipper.nozzle_diameter is not None:
        return klipper.nozzle_diameter, klipper.source
    if host.nozzle_macro:
        value = _first_value(host, host.nozzle_macro, parse_nozzle_reply)
        if value is not None:
            return value, f"macro:{host.nozzle_macro}"
    if host.nozzle_fallback is not None:
        return float(host.nozzle_fallback), "config"
    return DEFAULT_NOZZLE, "default"


def parse_object_model_axes(lines: list[str]) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """RepRapFirmware 3's reply to ``M409 K"move.axes"``: the JSON line
    ``{"key":"move.axes","flags":"","result":[{"letter":"X","min":0,"max":235,...},...]}``
    -> ((xmin, ymin, zmin), (xmax, ymax, zmax)) in mm, or None."""
    for line in lines:
        text = line.strip()
        if not text.startswith("{"):
            continue
        try:
            reply = json.loads(text)
        except ValueError:
            continue
        if not isinstance(reply, dict) or not isinstance(reply.get("result"), list):
            continue
        axes = {}
        for axis in reply["result"]:
            if isinstance(axis, dict) and axis.get("letter") in ("X", "Y", "Z"):
                low, high = axis.get("min"), axis.get("max")
                if all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       for v in (low, high)) and high > low:
                    axes[axis["letter"]] = (float(low), float(high))
        if len(axes) == 3:
            return tuple(axes[a][0] for a in "XYZ"), tuple(axes[a][1] for a in "XYZ")
    return None


def _build_volume(host: PrinterHost,
                  klipper: KlipperCapabilities | None) -> tuple[list[float] | None, str | None]:
    volume, source = None, None
    if host.flavour == "rrf":
        limits = parse_object_model_axes(host.query('M409 K"move.axes"'))
        if limits:
            volume, source = extent(limits), 'M409 K"move.axes"'
        else:
            for line in host.query("M208"):
                limits = parse_axis_limits(line)
                if limits:
                    volume, source = extent(limits), "M208"
    elif host.flavour == "klipper":
        if klipper is not None and klipper.limits is not None:
            volume, source = extent(klipper.limits), klipper.source
    else:
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


def query_info(host: PrinterHost, *, klipper_socket: str | os.PathLike | None = DEFAULT_SOCKET,
               klipper_config: str | os.PathLike | None = None) -> PrinterInfo:
    """Ask the printer behind ``host`` what it is (read-only queries). For Klipper, its
    API socket ``klipper_socket`` is asked, else ``klipper_config`` (printer.cfg) read."""
    klipper = None
    if host.flavour == "klipper":
        klipper, _problems = klipper_capabilities(klipper_socket, klipper_config)
    nozzle, nozzle_source = _nozzle(host, klipper)
    volume, volume_source = _build_volume(host, klipper)
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
