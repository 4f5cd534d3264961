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
from dataclasses import dataclass, field
from pathlib import Path as FsPath
from typing import Any

import numpy as np

from slicer.errors import SliceError
from slicer.layers import Written
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


class _Reporter:
    """Forwards ``(stage, fraction of the whole job)`` to ``progress`` when the stage
    changes or the job moved on by at least 0.5 %."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.stage = ""
        self.fraction = -1.0

    def __call__(self, stage: str, fraction: float) -> None:
        if self.progress is None:
            return
        fraction = float(min(max(fraction, 0.0), 1.0))
        if stage != self.stage or fraction - self.fraction >= 0.005 or fraction >= 1.0:
            self.stage, self.fraction = stage, fraction
            self.progress(stage, fraction)


@dataclass
class _Model:
    """The placed model (mm), its layers and what is planned for them. Per-layer lists
    are emptied (set to None) as the layers are written."""

    vertices: np.ndarray
    faces: np.ndarray
    layout: dict[str, Any]
    size: np.ndarray
    tops: np.ndarray
    heights: np.ndarray
    sections: list = field(default_factory=list)
    #: per layer, a number naming its section's exact shape (geometry.shape_ids)
    section_ids: list[int] = field(default_factory=list)
    widths: list[float] = field(default_factory=list)
    shells: list = field(default_factory=list)
    spacing: list[float] = field(default_factory=list)
    solids: list = field(default_factory=list)
    supports: list | None = None
    brim: list = field(default_factory=list)
    first_area: Any = None
    #: processes that planned the shells (this one included), the workers' CPU seconds and
    #: largest peak resident memory (MB)
    plan_workers: int = 1
    plan_worker_cpu_seconds: float = 0.0
    plan_worker_peak_mb: float = 0.0


def slice_mesh(vertices: Any, faces: Any, profile: Profile, *, progress: Progress = None
               ) -> SliceResult:
    """Slice a closed triangle mesh (mm) with ``profile``; raises SliceError on bad input."""
    report = _Reporter(progress)
    model, man = _placed(*_checked_mesh(vertices, faces), profile)
    head, tail = _head_and_tail(profile, model.tops)  # before the heavy work: fail fast
    thumbs = _thumbnails(model, man, profile)  # drawn from the solid, beside the planning
    try:
        _plan_layers(model, man, profile, report)
        del man
        _plan_support(model, profile, report)
        written = _write_layers(model, profile, report)
        thumbnails = thumbs.result()
    finally:
        thumbs.stop()
    if written.filament_mm <= 0:
        raise SliceError("nothing to print: the model produced no extrusions")
    summary = _summary(model, written, profile)
    gcode = _assemble(model, written, profile, head, tail, summary, thumbnails)
    report("done", 1.0)
    return SliceResult(gcode, summary)


def _checked_mesh(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray]:
    """The mesh as arrays, with coincident vertices merged; SliceError if it is not one."""
    from slicer import geometry as geo

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise SliceError("mesh has no triangles")
    if not np.isfinite(v).all():
        raise SliceError("mesh has non-finite vertex coordinates")
    if f.min() < 0 or f.max() >= len(v):
        raise SliceError("mesh faces index missing vertices")
    return geo.merge_vertices(v, f.astype(np.int64))


def _placed(v: np.ndarray, f: np.ndarray, profile: Profile) -> tuple[_Model, Any]:
    """Orient and arrange the model (``orient``, ``arrange``), put it on the bed, and find
    its layer tops; with its manifold3d solid."""
    from slicer import geometry as geo
    from slicer.arrange import layout_model

    v, layout = layout_model(v, f, profile)
    v, size = geo.place_on_bed(v, profile.build_volume)
    man = _to_manifold(v, f)
    tops = geo.layer_tops(float(size[2]), profile.first_layer_height, profile.layer_height)
    if len(tops) == 0:
        raise SliceError(f"model is only {size[2]:.3f} mm tall, thinner than half a first layer")
    return _Model(v, f, layout, size, tops, np.diff(tops, prepend=0.0)), man


def _head_and_tail(profile: Profile, tops: np.ndarray) -> tuple[str, str]:
    """The rendered start and end G-code; SliceError for a bad template."""
    from slicer.gcode import start_block
    from slicer.templates import render_template

    values = dict(profile.to_dict())
    values.update(
        layer_count=len(tops), max_z=float(tops[-1]),
        park_z=float(min(tops[-1] + 10.0, profile.build_volume[2])),
        park_y=float(profile.build_volume[1] * 0.9),
        travel_feedrate=profile.travel_speed * 60.0,
    )
    try:
        return start_block(profile, values), render_template(profile.end_gcode, values)
    except ValueError as exc:
        raise SliceError(str(exc)) from None


def _plan_layers(model: _Model, man: Any, profile: Profile, report: _Reporter) -> None:
    """Slice at mid-layer heights, then plan shells and skins (slicer.layer_plans)."""
    from slicer import geometry as geo
    from slicer.layer_plans import plan_shells_and_skins

    heights, res = model.heights, profile.resolution
    n = len(model.tops)
    for i, z in enumerate(model.tops - heights / 2):
        model.sections.append(man.slice(float(z)).simplify(res))
        report("slice", i / n * 0.2)
    model.section_ids = geo.shape_ids(model.sections)
    model.widths = [profile.first_layer_line_width if i == 0 else profile.line_width
                    for i in range(n)]
    model.spacing = [geo.bead_spacing(model.widths[i], float(heights[i])) for i in range(n)]
    plan_shells_and_skins(model, profile, report)
    report("skins", 0.45)


def _plan_support(model: _Model, profile: Profile, report: _Reporter) -> None:
    """Plan support (from the top layer down: it needs every layer) and the brim."""
    from slicer.brim import brim_paths, needs_brim
    from slicer.support import bead_area_of, support_regions

    heights = model.heights
    model.supports = support_regions(model.sections, heights, profile, model.widths,
                                     [bead_area_of(sh.thin) for sh in model.shells],
                                     model.section_ids)
    report("support", 0.5)
    model.first_area = model.sections[0]
    if needs_brim(profile, model.sections[0], float(model.tops[-1])):
        model.brim, covered = brim_paths(profile, model.sections[0], model.widths[0],
                                         float(heights[0]))
        model.first_area = model.first_area + covered
    if model.supports is not None:
        model.first_area = model.first_area + model.supports[0].area()


def _write_layers(model: _Model, profile: Profile, report: _Reporter) -> Written:
    """Plan, order and write the layers: the first share here, one layer at a time (only
    one layer's paths exist at once), and each further share in a forked worker (see
    slicer.layers). The G-code is the same whatever the number of workers."""
    from slicer.layers import (
        WRITE_WORKER_OVERHEAD,
        LayerRun,
        layer_shares,
        layer_work,
        worker_count,
        write_shares,
    )

    run = LayerRun(model, profile)
    work = layer_work(model, run.keys)
    shares = layer_shares(work, worker_count(profile, work), WRITE_WORKER_OVERHEAD)
    out = write_shares(run, shares, report)
    model.shells = model.solids = model.sections = []
    model.first_area = None
    return out


def _summary(model: _Model, written: Written, p: Profile) -> dict[str, Any]:
    """The job's figures; the workers' CPU and peak memory over the planning and writing
    phases (the thumbnails' child is left out: its share varies from run to run); the
    writing's split where workers wrote (:func:`_write_split`: is it balanced?)."""
    cm3 = written.filament_mm * p.filament_area / 1000.0
    return {
        "layers": len(model.tops),
        "filament_mm": round(written.filament_mm, 2),
        "filament_cm3": round(cm3, 3),
        "filament_g": round(cm3 * p.filament_density, 2),
        "estimated_seconds": round(float(sum(written.seconds)), 1),
        "height_mm": round(float(model.tops[-1]), 3),
        "size_mm": [round(float(s), 3) for s in model.size],
        "slicer": "embedded",
        "support": p.support if model.supports is not None else "none needed"
        if p.support != "off" else "off",
        "support_cm3": round(written.support_mm * p.filament_area / 1000.0, 3),
        "support_seconds": round(written.support_seconds, 1),
        "brim": bool(model.brim),
        "workers": max(written.workers, model.plan_workers),
        "worker_peak_mb": round(max(written.worker_peak_mb, model.plan_worker_peak_mb), 1),
        "worker_cpu_seconds": round(written.worker_cpu_seconds + model.plan_worker_cpu_seconds,
                                    3),
        **model.layout,
        **_write_split(written),
    }


def _write_split(written: Written) -> dict[str, Any]:
    """Where workers wrote layers, the split's figures (Written.write_cpu_seconds,
    write_wait_seconds); none for one process, whose summary stays the same run to run."""
    if written.workers <= 1:
        return {}
    return {"write_cpu_seconds": [round(s, 3) for s in written.write_cpu_seconds],
            "write_wait_seconds": round(written.write_wait_seconds, 3)}


def _thumbnails(model: _Model, man: Any, p: Profile):
    """The thumbnail blocks of the profile's sizes being drawn from the solid (a
    slicer.thumbnail.ThumbnailJob: in a child beside the planning where it may fork)."""
    from slicer.profile import thumbnail_sizes
    from slicer.thumbnail import ThumbnailJob

    return ThumbnailJob(model.vertices, model.faces, thumbnail_sizes(p.thumbnails), man,
                        p.workers)


def _assemble(model: _Model, written: Written, p: Profile, head: str, tail: str,
              summary: dict[str, Any], thumbnails: str = "") -> str:
    """The whole file: thumbnails, header comments, start G-code, the layers with M73
    progress, temperature and fan changes and Z moves, then the end G-code."""
    from slicer.gcode import fan_command, m73
    from slicer.profile import thumbnail_sizes

    parts: list[str] = []
    if thumbnails:  # first in the file, where printers and UIs look for them
        parts.append(thumbnails)
        summary["thumbnails"] = [f"{w}x{h}" for w, h in thumbnail_sizes(p.thumbnails)]
    total = float(sum(written.seconds))
    filament = written.filament_mm
    cm3 = filament * p.filament_area / 1000.0
    if p.comments:
        parts.append(
            "; generated by preflight embedded slicer\n"
            f"; layers: {len(model.tops)}, filament: {filament:.1f} mm ({cm3:.2f} cm3), "
            f"estimated time: {total:.0f} s\n"
            f"; nozzle {p.nozzle_diameter} mm, layer {p.layer_height} mm, "
            f"line {p.line_width} mm, infill {p.infill_percent:g}% {p.infill_pattern}\n"
        )
    parts.append(head)
    done = 0.0
    z_feed = 600.0
    for i, body in enumerate(written.bodies):
        z = model.tops[i]
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
        done += written.seconds[i]
    parts.append("M73 P100 R0\n")
    parts.append(tail)
    return "".join(parts)


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
