"""The embedded slicer's entry points: a closed mesh (mm) in, G-code and a summary out.

``slice_mesh`` places the model (dropped onto z = 0, centred on the bed), slices it with
manifold3d at mid-layer heights, plans shells/skins/infill per layer, orders travels and emits
G-code with M73 progress. ``summary`` holds layers, filament_mm, filament_cm3, filament_g and
estimated_seconds (trapezoidal motion estimate; heating time is not included), plus support
("off", "none needed" or the mode used), support_cm3, support_seconds and brim. Support
(slicer.support, slicer.overhang) and the brim (slicer.brim) are planned before the layers.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path as FsPath
from typing import Any

import numpy as np

from slicer.errors import SliceError
from slicer.profile import Profile

__all__ = ["SliceError", "SliceResult", "slice_mesh", "slice_file", "write_gcode"]

Progress = Callable[[str, float], None] | None


@dataclass(frozen=True)
class SliceResult:
    """G-code text and a JSON-serialisable summary of the job."""

    gcode: str
    summary: dict[str, Any]


def _to_manifold(vertices: np.ndarray, faces: np.ndarray):
    from manifold3d import Manifold, Mesh

    mesh = Mesh(vert_properties=np.ascontiguousarray(vertices, dtype=np.float32),
                tri_verts=np.ascontiguousarray(faces, dtype=np.uint32))
    man = Manifold(mesh)
    status = man.status()
    if str(status) != "Error.NoError":
        raise SliceError(f"mesh is not a closed manifold solid ({str(status).split('.')[-1]}); "
                         "repair it first")
    if not man.is_empty() and man.volume() < 0:
        # closed but inside out (every normal pointing in): slice the same solid, turned out
        return _to_manifold(vertices, faces[:, ::-1])
    if man.is_empty() or man.volume() <= 0:
        raise SliceError("mesh encloses no volume")
    return man


def slice_mesh(vertices: Any, faces: Any, profile: Profile, *, progress: Progress = None
               ) -> SliceResult:
    """Slice a closed triangle mesh (mm) with ``profile``; raises SliceError on bad input."""
    from slicer import geometry as geo
    from slicer.arrange import layout_model
    from slicer.gcode import GcodeWriter, fan_command, m73, start_block
    from slicer.ordering import order_paths
    from slicer.planner import LayerPlan, infill_paths, plan_shells, skin_regions, skirt_paths
    from slicer.profile import thumbnail_sizes
    from slicer.templates import render_template
    from slicer.thumbnail import thumbnail_blocks
    from slicer.travel import SeamAligner, TravelRouter

    last = ["", -1.0]

    def report(stage: str, fraction: float) -> None:
        """Called for every layer in every stage with the fraction of the whole job (0..1);
        forwarded when the stage changes or the job moved on by ≥ 0.5 %."""
        if progress is None:
            return
        fraction = float(min(max(fraction, 0.0), 1.0))
        if stage != last[0] or fraction - last[1] >= 0.005 or fraction >= 1.0:
            last[0], last[1] = stage, fraction
            progress(stage, fraction)

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise SliceError("mesh has no triangles")
    if not np.isfinite(v).all():
        raise SliceError("mesh has non-finite vertex coordinates")
    if f.min() < 0 or f.max() >= len(v):
        raise SliceError("mesh faces index missing vertices")
    v, f = geo.merge_vertices(v, f.astype(np.int64))
    v, layout = layout_model(v, f, profile)  # orient = keep | auto | if-needed; arrange
    v, size = geo.place_on_bed(v, profile.build_volume)
    man = _to_manifold(v, f)
    tops = geo.layer_tops(float(size[2]), profile.first_layer_height, profile.layer_height)
    if len(tops) == 0:
        raise SliceError(f"model is only {size[2]:.3f} mm tall, thinner than half a first layer")
    heights = np.diff(tops, prepend=0.0)
    mids = tops - heights / 2
    n = len(tops)
    res = profile.resolution
    values = dict(profile.to_dict())
    values.update(
        layer_count=n, max_z=float(tops[-1]),
        park_z=float(min(tops[-1] + 10.0, profile.build_volume[2])),
        park_y=float(profile.build_volume[1] * 0.9),
        travel_feedrate=profile.travel_speed * 60.0,
    )
    try:  # before the heavy work: a bad template fails fast
        head = start_block(profile, values)
        tail = render_template(profile.end_gcode, values)
    except ValueError as exc:
        raise SliceError(str(exc)) from None

    sections = []
    for i, z in enumerate(mids):
        sections.append(man.slice(float(z)).simplify(res))
        report("slice", i / n * 0.2)
    del man

    widths = [profile.first_layer_line_width if i == 0 else profile.line_width for i in range(n)]
    shells = []
    for i in range(n):
        shells.append(plan_shells(sections[i], widths[i], float(heights[i]), profile.perimeters,
                                  profile.thin_walls, res))
        report("shells", 0.2 + i / n * 0.2)
    spacing = [geo.bead_spacing(widths[i], float(heights[i])) for i in range(n)]
    solids = skin_regions([s.inner for s in shells], sections, profile.top_layers,
                          profile.bottom_layers, spacing, profile.infill_percent >= 100)
    report("skins", 0.45)
    from manifold3d import CrossSection

    from slicer.brim import brim_paths, needs_brim
    from slicer.support import bead_area_of, support_paths, support_regions

    supports = support_regions(sections, heights, profile, widths,
                               [bead_area_of(sh.thin) for sh in shells])
    report("support", 0.5)
    brim, first_area = [], sections[0]
    if needs_brim(profile, sections[0], float(tops[-1])):
        brim, covered = brim_paths(profile, sections[0], widths[0], float(heights[0]))
        first_area = first_area + covered
    if supports is not None:
        first_area = first_area + supports[0].area()

    # plan, order and write one layer at a time, so only one layer's paths exist at once
    writer = GcodeWriter(profile)
    aligner = SeamAligner() if profile.seam_position == "aligned" else None
    pos = np.array([0.0, 0.0])
    bodies: list[str] = []
    seconds: list[float] = []
    filament = support_mm = support_s = 0.0
    support_cache: dict = {}
    for i in range(n):
        sh = shells[i]
        h = float(heights[i])
        paths = []
        if i < profile.skirt_height:
            paths.extend(skirt_paths(profile, first_area, widths[i], h))
        if i == 0:
            paths.extend(brim)
        if supports is not None:
            paths.extend(support_paths(supports[i], profile, widths[i], h, support_cache))
            supports[i] = None
        paths.extend(sh.loops)
        paths.extend(sh.thin)
        paths.extend(infill_paths(profile, i, sh.inner, solids[i], widths[i], h,
                                  sections[i - 1] if i > 0 else None,
                                  sections[i + 1] if i + 1 < n else CrossSection()))
        plan = LayerPlan(i, float(tops[i]), h, paths, geo.contours(sections[i]))
        ordered, _ = order_paths(plan.paths, pos, profile.seam_position, aligner)
        router = TravelRouter(sections[i], spacing[i]) \
            if profile.avoid_crossing_perimeters else None
        code = writer.layer(plan, ordered, pos, router)
        bodies.append(code.text)
        seconds.append(code.seconds + 0.1)  # Z move and layer change
        filament += code.filament_mm
        support_mm += code.support_mm
        support_s += code.support_seconds
        pos = code.end_pos
        shells[i] = solids[i] = None  # free as we go
        if i > 0:
            sections[i - 1] = None  # (section 0 stays: the skirt follows it)
        report("gcode", 0.5 + i / n * 0.5)
    del shells, solids, sections, first_area
    if filament <= 0:
        raise SliceError("nothing to print: the model produced no extrusions")

    total = float(sum(seconds))
    p = profile
    cm3 = filament * p.filament_area / 1000.0
    summary = {
        "layers": n,
        "filament_mm": round(filament, 2),
        "filament_cm3": round(cm3, 3),
        "filament_g": round(cm3 * p.filament_density, 2),
        "estimated_seconds": round(total, 1),
        "height_mm": round(float(tops[-1]), 3),
        "size_mm": [round(float(s), 3) for s in size],
        "slicer": "embedded",
        "support": profile.support if supports is not None else "none needed"
        if profile.support != "off" else "off",
        "support_cm3": round(support_mm * p.filament_area / 1000.0, 3),
        "support_seconds": round(support_s, 1),
        "brim": bool(brim),
        **layout,
    }
    parts: list[str] = []
    sizes = thumbnail_sizes(p.thumbnails)
    if sizes:  # first in the file, where printers and UIs look for them
        parts.append(thumbnail_blocks(v, f, sizes))
        summary["thumbnails"] = [f"{w}x{h}" for w, h in sizes]
    if p.comments:
        parts.append(
            "; generated by preflight embedded slicer\n"
            f"; layers: {n}, filament: {filament:.1f} mm ({cm3:.2f} cm3), "
            f"estimated time: {total:.0f} s\n"
            f"; nozzle {p.nozzle_diameter} mm, layer {p.layer_height} mm, "
            f"line {p.line_width} mm, infill {p.infill_percent:g}% {p.infill_pattern}\n"
        )
    parts.append(head)
    done = 0.0
    z_feed = 600.0
    for i, body in enumerate(bodies):
        z = tops[i]
        parts.append(f";LAYER:{i}\n;Z:{z:.3f}\n" if p.comments else "")
        parts.append(m73(100.0 * done / total if total > 0 else 0, total - done))
        if i == 1:
            if p.temperature != p.first_layer_temperature:
                parts.append(f"M104 S{p.temperature:.0f}\n")
            if p.bed_temperature != p.first_layer_bed_temperature:
                parts.append(f"M140 S{p.bed_temperature:.0f}\n")
        if i == p.disable_fan_first_layers:
            parts.append(fan_command(p.fan_speed))
        parts.append(f"G1 Z{z:.3f} F{z_feed:.0f}\n")
        parts.append(body)
        done += seconds[i]
    parts.append("M73 P100 R0\n")
    parts.append(tail)
    report("done", 1.0)
    return SliceResult("".join(parts), summary)


def _load_mesh(path: FsPath) -> tuple[np.ndarray, np.ndarray]:
    """Read any mesh format preflight accepts, through repair.io (the one reader)."""
    from repair.io import MeshReadError, load_mesh

    try:
        mesh = load_mesh(path)
    except MeshReadError as exc:
        raise SliceError(str(exc)) from None
    return mesh.vertices, mesh.faces


def slice_file(in_path: str | os.PathLike, out_path: str | os.PathLike, profile: Profile, *,
               progress: Progress = None) -> dict[str, Any]:
    """Slice a mesh file into G-code at ``out_path`` (written atomically); returns the summary."""
    src = FsPath(in_path)
    dst = FsPath(out_path)
    vertices, faces = _load_mesh(src)
    result = slice_mesh(vertices, faces, profile, progress=progress)
    write_gcode(dst, result.gcode)
    summary = dict(result.summary)
    summary["output"] = str(dst)
    return summary


def write_gcode(path: str | os.PathLike, text: str) -> None:
    """Write G-code atomically (temporary file in the same folder, then rename)."""
    from repair.io import write_atomic

    write_atomic(path, [text.encode("utf-8")])
