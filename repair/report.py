"""The repair's report: what was found, what was done, how far the surface moved, and
how long each stage took -- a JSON-serialisable dict plus a one-line summary.

Units are mm (areas mm², volumes mm³, times seconds).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from repair.check import Printability
from repair.holes import HolesClosed
from repair.meshes import shell_volumes
from repair.topology import edge_components

__all__ = [
    "Progress",
    "RepairOutcome",
    "RepairTally",
    "StageClock",
    "input_report",
    "repair_report",
    "summary",
]

Progress = Callable[[str, float], None] | None


class StageClock:
    """Seconds spent per named stage; tells ``progress`` (if given) each stage's end."""

    def __init__(self, progress: Progress) -> None:
        self.stages: dict[str, float] = {}
        self.progress = progress
        self._t = time.perf_counter()

    def lap(self, name: str, fraction: float) -> None:
        """End stage ``name`` (adding to its time if it ran before); ``fraction`` of the
        whole repair is done."""
        now = time.perf_counter()
        self.stages[name] = round(self.stages.get(name, 0.0) + now - self._t, 4)
        self._t = now
        if self.progress is not None:
            self.progress(name, fraction)


@dataclass
class RepairTally:
    """What the hull, thicken and finish stages did, counted as they go."""

    intersecting_pairs: int = -1
    internal_faces: int = 0
    sheet_area: float = 0.0
    sheet_triangles: int = 0
    wires: int = 0
    singular_edges: int = 0
    separated: int = 0
    passes: int = 0
    collapsed: int = 0
    junk_shells: int = 0
    junk_volume: float = 0.0
    #: Why the finish stopped taking the whole arrangement again (empty when it did not).
    finish_stopped: str = ""


@dataclass
class RepairOutcome:
    """The written mesh and its verdict, the path that made it (``unchanged``, ``union``,
    ``exact`` or ``fallback``), its deviation D from the input and what the stages did."""

    vertices: np.ndarray
    faces: np.ndarray
    verdict: Printability
    path: str
    deviation: float
    tally: RepairTally
    holes: HolesClosed
    degenerate_removed: int = 0
    duplicates_removed: int = 0
    dropped_components: int = 0
    #: Further report sections by name (``stitched``, ``scan_cleanup``), JSON-ready.
    sections: dict[str, Any] = field(default_factory=dict)


def input_report(verdict: Printability, n_vertices: int) -> dict[str, Any]:
    """The ``before`` section: the check of the (float32-rounded) input."""
    return {
        "triangles": int(verdict.triangles),
        "vertices": int(n_vertices),
        "components": verdict.components,
        "boundary_edges": verdict.boundary_edges,
        "nonmanifold_edges": verdict.nonmanifold_edges,
        "misoriented_edges": verdict.misoriented_edges,
        "degenerate_faces": verdict.degenerate_faces,
        "duplicate_faces": verdict.duplicate_faces,
        "intersecting_pairs": verdict.intersecting_pairs,
        "volume": verdict.volume,
        "printable": verdict.ok,
    }


def _after_report(out: RepairOutcome, n_parts: int) -> dict[str, Any]:
    tally = out.tally
    return {
        "triangles": int(len(out.faces)),
        "vertices": int(len(out.vertices)),
        "components": n_parts,
        "degenerate_removed": int(out.degenerate_removed),
        "duplicates_removed": int(out.duplicates_removed),
        "intersecting_pairs_resolved": int(max(tally.intersecting_pairs, 0)),
        "internal_triangles_dropped": int(tally.internal_faces),
        "components_dropped_internal": int(out.dropped_components),
        "sheet_triangles_thickened": int(tally.sheet_triangles),
        "sheet_area_thickened": round(float(tally.sheet_area), 6),
        "wires_inflated": int(tally.wires),
        "singular_edges_thickened": int(tally.singular_edges),
        "singular_edges_separated": int(tally.separated),
        "arrangement_passes": int(tally.passes),
        "internal_junk_shells_removed": int(tally.junk_shells),
        "internal_junk_volume": float(tally.junk_volume),
    }


def _parts(out: RepairOutcome) -> tuple[int, np.ndarray, np.ndarray]:
    """Number of manifold-connected parts of the written mesh, their volumes and their
    triangle counts."""
    verdict, v, f = out.verdict, out.vertices, out.faces
    if verdict.components == 1:  # the check already counted: skip relabelling
        return 1, np.array([verdict.volume]), np.array([len(f)])
    known = verdict.shells is not None and len(verdict.shells) == len(f)
    labels = verdict.shells if known else edge_components(f)
    n_parts = int(labels.max()) + 1 if len(labels) else 0
    volumes = shell_volumes(v, f, labels, n_parts) if n_parts else np.zeros(0)
    return n_parts, volumes, np.bincount(labels, minlength=n_parts)


def repair_report(
    before: dict[str, Any], out: RepairOutcome, eps: float, clock: StageClock
) -> dict[str, Any]:
    """The whole report of a repair whose input check gave ``before``; ends the
    ``report`` stage of ``clock`` and includes the stage times."""
    n_parts, part_vol, part_tris = _parts(out)
    order = np.argsort(-part_vol)
    report: dict[str, Any] = {"epsilon": eps, "before": before}
    report["after"] = _after_report(out, n_parts)
    report["holes_closed"] = out.holes.to_dict()
    report["path"] = out.path
    report.update(out.sections)
    report["deviation"] = out.deviation
    report["deviation_over_epsilon"] = out.deviation / eps
    report["volume"] = out.verdict.volume
    report["parts"] = [
        {"triangles": int(part_tris[i]), "volume": float(part_vol[i])} for i in order[:50]
    ]
    report["printable"] = out.verdict.to_dict()
    clock.lap("report", 1.0)
    report["stages"] = dict(clock.stages)
    report["seconds"] = round(sum(clock.stages.values()), 4)
    report["summary"] = summary(report)
    return report


def summary(r: dict[str, Any]) -> str:
    """One line saying what the repair found and did."""
    a, b = r["after"], r["before"]
    from repair.surface.stage import surface_summary

    curved = surface_summary(r.get("surface"))
    if r["path"] == "unchanged":
        if curved:
            return f"already printable: {b['triangles']} -> {a['triangles']} triangles, {curved}"
        return f"already printable: {b['triangles']} triangles kept unchanged"
    fixes = []
    for key, label in (
        ("degenerate_removed", "degenerate triangles removed"),
        ("duplicates_removed", "duplicate triangles removed"),
        ("intersecting_pairs_resolved", "intersecting pairs resolved"),
        ("components_dropped_internal", "internal parts dropped"),
        ("internal_triangles_dropped", "internal triangles dropped"),
        ("internal_junk_shells_removed", "thin internal shells removed"),
        ("wires_inflated", "wires inflated"),
        ("singular_edges_thickened", "singular edges thickened"),
    ):
        if a.get(key):
            fixes.append(f"{a[key]} {label}")
    sc = r.get("scan_cleanup") or {}
    if sc:
        asked = "asked" if sc["why"].startswith("asked") else "looks like a scan"
        fixes.append(
            f"cleaned as a scan ({asked}: {sc['relaxed_vertices']} spike vertices relaxed, "
            f"{sc['spike_faces_removed'] + sc['boundary_faces_removed']} spike/ragged "
            f"triangles and {sc['components_removed']} specks removed)"
        )
    st = r.get("stitched") or {}
    if st.get("snapped") or st.get("inserted"):
        fixes.append(f"cracks stitched within {st['gamma']:g} mm")
    h = r.get("holes_closed") or {}
    if h.get("count"):
        fixes.append(f"{h['count']} small hole(s) closed ({h['area']:.4g} mm² of lid)")
    if h.get("flaps_removed"):
        fixes.append(f"{h['flaps_removed']} flap triangle(s) beside holes removed")
    if a["sheet_triangles_thickened"]:
        fixes.append(
            f"{a['sheet_area_thickened']:.4g} mm² of sheet thickened to {r['epsilon']:g} mm"
        )
    if b["misoriented_edges"] or b["volume"] < 0:
        fixes.append("orientation fixed")
    if curved:
        fixes.append(curved)
    what = ", ".join(fixes) if fixes else "re-oriented and closed"
    counts = (f"{b['triangles']} -> {a['triangles']} triangles in {a['components']} part(s), "
              f"{r['volume']:.6g} mm³")  # fmt: skip
    d = f"D = {r['deviation']:.3g} mm"
    fb = r.get("fallback")
    if fb:
        return f"fallback: {fb['reason']}; approximation: {fb['approximation']}, {d}; " \
               f"{counts}: {what}"
    return f"{counts}, {d}: {what}"
