"""Flat neighbours of a feature: found before VTA, re-triangulated after it.

Moving a hole's rim outward onto the design circle moves vertices inside the plate's flat
top face. A CAD export triangulates that face with long slivers from the rim to the far
corners, and splitting a sliver at the moved point can fold it. So the faces of each flat
region (a *patch*: coplanar faces joined by edges) are re-triangulated as a whole once its
border has its new vertices: same plane, same outline, the refined rims as its holes.
"""

from __future__ import annotations

import numpy as np
from manifold3d import triangulate

from repair.surface.regions import face_geometry
from repair.topology import connected_labels, edge_ids, paired_half_edges

#: normals of one flat patch agree to this (about 0.03°)
COPLANAR_COS = 1.0 - 1e-7


def planar_patches(vertices: np.ndarray, faces: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Patch id of each face with ``free`` True (coplanar faces joined by an edge share one);
    -1 elsewhere."""
    normals, _, centroids = face_geometry(vertices, faces)
    eid, _ = edge_ids(faces)
    first, second, _ = paired_half_edges(eid)
    fa, fb = first // 3, second // 3
    off = np.abs(np.einsum("ij,ij->i", normals[fa], centroids[fb] - centroids[fa]))
    scale = max(float(np.ptp(vertices, axis=0).max()), 1.0)
    join = (free[fa] & free[fb] & (np.einsum("ij,ij->i", normals[fa], normals[fb]) > COPLANAR_COS)
            & (off < 1e-7 * scale))
    labels = connected_labels(len(faces), fa[join], fb[join])
    _, dense = np.unique(labels[free], return_inverse=True)
    out = np.full(len(faces), -1, dtype=np.int64)
    out[free] = dense
    return out


def border_loops(faces: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """The border loops of a set of faces, each a vertex sequence along the faces' winding."""
    he = np.stack([faces.reshape(-1), faces[:, [1, 2, 0]].reshape(-1)], axis=1)
    key = he[:, 0] * n_vertices + he[:, 1]
    border = he[~np.isin(key, he[:, 1] * n_vertices + he[:, 0])]
    succ = np.full(n_vertices, -1, dtype=np.int64)
    if len(np.unique(border[:, 0])) != len(border):
        raise ValueError("a region's border touches itself at a vertex")
    succ[border[:, 0]] = border[:, 1]
    seen = np.zeros(n_vertices, bool)
    loops = []
    for start in border[:, 0]:
        if seen[start]:
            continue
        loop = [start]
        seen[start] = True
        nxt = succ[start]
        while nxt != start:
            if nxt < 0 or seen[nxt]:
                raise ValueError("a region's border is broken")
            loop.append(nxt)
            seen[nxt] = True
            nxt = succ[nxt]
        loops.append(np.array(loop))
    return loops


def retriangulate(vertices: np.ndarray, faces: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """New faces for the flat region ``faces`` with unit ``normal``: its border loops
    triangulated in its plane (interior vertices are dropped; the plane is the same).
    Raises ValueError when the region's outline is not a valid polygon."""
    loops = border_loops(faces, len(vertices))
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    flat = [np.column_stack([vertices[lp] @ u, vertices[lp] @ w]) for lp in loops]
    ids = np.concatenate(loops)
    tris = np.asarray(triangulate(flat), dtype=np.int64).reshape(-1, 3)
    tris = _without_slivers(tris, np.vstack(flat))
    holes = len(loops) - 1
    if len(tris) != len(ids) + 2 * holes - 2 or (_areas(tris, np.vstack(flat)) <= 0).any():
        raise ValueError("a flat face next to the feature could not be re-triangulated")
    return ids[tris]


def _areas(tris: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = pts[tris]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


def _without_slivers(tris: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Flip away the zero-area triangles an ear-clipper leaves where vertices of different
    loops line up (a row of equal holes): a triangle (a, b, c) with c on ab and the triangle
    (b, a, d) across ab become (b, c, d) and (c, a, d). A loop per sliver (there are few)."""
    tris = tris.copy()
    for _ in range(len(tris)):
        bad = np.flatnonzero(_areas(tris, pts) <= 0)
        if len(bad) == 0:
            break
        t = bad[0]
        tri = tris[t]
        lengths = np.linalg.norm(pts[tri[[1, 2, 0]]] - pts[tri], axis=1)
        k = int(np.argmax(lengths))  # the longest edge runs corner k -> k+1
        a, b, c = tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]
        across = np.flatnonzero(((tris == b) | (tris == a)).sum(1) == 2)
        across = across[across != t]
        if len(across) != 1:
            break
        o = tris[across[0]]
        d = o[(o != a) & (o != b)][0]
        tris[t], tris[across[0]] = (b, c, d), (c, a, d)
    return tris
