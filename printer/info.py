"""What the printer told us about itself."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field


@dataclass(frozen=True)
class PrinterInfo:
    """Capabilities read from the printer.

    firmware: ``FIRMWARE_NAME`` as reported (e.g. ``"Marlin 2.1.2.1 (...)"``).
    flavour: one of marlin, prusa, buddy, klipper, rrf, unknown.
    nozzle_diameter (mm) and nozzle_source (``"M862.1"``, ``"macro:<name>"``,
    ``"config"`` or ``"default"``). build_volume: [x, y, z] mm or None, with
    build_volume_source (``"M211"``, ``"M208"``, ``"M115 area"``, ``"machine type"``).
    filament_diameter (mm) with filament_source. capabilities: ``Cap:`` flags.
    """

    firmware: str
    flavour: str
    nozzle_diameter: float
    nozzle_source: str
    build_volume: list[float] | None
    build_volume_source: str | None
    filament_diameter: float
    filament_source: str
    capabilities: dict[str, bool] = field(default_factory=dict)
    fields: dict[str, str] = field(default_factory=dict)
    temperatures: dict[str, list[float | None]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-serialisable view (keys as in the team contract)."""
        return asdict(self)
