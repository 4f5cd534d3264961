"""Winding numbers of closed triangle shells, and the nesting of the shells of a closed,
oriented, non-self-intersecting mesh that they decide (which shells are solids outside
all others, which are cavities inside exactly one solid).

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Vectorised numpy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["misnested_shells", "winding_numbers"]


def winding_numbers(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Generalised winding number of the closed triangle shell at each point.

    Exact solid-angle sums (Van Oosterom and Strackee), vectorised in numpy -- ten times
    faster than libigl's ``winding_number`` -- for modest point x face products; libigl's
    hierarchical ``fast_winding_number`` (near field exact, far field approximated far
    below the 0.5 that rounding tolerates) for huge ones.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(q) * len(f) > 5_000_000:
        import igl

        return np.asarray(igl.fast_winding_number(v, f, q), dtype=np.float64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    out = np.zeros(len(q))
    if len(f) == 0:
        return out
    chunk = max(1, 500_000 // len(f))
    for s in range(0, len(q), chunk):
        p = q[s : s + chunk, None, :]
        x, y, z = a[None] - p, b[None] - p, c[None] - p
        lx, ly, lz = (np.sqrt(np.einsum("pfk,pfk->pf", r, r)) for r in (x, y, z))
        det = np.einsum("pfk,pfk->pf", x, np.cross(y, z))
        den = (
            lx * ly * lz
            + np.einsum("pfk,pfk->pf", x, y) * lz
            + np.einsum("pfk,pfk->pf", x, z) * ly
            + np.einsum("pfk,pfk->pf", y, z) * lx
        )
        out[s : s + chunk] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return out


def misnested_shells(
    vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, n_shells: int
) -> int:
    """Shells that are not where an outward-oriented solid needs them.

    For a closed, oriented, non-self-intersecting mesh split into shells (edge-connected
    components), the winding number of the *other* shells is constant on each shell. An
    outward shell (positive volume) must sit outside every other solid (winding 0); an
    inverted shell (negative volume) is a cavity and must sit inside exactly one solid
    (winding 1). Anything else is an inverted body or a shell nested in a solid.
    """
    vertices = vertices - 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    vol = np.bincount(labels, np.einsum("ij,ij->i", a, np.cross(b, c)), minlength=n_shells)
    if n_shells == 1:
        return int(vol[0] <= 0)
    order = np.argsort(labels, kind="stable")
    starts = np.searchsorted(labels[order], np.arange(n_shells + 1))
    # One probe point per shell: the centroid of one of its faces.
    probe = (a + b + c)[order[starts[:-1]]] / 3.0
    # Bounding box per shell: a closed shell winds 0 around any point outside its box
    # (element-wise min / max of the corners: a reduction over rows of three costs more).
    lo = np.minimum.reduceat(np.minimum(np.minimum(a, b), c)[order], starts[:-1], axis=0)
    hi = np.maximum.reduceat(np.maximum(np.maximum(a, b), c)[order], starts[:-1], axis=0)
    if n_shells <= 2048:  # a box-against-probe table (scipy.spatial costs 0.1 s to import)
        inside = np.all((lo[:, None] <= probe[None]) & (probe[None] <= hi[:, None]), axis=2)
        candidates = [np.flatnonzero(row) for row in inside]
    else:
        from scipy.spatial import cKDTree

        tree = cKDTree(probe)
        radius = 0.5 * np.linalg.norm(hi - lo, axis=1) * (1 + 1e-9) + 1e-300
        candidates = tree.query_ball_point(0.5 * (lo + hi), radius)
    winding = np.zeros(n_shells)
    for d, cand in enumerate(candidates):
        cand = np.asarray(cand, dtype=np.int64)
        cand = cand[cand != d]
        if len(cand) == 0:
            continue
        cand = cand[np.all((lo[d] <= probe[cand]) & (probe[cand] <= hi[d]), axis=1)]
        if len(cand):
            shell_faces = faces[order[starts[d] : starts[d + 1]]]
            winding[cand] += winding_numbers(vertices, shell_faces, probe[cand])
    w = np.rint(winding)
    bad = np.where(vol > 0, w != 0, w != 1) | (vol == 0)
    return int(np.count_nonzero(bad))
