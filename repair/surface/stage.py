"""The repair pipeline's ``surface`` stage: FIA + VTA on the repaired (printable) mesh."""

from __future__ import annotations

import dataclasses

import numpy as np

from repair.check import check_printable, round_to_float32
from repair.report import RepairOutcome
from repair.surface.features import MODES, find_features, refine_surfaces, surface_tolerance
from repair.topology import edge_ids


def surface_stage(
    out: RepairOutcome, epsilon: float, mode: str, found: list | None = None
) -> RepairOutcome:
    """``out`` with its analytic features refined (``mode``: a key of ``MODES``) and a
    ``surface`` report section; ``out`` itself (plus the section) when nothing changed or the
    refined mesh does not pass the exact check on its float32 coordinates. ``found``:
    :func:`features_of` ``out``'s very arrays, when already computed."""
    if mode not in MODES:
        raise ValueError(f"surface must be one of {', '.join(MODES)}, got {mode!r}")
    if mode == "off":
        return out
    try:
        result = refine_surfaces(out.vertices, out.faces, epsilon=epsilon, mode=mode,
                                 found=found)
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 -- an optional refinement never fails the repair
        section = {"mode": mode, "features": [], "triangles_added": 0,
                   "undone": f"surface refinement failed: {type(exc).__name__}: {exc}"}
        return dataclasses.replace(out, sections={**out.sections, "surface": section})
    section = result.to_dict()
    if not result.changed:
        return dataclasses.replace(out, sections={**out.sections, "surface": section})
    vertices = round_to_float32(result.vertices)
    verdict = check_printable(vertices, result.faces)
    if not verdict.ok:  # refine_surfaces checks this too; never write an unprintable mesh
        section["undone"] = "; ".join(verdict.failures())
        return dataclasses.replace(out, sections={**out.sections, "surface": section})
    return dataclasses.replace(out, vertices=vertices, faces=result.faces, verdict=verdict,
                               sections={**out.sections, "surface": section})


def surface_summary(section: dict | None) -> str:
    """A clause for the report's one-line summary, or "" when no feature was refined."""
    if not section or section.get("undone"):
        return ""
    refined = [f for f in section["features"] if f["status"] == "refined"]
    if not refined:
        return ""
    worst = max(f["chordal_error_before"]["max"] for f in refined)
    after = max(f["chordal_error_after"]["max"] for f in refined)
    return (f"{len(refined)} curved feature(s) refined: chordal error {worst:.3g} -> "
            f"{after:.3g} mm (+{section['triangles_added']} triangles)")


def feature_lines(section: dict | None) -> list[str]:
    """One indented text line per recognised feature (the job's text report)."""
    if not section:
        return []
    out = []
    for f in section.get("features", []):
        size = (f"r {f['radius']:.4g} mm" if "radius" in f else
                f"R {f['major_radius']:.4g} / r {f['minor_radius']:.4g} mm" if "major_radius" in f
                else f"half-angle {f['half_angle_deg']:.4g}°")
        before, after = f["chordal_error_before"], f["chordal_error_after"]
        out.append(f"  {f['kind']} {size}: chordal error max {before['max']:.3g} -> "
                   f"{after['max']:.3g} mm, avg {before['avg']:.3g} -> {after['avg']:.3g} mm, "
                   f"{f['faces_before']} -> {f['faces_after']} triangles ({f['status']})")
    if section.get("undone"):
        out.append(f"  surface refinement undone: {section['undone']}")
    return out


def features_of(vertices: np.ndarray, faces: np.ndarray, epsilon: float, mode: str, *,
                closed_only: bool = False) -> list | None:
    """What :func:`surface_stage` finds to refine on these arrays (``mode`` not "off"):
    computed ahead, e.g. while the input check runs, and handed to it as ``found``.
    ``closed_only``: None, found first, when an edge is not used by exactly two faces --
    such an input is not printable, so it never reaches the stage unchanged."""
    eid = None
    if closed_only:
        eid, counts = edge_ids(faces)
        if len(counts) == 0 or np.any(counts != 2):
            return None
    return find_features(vertices, faces, tolerance=surface_tolerance(epsilon),
                         kinds=MODES[mode], eid=eid)
