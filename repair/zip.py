"""Local zip of hairline slits and blades: walls of one closed surface that come within
a hair (the probe distance of :func:`repair.junk.face_winding_sides`) of each other are
pressed together and the faces that then lie back to back are dropped.

Each corner of a failing face (:func:`repair.hairline.hairline_failures`) is merged with
the corners of other failing faces nearer than ``reach`` (a KD-tree and union-find, so a
wall's corners close onto the opposite wall's corners: the slit's two walls, or a
blade's two faces, become the same triangles with opposite orientation). Faces left
with a repeated corner go, and coincident faces cancel by orientation
(:func:`repair.clean.cancel_opposite_faces`), so a closed, oriented surface stays one.
Closed shells the zip leaves thinner than ``reach`` on average (tetrahedra pinched off
between merged corners) go too. Nothing moves by more than ``reach`` x the length of a
merged chain; the caller rounds,
checks and keeps the result only when it is printable and fewer faces fail.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.clean import cancel_opposite_faces, drop_unreferenced
from repair.topology import connected_labels

__all__ = ["zip_hairline"]


def zip_hairline(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray, reach: float,
    guarded: bool = True,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Merge the corners of the faces ``which`` that lie within ``reach`` (mm) of each
    other onto their group's mean, drop the faces this collapses and the coincident
    pairs it makes cancel. ``guarded``: a merge that would leave an edge not shared by
    exactly two faces in opposite directions is not made; else walls triangulated
    differently are left overlapping, for :func:`repair.mend.mend_intersections`.
    Returns ``(vertices, faces, largest move in mm)``, or None when no two such corners
    are that near (or every merge is undone)."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    corners = np.unique(f[np.asarray(which, dtype=np.int64)].reshape(-1))
    if len(corners) < 2 or reach <= 0:
        return None
    near = cKDTree(v[corners]).query_pairs(reach, output_type="ndarray")
    if len(near) == 0:
        return None
    pairs = corners[near]
    # A merge that would leave an edge not shared by exactly two faces of opposite
    # directions is undone (its pairs dropped), round by round: the rest zips.
    for _ in range(8 if guarded else 1):
        merged = _merged(v, f, pairs)
        bad = _bad_topology_vertices(merged[1], len(v)) & guarded
        if not bad.any():
            break
        pairs = pairs[~(bad[pairs[:, 0]] | bad[pairs[:, 1]])]
        if len(pairs) == 0:
            return None
    out_v, nf = merged
    if bad.any():
        return None
    shift = float(np.linalg.norm(out_v - v, axis=1).max())
    out_v, nf = drop_unreferenced(out_v, nf[~_hair_thin_shells(out_v, nf, reach)])
    return out_v, nf, shift


def _hair_thin_shells(v: np.ndarray, f: np.ndarray, reach: float) -> np.ndarray:
    """Per face: on a closed shell thinner than ``reach`` on average (2 |volume| / area;
    the tetrahedra a zip pinches off between three merged corners)."""
    from repair.meshes import shell_volumes
    from repair.topology import edge_components

    lab = edge_components(f)
    n = int(lab.max()) + 1
    if n == 1:
        return np.zeros(len(f), dtype=bool)
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    shell_area = np.bincount(lab, weights=area, minlength=n)
    thin = 2.0 * np.abs(shell_volumes(v, f, lab, n)) < reach * shell_area
    return thin[lab]


def _merged(v: np.ndarray, f: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices joined by ``pairs`` merged onto their group's mean (each group's lowest
    index stands for it); faces left with a repeated corner dropped and coincident faces
    cancelled by orientation. Vertices keep their indices (unused ones stay)."""
    lab = connected_labels(len(v), pairs[:, 0], pairs[:, 1])
    size = np.bincount(lab)
    mean = np.zeros((len(size), 3))
    np.add.at(mean, lab, v)
    mean /= size[:, None]
    rep = np.full(len(size), len(v), dtype=np.int64)
    np.minimum.at(rep, lab, np.arange(len(v)))
    moved = size[lab] > 1
    out_v = v.copy()
    out_v[moved] = mean[lab[moved]]
    nf = rep[lab][f]
    keep = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 2] != nf[:, 0])
    nf = nf[keep]
    return out_v, nf[cancel_opposite_faces(nf)]


def _bad_topology_vertices(f: np.ndarray, n: int) -> np.ndarray:
    """Per vertex: on an edge not shared by exactly two faces in opposite directions."""
    from repair.rows import unique_rows
    from repair.topology import edge_ids, half_edges

    he = half_edges(f)
    eid, count = edge_ids(f)
    _, inv, hcount = unique_rows(he, return_inverse=True, return_counts=True)
    bad_he = (count[eid] != 2) | (hcount[inv.reshape(-1)] > 1)
    mark = np.zeros(n, dtype=bool)
    mark[he[bad_he].reshape(-1)] = True
    return mark


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
