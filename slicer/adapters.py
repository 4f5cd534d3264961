"""Adapters for installed desktop slicers: CuraEngine (Debian ``cura-engine``) and PrusaSlicer.

The same :class:`~slicer.profile.Profile` is mapped onto each tool's settings, the tool runs in
a subprocess, its failure is surfaced as :class:`SliceError` (one line, the tool's own
message), and a summary like the embedded slicer's is read back from the G-code.

CuraEngine pitfalls handled here: it evaluates no setting formulas (every derived value —
per-feature widths and speeds, infill line distance, thicknesses — is passed explicitly),
``material_diameter`` and the other extruder settings must follow ``-e0``, and it does not
centre the model without ``center_object=true``. It also needs Cura's definition files
(``fdmprinter.def.json`` + ``fdmextruder.def.json``), found via ``PREFLIGHT_CURA_DEFINITIONS``,
``CURA_ENGINE_SEARCH_PATH`` or ``/usr/share/cura/resources/definitions``.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from printer.gcode import lex
from repair.io import write_atomic
from slicer.errors import SliceError
from slicer.profile import Profile

BINARIES = {"cura": "CuraEngine", "prusa": "prusa-slicer"}
CURA_DEFINITION_DIRS = ("/usr/share/cura/resources/definitions",)

Progress = Callable[[str, float], None] | None


def find_binary(name: str) -> str | None:
    """Path of the tool for ``name`` ("cura" or "prusa"), or None when not installed."""
    exe = BINARIES.get(name)
    return shutil.which(exe) if exe else None


def cura_definitions() -> Path | None:
    """Folder holding fdmprinter.def.json and fdmextruder.def.json, or None."""
    candidates = []
    if os.environ.get("PREFLIGHT_CURA_DEFINITIONS"):
        candidates.append(os.environ["PREFLIGHT_CURA_DEFINITIONS"])
    candidates += [p for p in os.environ.get("CURA_ENGINE_SEARCH_PATH", "").split(os.pathsep) if p]
    candidates += list(CURA_DEFINITION_DIRS)
    for c in candidates:
        d = Path(c)
        if (d / "fdmprinter.def.json").is_file() and (d / "fdmextruder.def.json").is_file():
            return d
    return None


def available() -> dict[str, bool]:
    """Which external slicers can run here."""
    return {"cura": find_binary("cura") is not None and cura_definitions() is not None,
            "prusa": find_binary("prusa") is not None}


def _rendered_templates(profile: Profile) -> tuple[str, str]:
    from slicer.templates import render_template

    values = dict(profile.to_dict())
    values.update(layer_count=0, max_z=profile.build_volume[2], park_z=profile.build_volume[2],
                  park_y=profile.build_volume[1] * 0.9, travel_feedrate=profile.travel_speed * 60)
    return render_template(profile.start_gcode, values), render_template(profile.end_gcode, values)


def _num(x: float) -> str:
    return f"{x:.6g}"


# ---- PrusaSlicer ------------------------------------------------------------------------
_PRUSA_FLAVOUR = {"marlin": "marlin2", "klipper": "klipper", "reprapfirmware": "reprapfirmware"}


def prusa_args(profile: Profile) -> list[str]:
    """PrusaSlicer 2.5 command-line options equivalent to ``profile``."""
    p = profile
    bx, by, bz = p.build_volume
    start, end = _rendered_templates(p)
    # PrusaSlicer treats [..] and {..} as macros; our rendered templates contain neither
    opts = {
        "nozzle-diameter": p.nozzle_diameter, "filament-diameter": p.filament_diameter,
        "bed-shape": f"0x0,{_num(bx)}x0,{_num(bx)}x{_num(by)},0x{_num(by)}",
        "max-print-height": bz, "center": f"{_num(bx / 2)},{_num(by / 2)}",
        "gcode-flavor": _PRUSA_FLAVOUR[p.flavour],
        "layer-height": p.layer_height, "first-layer-height": p.first_layer_height,
        "extrusion-width": p.line_width, "perimeter-extrusion-width": p.line_width,
        "external-perimeter-extrusion-width": p.line_width,
        "infill-extrusion-width": p.line_width, "solid-infill-extrusion-width": p.line_width,
        "top-infill-extrusion-width": p.line_width,
        "first-layer-extrusion-width": p.first_layer_line_width,
        "perimeters": p.perimeters, "top-solid-layers": p.top_layers,
        "bottom-solid-layers": p.bottom_layers, "top-solid-min-thickness": 0,
        "bottom-solid-min-thickness": 0,
        "fill-density": f"{_num(p.infill_percent)}%",
        # PrusaSlicer refuses grid at 100 %; solid rectilinear is what the profile means there
        "fill-pattern": "rectilinear" if p.infill_percent >= 100 else p.infill_pattern,
        "fill-angle": p.infill_angle,
        "perimeter-speed": p.perimeter_speed,
        "external-perimeter-speed": p.external_perimeter_speed,
        "infill-speed": p.infill_speed, "solid-infill-speed": p.solid_infill_speed,
        "top-solid-infill-speed": p.solid_infill_speed, "travel-speed": p.travel_speed,
        "first-layer-speed": p.first_layer_speed, "default-acceleration": p.print_acceleration,
        "temperature": p.temperature, "first-layer-temperature": p.first_layer_temperature,
        "bed-temperature": p.bed_temperature,
        "first-layer-bed-temperature": p.first_layer_bed_temperature,
        "retract-length": p.retract_length, "retract-speed": p.retract_speed,
        "retract-lift": p.retract_lift, "retract-before-travel": p.retract_min_travel,
        "max-fan-speed": p.fan_speed, "min-fan-speed": p.fan_speed,
        "disable-fan-first-layers": p.disable_fan_first_layers,
        "slowdown-below-layer-time": p.min_layer_time, "min-print-speed": p.min_print_speed,
        "bridge-speed": p.bridge_speed, "bridge-fan-speed": p.bridge_fan_speed,
        "skirts": p.skirts, "skirt-distance": p.skirt_distance, "skirt-height": p.skirt_height,
        "extrusion-multiplier": p.extrusion_multiplier, "filament-density": p.filament_density,
        "resolution": p.resolution, "after-layer-gcode": "G92 E0",
        "seam-position": p.seam_position,  # rear | nearest | aligned, the same names
        "start-gcode": start, "end-gcode": end,
    }
    flags = {
        "thin-walls": p.thin_walls, "use-relative-e-distances": p.relative_e,
        "avoid-crossing-perimeters": p.avoid_crossing_perimeters,
        "gcode-comments": p.comments,
    }
    args: list[str] = []
    for k, v in opts.items():
        args += [f"--{k}", _num(v) if isinstance(v, float) else str(v)]
    for k, on in flags.items():
        args.append(f"--{k}" if on else f"--no-{k}")
    return args + prusa_support_args(p)


def prusa_support_args(profile: Profile) -> list[str]:
    """PrusaSlicer options for the profile's support and brim settings. PrusaSlicer's
    threshold is measured from the horizontal; it has no automatic brim, so ``brim = auto``
    maps to none."""
    p = profile
    args = ["--brim-width", _num(p.brim_width if p.brim == "on" else 0.0)]
    if p.support == "off":
        return args + ["--no-support-material"]
    opts = {
        "support-material-threshold": 90.0 - p.support_angle,
        "support-material-contact-distance": p.layer_height,
        "support-material-xy-spacing": p.support_xy_gap,
        # PrusaSlicer's spacings are the gaps between lines, ours centre to centre
        "support-material-spacing": max(p.support_spacing - p.line_width, 0.0),
        "support-material-interface-layers": p.support_interface_layers,
        "support-material-interface-spacing": max(p.support_interface_spacing - p.line_width,
                                                  0.0),
        "support-material-speed": p.support_speed,
        "support-material-interface-speed": p.support_interface_speed,
    }
    args += ["--support-material", "--support-material-auto"]
    if p.support == "buildplate":
        args.append("--support-material-buildplate-only")
    for k, v in opts.items():
        args += [f"--{k}", _num(float(v))]
    return args


# ---- CuraEngine -------------------------------------------------------------------------
_CURA_FLAVOUR = {"marlin": "RepRap (Marlin/Sprinter)", "klipper": "RepRap (Marlin/Sprinter)",
                 "reprapfirmware": "RepRap (RepRap)"}


def cura_settings(profile: Profile) -> tuple[dict[str, str], dict[str, str]]:
    """(global, extruder-0) CuraEngine settings for ``profile``, every derived value explicit."""
    p = profile
    bx, by, bz = p.build_volume
    start, end = _rendered_templates(p)
    w = p.line_width
    dens = p.infill_percent
    lines_per = 2.0 if p.infill_pattern == "grid" else 1.0
    infill_distance = 0.0 if dens <= 0 else w * 100.0 / dens * lines_per
    ext: dict[str, Any] = {
        "machine_nozzle_size": p.nozzle_diameter, "material_diameter": p.filament_diameter,
        "line_width": w, "wall_line_width": w, "wall_line_width_0": w, "wall_line_width_x": w,
        "skin_line_width": w, "infill_line_width": w, "skirt_brim_line_width": w,
        "initial_layer_line_width_factor": 100.0 * p.first_layer_line_width / w,
        "wall_line_count": p.perimeters, "wall_thickness": p.perimeters * w,
        "top_layers": p.top_layers, "bottom_layers": p.bottom_layers,
        "initial_bottom_layers": p.bottom_layers,
        "top_thickness": p.top_layers * p.layer_height,
        "bottom_thickness": p.bottom_layers * p.layer_height,
        "top_bottom_thickness": p.top_layers * p.layer_height,
        "infill_sparse_density": dens, "infill_line_distance": infill_distance,
        "infill_pattern": "grid" if p.infill_pattern == "grid" else "lines",
        "fill_outline_gaps": "true" if p.thin_walls else "false",
        "speed_print": p.perimeter_speed, "speed_wall": p.perimeter_speed,
        "speed_wall_0": p.external_perimeter_speed, "speed_wall_x": p.perimeter_speed,
        "speed_infill": p.infill_speed, "speed_topbottom": p.solid_infill_speed,
        "speed_roofing": p.solid_infill_speed, "speed_travel": p.travel_speed,
        "speed_layer_0": p.first_layer_speed, "speed_print_layer_0": p.first_layer_speed,
        "speed_travel_layer_0": p.travel_speed, "skirt_brim_speed": p.first_layer_speed,
        "acceleration_enabled": "false",
        "material_print_temperature": p.temperature,
        "material_print_temperature_layer_0": p.first_layer_temperature,
        "material_initial_print_temperature": p.first_layer_temperature,
        "material_final_print_temperature": p.temperature,
        "material_bed_temperature": p.bed_temperature,
        "material_bed_temperature_layer_0": p.first_layer_bed_temperature,
        "retraction_enable": "true" if p.retract_length > 0 else "false",
        "retraction_amount": p.retract_length, "retraction_speed": p.retract_speed,
        "retraction_retract_speed": p.retract_speed, "retraction_prime_speed": p.retract_speed,
        "retraction_min_travel": p.retract_min_travel,
        "retraction_hop_enabled": "true" if p.retract_lift > 0 else "false",
        "retraction_hop": p.retract_lift,
        "cool_fan_enabled": "true" if p.fan_speed > 0 else "false",
        "cool_fan_speed": p.fan_speed, "cool_fan_speed_min": p.fan_speed,
        "cool_fan_speed_max": p.fan_speed, "cool_fan_speed_0": 0,
        "cool_fan_full_layer": p.disable_fan_first_layers + 1,
        "cool_min_layer_time": p.min_layer_time, "cool_min_speed": p.min_print_speed,
        "bridge_settings_enabled": "true", "bridge_skin_speed": p.bridge_speed,
        "bridge_fan_speed": p.bridge_fan_speed,
        "z_seam_type": {"rear": "back", "nearest": "shortest"}.get(p.seam_position,
                                                                   "sharpest_corner"),
        "retraction_combing": "all" if p.avoid_crossing_perimeters else "off",
        "material_flow": 100.0 * p.extrusion_multiplier,
    }
    glob: dict[str, Any] = {
        "machine_width": bx, "machine_depth": by, "machine_height": bz,
        "machine_center_is_zero": "false", "machine_heated_bed": "true",
        "machine_gcode_flavor": _CURA_FLAVOUR[p.flavour],
        "machine_start_gcode": start, "machine_end_gcode": end,
        "layer_height": p.layer_height, "layer_height_0": p.first_layer_height,
        "infill_sparse_thickness": p.layer_height,
        "support_infill_sparse_thickness": p.layer_height,
        "adhesion_type": "skirt" if p.skirts > 0 else "none",
        "skirt_line_count": p.skirts, "skirt_gap": p.skirt_distance,
        "relative_extrusion": "true" if p.relative_e else "false",
        "center_object": "true", "machine_extruder_count": 1,
    }
    glob.update(ext)  # global copies: settings read at mesh-group level see the same values
    conv = {k: (_num(v) if isinstance(v, float) else str(v)) for k, v in glob.items()}
    conv_e = {k: (_num(v) if isinstance(v, float) else str(v)) for k, v in ext.items()}
    return conv, conv_e


def cura_command(profile: Profile, in_path: Path, out_path: Path, exe: str, defs: Path
                 ) -> list[str]:
    """CuraEngine argv: global settings, then ``-e0`` with extruder settings, then the model."""
    glob, ext = cura_settings(profile)
    cmd = [exe, "slice", "-v", "-j", str(defs / "fdmprinter.def.json")]
    for k, v in glob.items():
        cmd += ["-s", f"{k}={v}"]
    cmd += ["-e0"]
    for k, v in ext.items():
        cmd += ["-s", f"{k}={v}"]
    cmd += ["-l", str(in_path), "-o", str(out_path)]
    return cmd


def cura_print_time(log: str) -> float | None:
    """CuraEngine's own time estimate from its verbose log (seconds), or None."""
    m = re.search(r"^Print time \(s\): (\d+)", log, re.MULTILINE)
    return float(m.group(1)) if m else None


# ---- running and reading back ----------------------------------------------------------
def _error_line(text: str, tool: str, code: int) -> str:
    # drop PrusaSlicer's timestamped log chatter: "[2026-...] [0x...] [trace] ..."
    lines = [ln.strip() for ln in text.splitlines()
             if ln.strip() and not re.match(r"^\[\d{4}-\d\d-\d\d ", ln.strip())]
    errs = [ln for ln in lines if "error" in ln.lower()]
    msg = (errs or lines or [f"exit status {code}"])[-1]
    return f"{tool} failed: {msg[:300]}"


def gcode_summary(text: str, profile: Profile) -> dict[str, Any]:
    """Layers, filament and time read from any slicer's G-code (E replayed, M82/M83/G92)."""
    rel = False
    e = 0.0
    total = 0.0
    for raw in text.splitlines():
        lexed = lex(raw)
        head = lexed.word
        if head in ("G0", "G1"):
            val = lexed.value("E")
            if val is not None:
                de = val if rel else val - e
                e = e + val if rel else val
                total += de
        elif head == "M83":
            rel = True
        elif head == "M82":
            rel = False
        elif head == "G92":
            val = lexed.value("E")
            if val is not None:
                e = val
    seconds = None
    m = re.search(r"estimated printing time \(normal mode\) = (.+)", text)
    if m:
        seconds = 0.0
        for num, unit in re.findall(r"(\d+)([dhms])", m.group(1)):
            seconds += int(num) * {"d": 86400, "h": 3600, "m": 60, "s": 1}[unit]
    m = re.search(r"^;TIME:(\d+)", text, re.MULTILINE)
    if seconds is None and m:
        seconds = float(m.group(1))
    layers = len(re.findall(r"^;(?:LAYER_CHANGE|LAYER:\d+)", text, re.MULTILINE))
    cm3 = total * profile.filament_area / 1000.0
    return {
        "layers": layers, "filament_mm": round(total, 2), "filament_cm3": round(cm3, 3),
        "filament_g": round(cm3 * profile.filament_density, 2),
        "estimated_seconds": seconds,
    }


def slice_external(name: str, in_path: str | os.PathLike, out_path: str | os.PathLike,
                   profile: Profile, *, progress: Progress = None, timeout: float = 3600.0
                   ) -> dict[str, Any]:
    """Slice with an installed slicer ("cura" or "prusa"); returns a summary dict."""
    exe = find_binary(name)
    if exe is None:
        raise SliceError(f"{BINARIES.get(name, name)} is not installed")
    src = Path(in_path)
    dst = Path(out_path)
    if not src.is_file():
        raise SliceError(f"no such file: {src}")
    dst.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dst.name}.", suffix=".gcode", dir=str(dst.parent))
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        if name == "cura":
            defs = cura_definitions()
            if defs is None:
                raise SliceError("CuraEngine needs Cura's fdmprinter.def.json: install the "
                                 "'cura' package or set CURA_ENGINE_SEARCH_PATH")
            cmd = cura_command(profile, src, tmp, exe, defs)
            env = dict(os.environ, CURA_ENGINE_SEARCH_PATH=str(defs))
        else:
            cmd = [exe, "--export-gcode", *prusa_args(profile), "--output", str(tmp), str(src)]
            env = dict(os.environ)
        if progress:
            progress(name, 0.0)
        try:
            res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
        except subprocess.TimeoutExpired:
            raise SliceError(f"{BINARIES[name]} did not finish within {timeout:.0f} s") from None
        data = tmp.read_bytes() if tmp.exists() else b""
        text = data.decode("utf-8", errors="replace")
        if res.returncode != 0 or not text.strip():
            raise SliceError(_error_line(res.stderr + "\n" + res.stdout, BINARIES[name],
                                         res.returncode))
        if name == "cura" and "[ERROR]" in res.stderr:
            bad = [ln for ln in res.stderr.splitlines() if "[ERROR]" in ln]
            raise SliceError(f"CuraEngine: {bad[0].replace('[ERROR]', '').strip()[:300]}")
        write_atomic(dst, [data])
    finally:
        if tmp.exists():
            tmp.unlink()
    summary = gcode_summary(text, profile)
    if name == "cura":  # the ;TIME: header is a placeholder the Cura front end fills in
        summary["estimated_seconds"] = cura_print_time(res.stderr)
    if summary["estimated_seconds"] is None or not math.isfinite(summary["estimated_seconds"]):
        summary["estimated_seconds"] = None
    summary["slicer"] = name
    summary["output"] = str(dst)
    if progress:
        progress(name, 1.0)
    return summary


def slice_with(name: str, in_path: str | os.PathLike, out_path: str | os.PathLike,
               profile: Profile, *, progress: Progress = None) -> dict[str, Any]:
    """Slice with the named engine: "embedded" (default), "cura" or "prusa"."""
    if name in ("", "embedded", None):
        from slicer.engine import slice_file

        return slice_file(in_path, out_path, profile, progress=progress)
    if name not in BINARIES:
        raise SliceError(f"unknown slicer {name!r} (embedded, cura or prusa)")
    return slice_external(name, in_path, out_path, profile, progress=progress)
