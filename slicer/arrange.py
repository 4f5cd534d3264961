"""Arrangement: separate bodies of one file placed apart on the bed.

A *body* is a group of connected shells whose bounding boxes overlap one another: a hollow
part's inner shell stays with its outer one, interlocked parts (chain links) stay together,
and bodies that overlap were already merged into one shell by repair. Each body is dropped
onto the bed and the bodies are packed in rows (tallest footprint first) with at least
``gap`` mm between their footprints' bounding boxes. Vectorised over vertices; the packing
itself loops over bodies (a handful).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer.errors import SliceError


@dataclass(frozen=True)
class Arrangement:
    """Where each body went: its vertex labels and the XY shift applied to it (mm)."""

    labels: np.ndarray  # (nv,) body index of each vertex
    shifts: np.ndarray  # (k, 3)

    @property
    def bodies(self) -> int:
        return len(self.shifts)

    def report(self) -> dict:
        return {"bodies": self.bodies}


def body_labels(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Body index (0..k-1) of every vertex: connected shells joined when their boxes overlap."""
    from repair.topology import connected_labels, vertex_components

    shell = vertex_components(len(vertices), faces)
    k = int(shell.max()) + 1 if len(shell) else 0
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    np.minimum.at(lo, shell, vertices)
    np.maximum.at(hi, shell, vertices)
    overlap = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    a, b = np.nonzero(np.triu(overlap, 1))
    return connected_labels(k, a, b)[shell]


def _rows(sizes: np.ndarray, width: float, gap: float) -> tuple[np.ndarray, float, float]:
    """Shelf packing of rectangles (k, 2) into rows at most ``width`` wide: lower-left
    corners (k, 2), total width and depth (gaps between rectangles, none outside)."""
    order = np.argsort(-sizes[:, 1], kind="stable")
    corner = np.zeros((len(sizes), 2))
    x = y = row_depth = used = 0.0
    for i in order:
        w, d = sizes[i]
        if x > 0 and x + w > width + 1e-9:
            y += row_depth + gap
            x = row_depth = 0.0
        corner[i] = (x, y)
        x += w + gap
        used = max(used, x - gap)
        row_depth = max(row_depth, d)
    return corner, used, y + row_depth


def arrange_bodies(vertices: np.ndarray, faces: np.ndarray,
                   build_volume: tuple[float, float, float], gap: float
                   ) -> tuple[np.ndarray, Arrangement]:
    """Place the bodies apart on the bed; raises SliceError when they do not fit."""
    v = np.asarray(vertices, dtype=np.float64)
    labels = body_labels(v, faces)
    k = int(labels.max()) + 1 if len(labels) else 0
    if k <= 1:
        return v, Arrangement(labels, np.zeros((k, 3)))
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    np.minimum.at(lo, labels, v)
    np.maximum.at(hi, labels, v)
    sizes = (hi - lo)[:, :2]
    bx, by, bz = (float(s) for s in build_volume)
    corner, used_x, used_y = _rows(sizes, bx, gap)
    if used_x > bx + 1e-9 or used_y > by + 1e-9 or float((hi - lo)[:, 2].max()) > bz + 1e-9:
        raise SliceError(
            f"the {k} separate bodies need {used_x:.1f} × {used_y:.1f} mm of bed with "
            f"{gap:g} mm between them; the bed is {bx:.0f} × {by:.0f} mm"
            + (" and the tallest is too tall" if float((hi - lo)[:, 2].max()) > bz else ""))
    shifts = np.zeros((k, 3))
    shifts[:, :2] = corner - lo[:, :2]
    shifts[:, 2] = -lo[:, 2]  # every body stands on the bed
    return v + shifts[labels], Arrangement(labels, shifts)


def layout_model(vertices: np.ndarray, faces: np.ndarray, profile) -> tuple[np.ndarray, dict]:
    """Orientation (``profile.orient``), then arrangement (``profile.arrange``) of the mesh;
    returns the moved vertices and a report for the slice summary."""
    v = np.asarray(vertices, dtype=np.float64)
    report: dict = {"orientation": {"mode": "keep", "rotated": False}}
    if profile.orient != "keep":
        from slicer.orient import choose_orientation

        chosen = choose_orientation(v, faces, profile.orient,
                                    bed_tolerance=profile.first_layer_height / 2)
        if chosen.rotated:
            v = v @ chosen.rotation.T
        report["orientation"] = chosen.report()
    if profile.arrange:
        v, arrangement = arrange_bodies(v, faces, profile.build_volume, profile.arrange_gap)
        report["arrangement"] = arrangement.report()
    return v, report
