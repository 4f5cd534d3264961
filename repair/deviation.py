"""Attene's deviation D: how far the repaired surface strays from the input.

``D = max over points p of the output surface of dist(p, input)``, where the input is
its non-degenerate triangles plus the segments its degenerate triangles stood for.
Estimated on the output's vertices, face centroids, edge midpoints and a few random
points per face (deterministic seed); output faces that are input faces (perhaps with
their corners rounded to float32) are bounded without samples. Units are mm. Vectorised
(libigl AABB tree).
"""

from __future__ import annotations

import numpy as np

from repair.rows import unique_rows

__all__ = ["max_deviation"]


def _surface_samples(v: np.ndarray, f: np.ndarray, max_points: int) -> np.ndarray:
    p = v[f]
    pts = [v, p.mean(axis=1), 0.5 * (p + p[:, [1, 2, 0]]).reshape(-1, 3)]
    extra = max(0, min(4, (max_points - len(v) - 4 * len(f)) // max(len(f), 1)))
    if extra:
        rng = np.random.default_rng(0)
        w = rng.dirichlet(np.ones(3), size=(len(f), extra))  # (m, extra, 3)
        pts.append(np.einsum("mek,mkd->med", w, p).reshape(-1, 3))
    return np.vstack(pts)


def _point_segment_d2(pts: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Squared distance from each point to the nearest segment, chunked."""
    best = np.full(len(pts), np.inf)
    a = seg[:, 0]
    ab = seg[:, 1] - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    chunk = max(1, 2_000_000 // max(len(seg), 1))
    for s in range(0, len(pts), chunk):
        q = pts[s : s + chunk, None, :] - a[None]
        t = np.clip(np.einsum("pkd,kd->pk", q, ab) / ab2, 0.0, 1.0)
        d = q - t[..., None] * ab[None]
        best[s : s + chunk] = np.einsum("pkd,pkd->pk", d, d).min(axis=1)
    return best


def _match_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each row of ``a``: the index of a bit-identical row of ``b``, or -1."""
    key = np.dtype((np.void, 24))
    bk = np.ascontiguousarray(b + 0.0).view(key).ravel()
    ak = np.ascontiguousarray(a + 0.0).view(key).ravel()
    order = np.argsort(bk)
    pos = np.clip(np.searchsorted(bk[order], ak), 0, len(bk) - 1)
    return np.where(bk[order][pos] == ak, order[pos], -1)


def _new_faces(
    ov: np.ndarray, of: np.ndarray, iv: np.ndarray, inf: np.ndarray
) -> tuple[np.ndarray, float]:
    """The output faces that are not input faces, and a bound (mm) on the distance of the
    others from the input.

    An output face on exactly the corners of an input face is that triangle (distance 0
    everywhere), so it needs no samples. Nor does one whose corners are those corners
    rounded to float32: every point of it lies within its largest corner displacement of
    the input triangle (a convex combination of the corners, each moved that far at most),
    so that displacement bounds its distance."""
    if len(inf) == 0 or len(iv) == 0:
        return of, 0.0
    ids = _match_rows(ov, iv)
    moved = np.zeros(len(ov))
    iv32 = iv.astype(np.float32).astype(np.float64)
    miss = np.flatnonzero(ids < 0)
    if len(miss) and not np.array_equal(iv32, iv):
        rid = _match_rows(ov[miss], iv32)
        hit = rid >= 0
        ids[miss[hit]] = rid[hit]
        moved[miss[hit]] = np.linalg.norm(ov[miss[hit]] - iv[rid[hit]], axis=1)
    fid = ids[of]
    known = (fid >= 0).all(axis=1)
    n = len(iv)
    if n >= 2**21:
        return of, 0.0
    a = np.sort(fid[known], axis=1)
    b = np.sort(inf, axis=1)
    kin = (b[:, 0] * n + b[:, 1]) * n + b[:, 2]
    kout = (a[:, 0] * n + a[:, 1]) * n + a[:, 2]
    same = np.zeros(len(of), dtype=bool)
    same[np.flatnonzero(known)] = np.isin(kout, kin)
    bound = float(moved[of[same]].max()) if np.any(same) else 0.0
    return of[~same], bound


def _point_mesh_d2(pts: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Squared distance from each point to the triangles (libigl AABB tree). When the
    points are few and local, the tree is built only over the triangles near them.

    Each triangle is binned by its centroid into a grid of cells ``h`` at least twice its
    largest box extent. A triangle within ``h`` of a point then has its centroid within
    two cells of the point's cell, so a point whose distance to the triangles of its
    5x5x5 cells is at most ``h`` has found its true nearest one; points farther out are
    measured against the whole mesh.
    """
    import igl

    def d2_to(faces: np.ndarray, q: np.ndarray) -> np.ndarray:
        return igl.point_mesh_squared_distance(
            np.ascontiguousarray(q), np.ascontiguousarray(v), np.ascontiguousarray(faces)
        )[0]

    if len(f) < 50_000 or len(pts) == 0 or len(pts) > len(f):
        return d2_to(f, pts)
    p = v[f]
    span = float(np.ptp(v, axis=0).max())
    h = max(2.0 * float(np.ptp(p, axis=1).max()), span / 256.0, 1e-12)
    if span / h < 8:
        return d2_to(f, pts)
    origin = v.min(axis=0)
    n = int(span / h) + 8

    def key(c: np.ndarray) -> np.ndarray:
        c = np.clip(c + 3, 0, n - 1)
        return (c[..., 0] * n + c[..., 1]) * n + c[..., 2]

    fc = np.floor((p.mean(axis=1) - origin) / h).astype(np.int64)
    pc = unique_rows(np.floor((pts - origin) / h).astype(np.int64))
    off = np.stack(np.meshgrid(*([np.arange(-2, 3)] * 3), indexing="ij"), -1).reshape(-1, 3)
    marked = np.unique(key(pc[:, None, :] + off[None]))
    near = np.isin(key(fc), marked)
    if near.mean() > 0.5:
        return d2_to(f, pts)
    d2 = d2_to(f[near], pts) if np.any(near) else np.full(len(pts), np.inf)
    far = d2 > h * h
    if np.any(far):
        d2[far] = d2_to(f, pts[far])
    return d2


def max_deviation(
    out_vertices: np.ndarray,
    out_faces: np.ndarray,
    in_vertices: np.ndarray,
    in_faces: np.ndarray,
    in_segments: np.ndarray | None = None,
    *,
    max_points: int = 400_000,
) -> float:
    """Largest distance (mm) from sampled output surface points to the input.

    Returns 0.0 for an empty output and ``inf`` when the input has nothing to measure to.
    """
    ov = np.asarray(out_vertices, dtype=np.float64)
    of = np.asarray(out_faces, dtype=np.int64)
    if len(of) == 0:
        return 0.0
    of, bound = _new_faces(ov, of, np.asarray(in_vertices, dtype=np.float64),
                           np.asarray(in_faces, dtype=np.int64))  # fmt: skip
    if len(of) == 0:
        return bound
    # Only the vertices of new faces: the others are (rounded) input vertices.
    used, local = np.unique(of, return_inverse=True)
    pts = _surface_samples(ov[used], local.reshape(-1, 3), max_points)
    d2 = np.full(len(pts), np.inf)
    if len(in_faces):
        d2 = _point_mesh_d2(pts, np.asarray(in_vertices, dtype=np.float64),
                            np.asarray(in_faces, dtype=np.int64))  # fmt: skip
    if in_segments is not None and len(in_segments):
        d2 = np.minimum(d2, _point_segment_d2(pts, np.asarray(in_segments, dtype=np.float64)))
    return max(float(np.sqrt(d2.max())), bound)
