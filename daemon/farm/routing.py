"""Routing by capability: a job's pin (nozzle class) and size, and whether a printer
can take it.

The size is the axis-aligned bounding box of the *input* mesh, measured once before
it is published (thickening grows it by at most ε; the slicer checks the placed part again).
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


def measure(input_path: Path, work: Path, cfg: Config) -> list[float] | None:
    """The model's size (mm, x y z), measured in a child process like the daemon's own
    routing does (never a stranger's mesh parsed in the daemon); None when it cannot be
    read (routed as fitting anywhere: the repair fails it with the reason)."""
    from daemon.worker import WorkerCancelled, WorkerFailed, run_task

    try:
        out = run_task("measure", {
            "in": str(input_path), "job_name": input_path.name,
            "max_bytes": int(cfg.limits.max_file_mb * 1024 * 1024),
            "max_triangles": cfg.limits.max_triangles,
        }, work_dir=work, timeout=cfg.limits.repair_timeout,
            memory_mb=cfg.limits.repair_memory_mb)
    except (WorkerFailed, WorkerCancelled) as e:
        log.info("farm: cannot measure %s (%s)", input_path.name, e)
        return None
    size = (out or {}).get("size")
    return [round(float(x), 4) for x in size] if size else None


def printer_fits(job: dict[str, Any], info: dict[str, Any]) -> bool:
    """Whether the printer ``info`` describes may take the farm ``job`` (its Redis hash)."""
    from daemon.printers import same_nozzle

    pin = job.get("pin") or ""
    nozzle = info.get("nozzle_diameter")
    if pin and not (isinstance(nozzle, (int, float)) and same_nozzle(float(pin), nozzle)):
        return False
    extents = job.get("extents")
    if isinstance(extents, str):
        extents = json.loads(extents) if extents and extents != "null" else None
    volume = info.get("build_volume")
    if not extents or not volume:
        return True
    return all(float(e) <= float(v) + 1e-6 for e, v in zip(extents, volume, strict=False))
