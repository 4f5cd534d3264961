"""Local zip of hairline slits and blades: walls of one closed surface that come within
a hair (the probe distance of :func:`repair.junk.face_winding_sides`) of each other are
pressed together and the faces that then lie back to back are dropped.

Each corner of a failing face (:func:`repair.hairline.hairline_failures`) is merged with
the corners of other failing faces nearer than ``reach`` (a KD-tree and union-find, so a
wall's corners close onto the opposite wall's corners: the slit's two walls, or a
blade's two faces, become the same triangles with opposite orientation). Faces left
with a repeated corner go, and coincident faces cancel by orientation
(:func:`repair.clean.cancel_opposite_faces`), so a closed, oriented surface stays one.
Nothing moves by more than ``reach`` x the length of a merged chain; the caller rounds,
checks and keeps the result only when it is printable and fewer faces fail.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.clean import cancel_opposite_faces, drop_unreferenced
from repair.topology import connected_labels

__all__ = ["zip_hairline"]


def zip_hairline(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Merge the corners of the faces ``which`` that lie within ``reach`` (mm) of each
    other onto their group's mean, drop the faces this collapses and the coincident
    pairs it makes cancel. Returns ``(vertices, faces, largest move in mm)``, or None
    when no two such corners are that near."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    corners = np.unique(f[np.asarray(which, dtype=np.int64)].reshape(-1))
    if len(corners) < 2 or reach <= 0:
        return None
    near = cKDTree(v[corners]).query_pairs(reach, output_type="ndarray")
    if len(near) == 0:
        return None
    lab = connected_labels(len(v), corners[near[:, 0]], corners[near[:, 1]])
    size = np.bincount(lab)
    mean = np.zeros((len(size), 3))
    np.add.at(mean, lab, v)
    mean /= size[:, None]
    # Each group's lowest vertex index stands for it, at the group's mean.
    rep = np.full(len(size), len(v), dtype=np.int64)
    np.minimum.at(rep, lab, np.arange(len(v)))
    moved = size[lab] > 1
    out_v = v.copy()
    out_v[moved] = mean[lab[moved]]
    shift = float(np.linalg.norm(out_v[moved] - v[moved], axis=1).max())
    nf = rep[lab][f]
    keep = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 2] != nf[:, 0])
    nf = nf[keep]
    nf = nf[cancel_opposite_faces(nf)]
    out_v, nf = drop_unreferenced(out_v, nf)
    return out_v, nf, shift


def closest_on_triangles(q: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Closest point of triangle ``tri[i]`` ((k, 3, 3)) to point ``q[i]`` ((k, 3))."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    on_plane = q - (np.einsum("ij,ij->i", q - a, n) / np.where(nn > 0, nn, 1.0))[:, None] * n
    # Inside when the plane point is on the inner side of all three edges.
    inside = nn > 0
    for s, e in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(e - s, on_plane - s), n) >= 0
    best = np.where(inside[:, None], on_plane, np.inf)
    best_d = np.where(inside, np.linalg.norm(q - on_plane, axis=1), np.inf)
    for s, e in ((a, b), (b, c), (c, a)):
        seg = e - s
        ll = np.einsum("ij,ij->i", seg, seg)
        t = np.clip(np.einsum("ij,ij->i", q - s, seg) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
        p = s + t[:, None] * seg
        d = np.linalg.norm(q - p, axis=1)
        closer = d < best_d
        best[closer], best_d[closer] = p[closer], d[closer]
    return best


def snap_onto_opposite(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Move each corner of the faces ``which`` onto the nearest point of the face that
    lies across the hairline from it (the nearest other face to a point ``reach`` / 2
    off the face, either side), when that point is within ``reach``; one wall of each
    slit moves (the face of lower index of a facing pair). Returns ``(vertices, moved
    mask)``, or None when nothing is that near. The walls then touch or cross by a
    rounding error: :func:`repair.mend.mend_intersections` resolves them exactly."""
    import igl

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    which = np.asarray(which, dtype=np.int64)
    p = v[f[which]]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)
    c = p.mean(axis=1)
    q = np.vstack([c + 0.5 * reach * n, c - 0.5 * reach * n])
    _, near, _ = igl.point_mesh_squared_distance(
        q, np.ascontiguousarray(v), np.ascontiguousarray(f))
    near = np.asarray(near, dtype=np.int64)
    own = np.tile(which, 2)
    lower = (near != own) & (own < near) | ~np.isin(near, which)
    own, opp = own[lower], near[lower]
    # Every corner of a moving face against its opposite face (not a corner of it).
    corner = f[own].reshape(-1)
    target = np.repeat(opp, 3)
    free = ~(f[target] == corner[:, None]).any(axis=1)
    corner, target = corner[free], target[free]
    if len(corner) == 0:
        return None
    to = closest_on_triangles(v[corner], v[f[target]])
    dist = np.linalg.norm(to - v[corner], axis=1)
    ok = dist <= reach
    corner, to, dist = corner[ok], to[ok], dist[ok]
    if len(corner) == 0:
        return None
    order = np.lexsort((dist, corner))
    first = order[np.r_[True, corner[order][1:] != corner[order][:-1]]]
    out = v.copy()
    out[corner[first]] = to[first]
    moved = np.zeros(len(v), dtype=bool)
    moved[corner[first]] = True
    return out, moved
