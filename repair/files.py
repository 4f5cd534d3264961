"""File in, file out: load a mesh file, repair it (:func:`repair.pipeline.repair_mesh`),
write a binary STL and, if asked, the report as JSON. Used by the CLI and the daemon's
worker; units are mm.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from repair.pipeline import RepairError, repair_mesh
from repair.report import Progress

__all__ = ["RepairError", "repair_file"]


def repair_file(
    in_path: str | Path,
    out_path: str | Path,
    *,
    epsilon: float = 0.4,
    report_path: str | Path | None = None,
    max_bytes: int | None = None,
    max_triangles: int | None = None,
    progress: Progress = None,
    clean: str = "auto",
    surface: str = "off",
    time_budget: float | None = None,
) -> dict[str, Any]:
    """Load a mesh file (STL/OBJ/PLY/3MF/STEP), repair it, write a binary STL at ``out_path``
    and, if asked, the report as JSON at ``report_path``. Returns the report.

    The options are :func:`repair.pipeline.repair_mesh`'s, with its defaults: in
    particular ``surface="off"``, while ``preflight repair`` and the daemon refine
    cylinders and cones unless told otherwise (``[repair] surface``'s default, "holes").
    A library caller gets the exact repair, whose surface stays within the input's facets
    (solids) or ``0.6 * epsilon`` of them (sheets, wires), unless it asks for refinement,
    which moves curved facets onto fitted design surfaces and adds triangles.

    Raises :class:`repair.io.MeshReadError` for unreadable input and :class:`RepairError`
    when nothing printable can be made of it.
    """
    from repair.io import load_mesh, write_stl
    from repair.io.step import chordal_deflection

    t0 = time.perf_counter()
    mesh = load_mesh(in_path, max_bytes=max_bytes, max_triangles=max_triangles,
                     deflection=chordal_deflection(epsilon))  # a STEP's tessellation
    t_load = time.perf_counter() - t0
    if progress is not None:
        progress("load", 0.05)
    result = repair_mesh(mesh.vertices, mesh.faces, epsilon, progress=progress, clean=clean,
                         surface=surface, time_budget=time_budget)  # fmt: skip
    t1 = time.perf_counter()
    write_stl(out_path, result.vertices, result.faces)
    report = dict(result.report)
    report["stages"] = {"load": round(t_load, 4), **report["stages"],
                        "write": round(time.perf_counter() - t1, 4)}  # fmt: skip
    report["input"] = {"path": str(in_path), "format": mesh.source_format,
                       "unit_scale": mesh.unit_scale}  # fmt: skip
    report["output"] = str(out_path)
    if report_path is not None:
        Path(report_path).write_text(json.dumps(report, indent=2) + "\n")
    return report
