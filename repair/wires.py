"""Wires (Attene Sec. 4.2.1, last paragraph): degenerate triangles stand for segments.

A segment that lies on the outer hull, or inside the solid it encloses, is hidden and
dropped; a visible one becomes a closed prism of diameter ``eps`` around it (a cylinder
with ``SIDES`` sides whose corners are at distance ``eps/2`` from the axis). The same
prisms thicken the singular edges of a result, which makes it edge-manifold.

Units are mm. Segments are float64 (k, 2, 3). Vectorised numpy.
"""

from __future__ import annotations

import numpy as np

from repair.rows import unique_rows

__all__ = ["SIDES", "cylinders", "moved_segments", "visible_segments"]

SIDES = 8


def cylinders(segments: np.ndarray, epsilon: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed, outward-oriented prisms of diameter ``epsilon`` around each segment.

    Returns ``(vertices, faces)`` of all prisms concatenated (they may overlap).
    Zero-length segments are skipped.
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    axis = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(axis, axis=1)
    seg, axis, length = seg[length > 0], axis[length > 0], length[length > 0]
    k = len(seg)
    if k == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    t = axis / length[:, None]
    # Any unit vector orthogonal to t, then the third of the frame.
    helper = np.where(np.abs(t[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(t, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(t, u)
    r = 0.5 * epsilon
    ang = 2 * np.pi * np.arange(SIDES) / SIDES
    ring = r * (np.cos(ang)[None, :, None] * u[:, None] + np.sin(ang)[None, :, None] * w[:, None])
    bottom = seg[:, 0, None] + ring  # (k, S, 3)
    top = seg[:, 1, None] + ring
    # Per prism: S bottom, S top, 2 cap centres.
    verts = np.concatenate([bottom, top, seg[:, 0, None], seg[:, 1, None]], axis=1)
    s = SIDES
    i = np.arange(s)
    j = (i + 1) % s
    side = np.concatenate([np.stack([i, j, j + s], 1), np.stack([i, j + s, i + s], 1)])
    cap_b = np.stack([np.full(s, 2 * s), j, i], 1)
    cap_t = np.stack([np.full(s, 2 * s + 1), i + s, j + s], 1)
    local = np.concatenate([side, cap_b, cap_t])  # outward for a right-handed (u, w, t)
    faces = (local[None] + (np.arange(k) * (2 * s + 2))[:, None, None]).reshape(-1, 3)
    return verts.reshape(-1, 3), faces.astype(np.int64)


def visible_segments(
    segments: np.ndarray,
    hull_vertices: np.ndarray,
    hull_faces: np.ndarray,
    solid_faces: np.ndarray,
    *,
    samples: int = 7,
) -> np.ndarray:
    """The segments not hidden by the outer hull: a segment is hidden when each of its
    ``samples`` points lies on the outer hull (``hull_faces``, solid and sheet) or inside
    the closed ``solid_faces``. Returns the visible ones, (k, 2, 3)."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    if len(seg) == 0 or len(hull_faces) == 0:
        return seg
    import igl

    t = np.linspace(0.0, 1.0, samples)
    pts = seg[:, 0, None] + t[None, :, None] * (seg[:, 1] - seg[:, 0])[:, None]
    pts = pts.reshape(-1, 3)
    hv = np.ascontiguousarray(hull_vertices, dtype=np.float64)
    scale = float(np.ptp(hv, axis=0).max()) if len(hv) else 1.0
    tol = 1e-9 * max(scale, 1e-9)
    d2 = igl.point_mesh_squared_distance(pts, hv, np.ascontiguousarray(hull_faces))[0]
    hidden = d2 <= tol * tol
    if len(solid_faces):
        wn = igl.winding_number(hv, np.ascontiguousarray(solid_faces, dtype=np.int64), pts)
        hidden |= wn > 0.5
    hidden = hidden.reshape(len(seg), samples).all(axis=1)
    return seg[~hidden]


def moved_segments(segments: np.ndarray, vertices: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """``segments`` (k, 2, 3) mm with each end that is exactly the point
    ``vertices[moved[i, 0]]`` put on ``vertices[moved[i, 1]]``: a wire on points that a
    stitch merged into others (:attr:`repair.stitch.Stitched.moved`) moves with them,
    and stays on the surface it lay on (off it by the crack's noise, it would be
    visible and inflated into a prism: D 0.14 mm on a cube's edge). ``vertices``
    (n, 3) mm: no two the same point (welded)."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    if len(seg) == 0 or len(moved) == 0:
        return seg
    src = np.asarray(vertices, dtype=np.float64)[moved[:, 0]]
    ends = seg.reshape(-1, 3)
    inv = unique_rows(np.vstack([src, ends]), return_inverse=True)[1].reshape(-1)
    slot = np.full(int(inv.max()) + 1, -1)
    slot[inv[: len(src)]] = np.arange(len(src))
    hit = slot[inv[len(src) :]]
    if not np.any(hit >= 0):
        return seg
    out = ends.copy()
    out[hit >= 0] = vertices[moved[hit[hit >= 0], 1]]
    return out.reshape(-1, 2, 3)
