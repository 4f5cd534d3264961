"""Routing by capability: a job's pin (nozzle class) and size, and whether a printer
can take it.

The size is the axis-aligned bounding box of the *input* mesh, measured once at
intake (thickening grows it by at most ε; the slicer checks the placed part again).
A printer takes a job when its nozzle is the pinned one (if pinned) and its build
volume holds the box (an unknown build volume holds anything).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from daemon.config import Config

log = logging.getLogger("preflight.farm")

NOZZLE_TOLERANCE = 1e-6


def pin_of(spool: Path, path: Path) -> float | None:
    """The nozzle (mm) a dropped file is pinned to: its sidecar ``<name>.toml``
    (``nozzle = 0.6``), or the spool subfolder ``nozzle-0.6/`` it was dropped into.
    Raises ValueError (the reason) for a sidecar that cannot be used."""
    from daemon import pins

    sidecar = pins.find_sidecar(path)
    if sidecar is not None:
        return pins.read_sidecar(sidecar)
    if path.parent != spool:
        return pins.folder_nozzle(spool, path.parent)
    return None


def measure(path: Path, cfg: Config) -> list[float] | None:
    """The model's size (mm, x y z), or None when it cannot be read (the repair will
    fail it with the reason)."""
    from repair.io import load_mesh

    try:
        mesh = load_mesh(path, max_bytes=int(cfg.limits.max_file_mb * 1024 * 1024),
                         max_triangles=cfg.limits.max_triangles)
    except Exception as e:  # MeshReadError, MemoryError...: routed as "fits anywhere"
        log.info("farm: cannot measure %s (%s)", path.name, e)
        return None
    if len(mesh.vertices) == 0:
        return None
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    return [round(float(x), 4) for x in extent]


def printer_fits(job: dict[str, Any], info: dict[str, Any]) -> bool:
    """Whether the printer ``info`` describes may take the farm ``job`` (its Redis hash)."""
    pin = job.get("pin") or ""
    nozzle = info.get("nozzle_diameter")
    if pin and (not isinstance(nozzle, (int, float))
                or abs(float(pin) - float(nozzle)) > NOZZLE_TOLERANCE):
        return False
    extents = job.get("extents")
    if isinstance(extents, str):
        extents = json.loads(extents) if extents and extents != "null" else None
    volume = info.get("build_volume")
    if not extents or not volume:
        return True
    return all(float(e) <= float(v) + 1e-6 for e, v in zip(extents, volume, strict=False))
