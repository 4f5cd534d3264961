"""Print profile: every setting the embedded slicer uses, with defaults derived from the printer.

Units: lengths mm, speeds mm/s, accelerations mm/s², temperatures °C, fan and infill in %.
A :class:`Profile` is immutable; derive variants with :meth:`Profile.with_overrides` or
:func:`load_profile` (TOML). Values are validated on construction; a bad value or an unknown
key raises :class:`ProfileError` whose message names the setting.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from printer.firmware import SLICER_FLAVOURS, slicer_flavour

FLAVOURS = SLICER_FLAVOURS
INFILL_PATTERNS = ("rectilinear", "grid")
SEAM_POSITIONS = ("rear", "nearest", "aligned")
ORIENT_MODES = ("keep", "auto", "if-needed")
#: auto: support where an overhang needs it (steeper than support_angle, not a bridge, at
#: least support_min_area), standing on the build plate and, where the plate cannot be
#: reached (a chin over a paw), on the part; buildplate: only columns that reach the plate;
#: everywhere: like auto, small overhang islands included; off: none.
SUPPORT_MODES = ("auto", "buildplate", "everywhere", "off")
#: auto: a brim when the first layer's contact is small against the part's height (see
#: slicer.brim.needs_brim); on: always; off: never.
BRIM_MODES = ("auto", "on", "off")

DEFAULT_START_GCODE = """\
M140 S{first_layer_bed_temperature:.0f} ; bed
M104 S{first_layer_temperature:.0f} ; hotend
M190 S{first_layer_bed_temperature:.0f}
M109 S{first_layer_temperature:.0f}
G28 ; home all axes
"""

DEFAULT_END_GCODE = """\
M104 S0 ; hotend off
M140 S0 ; bed off
M107 ; fan off
G1 Z{park_z:.3f} F600 ; lift away from the print
G1 X0 Y{park_y:.3f} F{travel_feedrate:.0f} ; present the print
M84 ; motors off
"""


class ProfileError(ValueError):
    """A profile setting is unknown or out of range; the message names the setting."""


@dataclass(frozen=True)
class Profile:
    """All slicer settings (mm, mm/s, mm/s², °C, %). Invariants are checked in __post_init__."""

    # machine
    nozzle_diameter: float = 0.4
    filament_diameter: float = 1.75
    build_volume: tuple[float, float, float] = (220.0, 220.0, 250.0)
    flavour: str = "marlin"
    # layers and widths
    layer_height: float = 0.2
    first_layer_height: float = 0.2
    line_width: float = 0.45
    first_layer_line_width: float = 0.5
    resolution: float = 0.0125
    # shells
    perimeters: int = 2
    top_layers: int = 4
    bottom_layers: int = 3
    thin_walls: bool = True
    seam_position: str = "rear"
    # infill
    infill_percent: float = 20.0
    infill_pattern: str = "grid"
    infill_angle: float = 45.0
    # speeds (mm/s)
    perimeter_speed: float = 45.0
    external_perimeter_speed: float = 35.0
    infill_speed: float = 80.0
    solid_infill_speed: float = 60.0
    thin_wall_speed: float = 30.0
    bridge_speed: float = 25.0
    travel_speed: float = 150.0
    first_layer_speed: float = 20.0
    # motion (for the time estimate)
    print_acceleration: float = 1000.0
    travel_acceleration: float = 1500.0
    max_jerk: float = 8.0
    # temperatures (°C)
    temperature: float = 210.0
    first_layer_temperature: float = 215.0
    bed_temperature: float = 60.0
    first_layer_bed_temperature: float = 60.0
    # retraction
    retract_length: float = 0.8
    retract_speed: float = 35.0
    retract_lift: float = 0.0
    retract_min_travel: float = 2.0
    # cooling
    fan_speed: float = 100.0
    disable_fan_first_layers: int = 1
    min_layer_time: float = 5.0
    bridge_fan_speed: float = 100.0
    min_print_speed: float = 10.0
    bridge_flow: float = 1.0  # extrusion multiplier of bridge lines, relative
    # support (slicer.support); angles from vertical, gaps mm
    support: str = "auto"
    support_angle: float = 50.0
    support_xy_gap: float = 0.4
    support_spacing: float = 2.5  # base lines, centre to centre (2.05 mm of gap)
    support_interface_layers: int = 2
    support_interface_spacing: float = 0.6
    support_speed: float = 50.0
    support_interface_speed: float = 30.0
    support_flow: float = 1.0  # extrusion multiplier of support lines, relative
    support_min_area: float = 1.0  # mm²; auto leaves smaller overhang islands alone
    # adhesion
    brim: str = "auto"
    brim_width: float = 5.0
    # skirt
    skirts: int = 1
    skirt_distance: float = 3.0
    skirt_height: int = 1
    # extrusion
    relative_e: bool = True
    extrusion_multiplier: float = 1.0
    filament_density: float = 1.24
    # templates (str.format with the profile's fields plus a few per-job values)
    start_gcode: str = DEFAULT_START_GCODE
    end_gcode: str = DEFAULT_END_GCODE
    comments: bool = True
    # placement, travel and thumbnails (slicer/orient.py, arrange.py, travel.py, thumbnail.py)
    orient: str = "keep"
    arrange: bool = False
    arrange_gap: float = 6.0
    avoid_crossing_perimeters: bool = True
    thumbnails: str = "16x16,220x124"

    def __post_init__(self) -> None:
        bv = tuple(float(v) for v in self.build_volume)
        if len(bv) != 3 or not all(v > 0 and math.isfinite(v) for v in bv):
            raise ProfileError(f"build_volume must be three positive sizes in mm, got {bv}")
        object.__setattr__(self, "build_volume", bv)
        positive = (
            "nozzle_diameter", "filament_diameter", "layer_height", "first_layer_height",
            "line_width", "first_layer_line_width", "resolution", "perimeter_speed",
            "external_perimeter_speed", "infill_speed", "solid_infill_speed", "thin_wall_speed",
            "bridge_speed",
            "travel_speed", "first_layer_speed", "print_acceleration", "travel_acceleration",
            "max_jerk", "retract_speed", "extrusion_multiplier", "filament_density",
            "min_print_speed", "bridge_flow", "support_spacing", "support_interface_spacing",
            "support_speed", "support_interface_speed", "support_flow",
        )
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ProfileError(f"{name} must be a positive number, got {v!r}")
        non_negative = (
            "perimeters", "top_layers", "bottom_layers", "infill_percent", "retract_length",
            "retract_lift", "retract_min_travel", "fan_speed", "disable_fan_first_layers",
            "min_layer_time", "bridge_fan_speed",
            "skirts", "skirt_distance", "skirt_height", "temperature", "first_layer_temperature",
            "bed_temperature", "first_layer_bed_temperature", "support_xy_gap",
            "support_interface_layers", "support_min_area", "brim_width",
        )
        for name in non_negative:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ProfileError(f"{name} must be zero or more, got {v!r}")
        if self.infill_percent > 100:
            raise ProfileError(f"infill_percent must be 0..100, got {self.infill_percent}")
        for name in ("fan_speed", "bridge_fan_speed"):
            if getattr(self, name) > 100:
                raise ProfileError(f"{name} must be 0..100 %, got {getattr(self, name)}")
        if self.flavour not in FLAVOURS:
            raise ProfileError(
                f"flavour must be one of {', '.join(FLAVOURS)}, got {self.flavour!r}"
            )
        if self.infill_pattern not in INFILL_PATTERNS:
            raise ProfileError(
                f"infill_pattern must be one of {', '.join(INFILL_PATTERNS)}, "
                f"got {self.infill_pattern!r}"
            )
        _check_placement(self)
        if self.seam_position not in SEAM_POSITIONS:
            raise ProfileError(
                f"seam_position must be one of {', '.join(SEAM_POSITIONS)}, "
                f"got {self.seam_position!r}"
            )
        for name, allowed in (("support", SUPPORT_MODES), ("brim", BRIM_MODES)):
            if getattr(self, name) not in allowed:
                raise ProfileError(
                    f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}"
                )
        if not 0 < self.support_angle < 90:
            raise ProfileError(
                f"support_angle must be between 0 and 90 degrees, got {self.support_angle}")
        for name, h in (("layer_height", self.layer_height),
                        ("first_layer_height", self.first_layer_height)):
            if h > self.nozzle_diameter:
                raise ProfileError(
                    f"{name} {h} mm exceeds the nozzle diameter {self.nozzle_diameter} mm"
                )
        for name, w in (("line_width", self.line_width),
                        ("first_layer_line_width", self.first_layer_line_width)):
            if w <= self.layer_height * (1 - math.pi / 4) or w > 3 * self.nozzle_diameter:
                raise ProfileError(f"{name} {w} mm is out of range for this nozzle")

    @classmethod
    def for_printer(
        cls,
        nozzle_diameter: float = 0.4,
        build_volume: tuple[float, float, float] | None = None,
        filament_diameter: float = 1.75,
        flavour: str = "marlin",
    ) -> Profile:
        """Defaults derived from the printer: line width 1.125 × nozzle, layer 0.5 × nozzle.

        ``flavour`` also accepts the printer area's firmware names (prusa, buddy, rrf, ...).
        """
        n = float(nozzle_diameter)
        if not (math.isfinite(n) and n > 0):
            raise ProfileError(
                f"nozzle_diameter must be a positive number, got {nozzle_diameter!r}"
            )
        kwargs: dict[str, Any] = dict(
            nozzle_diameter=n,
            filament_diameter=float(filament_diameter),
            flavour=slicer_flavour(flavour) or str(flavour),
            layer_height=round(0.5 * n, 4),
            first_layer_height=round(0.5 * n, 4),
            line_width=round(1.125 * n, 4),
            first_layer_line_width=round(1.25 * n, 4),
        )
        if build_volume is not None:
            kwargs["build_volume"] = tuple(float(v) for v in build_volume)
        return cls(**kwargs)

    def with_overrides(self, mapping: Mapping[str, Any]) -> Profile:
        """A copy with the given settings replaced; strings are parsed to the field's type."""
        known = {f.name: f for f in fields(self) if not f.name.startswith("_")}
        changes: dict[str, Any] = {}
        for key, value in mapping.items():
            if key not in known:
                raise ProfileError(f"unknown profile setting {key!r}")
            changes[key] = _coerce(key, getattr(self, key), value)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """All settings as plain JSON/TOML-serialisable values."""
        out = {}
        for f in fields(self):
            if f.name.startswith("_"):
                continue
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    # derived quantities -------------------------------------------------------------
    @property
    def filament_area(self) -> float:
        """Cross-section of the filament, mm²."""
        return math.pi * (self.filament_diameter / 2) ** 2


def thumbnail_sizes(spec: str) -> list[tuple[int, int]]:
    """Parse ``thumbnails`` ("16x16,220x124"; "" for none) into (width, height) pairs."""
    out: list[tuple[int, int]] = []
    for item in spec.replace(" ", "").split(","):
        if not item:
            continue
        w, sep, h = item.lower().partition("x")
        if not (sep and w.isdigit() and h.isdigit() and 8 <= int(w) <= 1024
                and 8 <= int(h) <= 1024):
            raise ProfileError(f"thumbnails must be sizes like 16x16,220x124 (8..1024 px), "
                               f"got {spec!r}")
        out.append((int(w), int(h)))
    return out


def _check_placement(p: Profile) -> None:
    if p.orient not in ORIENT_MODES:
        raise ProfileError(f"orient must be one of {', '.join(ORIENT_MODES)}, got {p.orient!r}")
    if not (math.isfinite(p.arrange_gap) and p.arrange_gap >= 0):
        raise ProfileError(f"arrange_gap must be zero or more, got {p.arrange_gap!r}")
    thumbnail_sizes(p.thumbnails)


def _coerce(key: str, current: Any, value: Any) -> Any:
    try:
        if isinstance(current, bool):
            if isinstance(value, str):
                low = value.strip().lower()
                if low in ("1", "true", "yes", "on"):
                    return True
                if low in ("0", "false", "no", "off"):
                    return False
                raise ValueError(value)
            return bool(value)
        if isinstance(current, int):
            f = float(value)
            if f != int(f):
                raise ValueError(value)
            return int(f)
        if isinstance(current, float):
            return float(value)
        if isinstance(current, tuple):
            if isinstance(value, str):
                value = [v for v in value.replace("x", ",").split(",") if v.strip()]
            return tuple(float(v) for v in value)
        if isinstance(current, str):
            if not isinstance(value, str):
                raise ValueError(value)
            return value
    except (TypeError, ValueError):
        raise ProfileError(f"profile setting {key!r} cannot take the value {value!r}") from None
    return value


def load_profile(path: str | Path, base: Profile) -> Profile:
    """Read a TOML profile (flat keys, or under a [slicer] / [profile] table) over ``base``."""
    import tomllib  # here: only a run with a profile file pays for the TOML parser's import

    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ProfileError(f"cannot read profile {p}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ProfileError(f"profile {p} is not valid TOML: {exc}") from None
    for table in ("slicer", "profile"):
        if set(data) == {table} and isinstance(data[table], dict):
            data = data[table]
    return base.with_overrides(data)
