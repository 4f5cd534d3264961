"""Fair patches for the holes of a scan (Liepa, "Filling holes in meshes", SGP 2003, as
Centin & Signoroni's RameshCleaner fills them, Sec. 3.4).

A minimal-area lid (:mod:`repair.closure`) spans a hole with long slivers between rim
vertices: flat-ish where the scanned surface is curved. Its patch is

1. *refined* so its edges match the rim's: each vertex has a scale ``sigma`` (rim
   vertices: the mean length of their two rim edges; a new vertex: its triangle's mean),
   and a triangle whose centroid is further than ``sigma / sqrt(2)`` from each of its
   corners, by both the centroid's and that corner's scale, is split at its centroid;
   then interior edges are swapped while the two angles facing them sum to more than pi
   (the Delaunay rule), an independent set of edges per round (each the best of both its
   triangles); rounds until nothing splits;
2. *faired*: its new (interior) vertices minimise the uniform bi-Laplacian energy
   ``sum |L x|^2`` over the patch's vertices and its rim, with the rim and the shell's
   faces round it (one ring) fixed -- one sparse least-squares solve, so the patch
   continues the surface's curvature across the rim.

Rim vertices keep their indices; the patch never gets an edge between two rim vertices
that the minimal-area lid did not have, nor new vertices on the rim, so the lid stays
watertight with it. All lids are refined and faired together (one patch mesh of
disjoint lids): every step is vectorised over all their triangles; the only Python
loops run once per round.

Units are mm. Arrays: vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.closure import Lid, triangle_reach

__all__ = ["FairPatches", "fair_lids", "fair_patches"]

#: Liepa's density factor: split while a centroid is sqrt(2) x sigma from the corners.
DENSITY = np.sqrt(2.0)
#: Rounds of splitting, and of edge swaps after each split round (both end well before).
MAX_SPLIT_ROUNDS = 40
MAX_SWAP_ROUNDS = 30


@dataclass(frozen=True)
class FairPatches:
    """Refined and faired lids. ``points`` (p, 3) mm: the patch vertices, the first
    ``n_rim`` of them the rim vertices given (same order), the others new; ``triangles``
    (t, 3): indices into ``points``; ``owner`` (t,): the lid each triangle belongs to."""

    points: np.ndarray
    n_rim: int
    triangles: np.ndarray
    owner: np.ndarray


def fair_patches(
    rim_points: np.ndarray,
    rim_sigma: np.ndarray,
    triangles: np.ndarray,
    owner: np.ndarray,
    ring_points: np.ndarray,
    ring_faces: np.ndarray,
    n_rim: int | None = None,
) -> FairPatches:
    """Refine and fair lids given on their rims' vertices.

    ``rim_points`` (r, 3) mm: the rim vertices of all lids (a vertex on two rims once);
    ``rim_sigma`` (r,) mm: their scale (mean length of their rim edges); ``triangles``
    (t, 3): the lids' triangles on those (indices into ``rim_points``), lid ``owner[i]``;
    ``ring_points`` (q, 3): the shell's other vertices round the rims, and ``ring_faces``
    (s, 3): the shell's faces with a corner on a rim, indices into the rim points
    followed by the ring points (fixed; they make the rim's Laplacian whole).
    ``n_rim``: where the rim points end, if ``rim_points`` is followed by new points
    (free, as refined ones; ``triangles`` may use them).
    """
    pts = np.asarray(rim_points, dtype=np.float64)
    sigma = np.asarray(rim_sigma, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    own = np.asarray(owner, dtype=np.int64)
    n_rim = len(pts) if n_rim is None else n_rim
    tris = _relax(pts, tris, n_rim)
    for _ in range(MAX_SPLIT_ROUNDS):
        c = pts[tris].mean(axis=1)
        sc = sigma[tris].mean(axis=1)
        d = DENSITY * np.linalg.norm(c[:, None, :] - pts[tris], axis=2)
        split = ((d > sc[:, None]) & (d > sigma[tris])).all(axis=1)
        if not split.any():
            break
        at = np.flatnonzero(split)
        new = len(pts) + np.arange(len(at))
        pts = np.vstack([pts, c[at]])
        sigma = np.r_[sigma, sc[at]]
        a, b, cc = tris[at].T
        tris = np.vstack([
            tris[~split], np.stack([a, b, new], axis=1), np.stack([b, cc, new], axis=1),
            np.stack([cc, a, new], axis=1),
        ])  # fmt: skip
        own = np.r_[own[~split], own[at], own[at], own[at]]
        tris = _relax(pts, tris, n_rim)
    if len(pts) > n_rim:
        pts = _faired(pts, n_rim, tris, np.asarray(ring_points, dtype=np.float64),
                      np.asarray(ring_faces, dtype=np.int64))  # fmt: skip
    return FairPatches(pts, n_rim, tris, own)


def _angle(o: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The angle (radians) at ``o`` between ``p`` and ``q`` (rows)."""
    u, w = p - o, q - o
    return np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), np.einsum("ij,ij->i", u, w))


def _relax(pts: np.ndarray, tris: np.ndarray, n_rim: int) -> np.ndarray:
    """Swap interior edges of the patch while the angles facing them sum to more than pi,
    an independent set per round; never to an edge between two rim vertices, an edge the
    patch has already, or to triangles that fold against the two they replace."""
    tris = tris.copy()
    n = len(pts)
    for _ in range(MAX_SWAP_ROUNDS):
        he = np.stack([tris, np.roll(tris, -1, axis=1)], axis=2).reshape(-1, 2)
        key = np.minimum(he[:, 0], he[:, 1]) * n + np.maximum(he[:, 0], he[:, 1])
        order = np.argsort(key, kind="stable")
        ks = key[order]
        pair = np.flatnonzero(ks[1:] == ks[:-1])
        if len(pair) == 0:
            return tris
        h1, h2 = order[pair], order[pair + 1]
        t1, i1 = np.divmod(h1, 3)
        t2, i2 = np.divmod(h2, 3)
        a, b = he[h1, 0], he[h1, 1]
        c = tris[t1, (i1 + 2) % 3]
        d = tris[t2, (i2 + 2) % 3]
        excess = _angle(pts[c], pts[a], pts[b]) + _angle(pts[d], pts[a], pts[b]) - np.pi
        new_key = np.minimum(c, d) * n + np.maximum(c, d)
        old_n = np.cross(pts[b] - pts[a], pts[c] - pts[a]) + np.cross(
            pts[a] - pts[b], pts[d] - pts[b])
        n1 = np.cross(pts[a] - pts[c], pts[d] - pts[c])
        n2 = np.cross(pts[b] - pts[d], pts[c] - pts[d])
        ok = (excess > 1e-9) & (c != d) & ((c >= n_rim) | (d >= n_rim))
        ok &= ~np.isin(new_key, ks) & (np.einsum("ij,ij->i", n1, old_n) > 0)
        ok &= np.einsum("ij,ij->i", n2, old_n) > 0
        cand = np.flatnonzero(ok)
        if len(cand) == 0:
            return tris
        # Independent set: an edge swaps when it is the best candidate of both triangles.
        rank = np.empty(len(cand), dtype=np.int64)
        rank[np.argsort(excess[cand], kind="stable")] = np.arange(len(cand))
        best = np.full(len(tris), -1, dtype=np.int64)
        np.maximum.at(best, t1[cand], rank)
        np.maximum.at(best, t2[cand], rank)
        go = cand[(best[t1[cand]] == rank) & (best[t2[cand]] == rank)]
        go = go[np.unique(new_key[go], return_index=True)[1]]  # one swap per new edge
        tris[t1[go]] = np.stack([c[go], a[go], d[go]], axis=1)
        tris[t2[go]] = np.stack([d[go], b[go], c[go]], axis=1)
    return tris


def _faired(
    pts: np.ndarray, n_rim: int, tris: np.ndarray, ring_points: np.ndarray,
    ring_faces: np.ndarray,
) -> np.ndarray:
    """``pts`` with its new vertices (index ``n_rim`` and up) moved to minimise the sum
    of squared uniform Laplacians over the patch's vertices (rim and new), the rim and
    the ring (``ring_faces`` on the rim and ``ring_points``, indexed after ``pts``' rim
    vertices: ring point j is index ``n_rim + j`` there) fixed."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import factorized

    n_new = len(pts) - n_rim
    # Combined numbering: rim, new, ring.
    ring_f = np.where(ring_faces >= n_rim, ring_faces + n_new, ring_faces)
    allp = np.vstack([pts, ring_points])
    f = np.vstack([tris, ring_f])
    e = np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)
    e = np.unique(np.sort(e, axis=1), axis=0)
    total = len(allp)
    adj = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                        shape=(total, total)).tocsr()  # fmt: skip
    deg = np.asarray(adj.sum(axis=1)).ravel()
    lap = sp.identity(total, format="csr") - sp.diags(1.0 / np.maximum(deg, 1.0)) @ adj
    rows = lap[: n_rim + n_new]
    free = np.arange(n_rim, n_rim + n_new)
    fixed = np.r_[np.arange(n_rim), np.arange(n_rim + n_new, total)]
    a = rows[:, free].tocsc()
    rhs = -(rows[:, fixed] @ allp[fixed])
    atb = a.T @ rhs
    try:
        solve = factorized((a.T @ a).tocsc())
        moved = np.stack([solve(atb[:, i]) for i in range(3)], axis=1)
    except RuntimeError:  # a singular system (degenerate rims): the refined points stay
        return pts
    if not np.isfinite(moved).all():
        return pts
    out = pts.copy()
    out[n_rim:] = moved
    return out


def fair_lids(
    vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray], lids: list[Lid]
) -> list[Lid]:
    """The lids of ``loops`` (lid order; vertex indices into ``vertices``) refined and
    faired together (:func:`fair_patches`), on the shell ``faces`` (fixed: its faces
    round the rims give the rims' Laplacians). A lid keeps the rim vertex indices; its
    new vertices are numbered from ``len(vertices)`` up, as each :class:`Lid` numbers
    its own; a lid that gains no new vertex is returned as it was."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = len(v)
    rim = np.unique(np.concatenate(loops))
    at = np.concatenate(loops)
    nxt = np.concatenate([np.roll(lp, -1) for lp in loops])
    length = np.linalg.norm(v[nxt] - v[at], axis=1)
    ends = np.searchsorted(rim, np.r_[at, nxt])
    sigma = np.bincount(ends, np.r_[length, length], len(rim)) / np.bincount(ends, None, len(rim))
    # The lids' own new vertices (fan centres) start free, after the rim.
    starts = [lid.new_vertices for lid in lids]
    n_start = np.cumsum([0, *(len(s) for s in starts)])
    tris, owner = [], []
    for j, lid in enumerate(lids):
        t = lid.triangles
        local = np.where(t < n, np.searchsorted(rim, np.minimum(t, n - 1)),
                         len(rim) + n_start[j] + t - (t[t >= n].min() if (t >= n).any() else 0))
        tris.append(local)  # fmt: skip
        owner.append(np.full(len(t), j))
    start_pts = np.vstack([v[rim], *starts])
    start_sigma = np.r_[sigma, np.full(int(n_start[-1]), sigma.mean())]
    on_rim = np.zeros(n, dtype=bool)
    on_rim[rim] = True
    ring_f = f[on_rim[f].any(axis=1)]
    ring_v = np.setdiff1d(ring_f, rim)
    ring_local = np.where(on_rim[ring_f], np.searchsorted(rim, ring_f),
                          len(rim) + np.searchsorted(ring_v, ring_f))  # fmt: skip
    patches = fair_patches(start_pts, start_sigma, np.vstack(tris), np.concatenate(owner),
                           v[ring_v], ring_local, n_rim=len(rim))  # fmt: skip
    order = np.argsort(patches.owner, kind="stable")
    cut = np.searchsorted(patches.owner[order], np.arange(len(lids) + 1))
    return [_lid_of(patches, rim, patches.triangles[order[cut[j] : cut[j + 1]]], lid, n)
            for j, lid in enumerate(lids)]  # fmt: skip


def _lid_of(patches: FairPatches, rim: np.ndarray, local: np.ndarray, lid: Lid, n: int) -> Lid:
    """The lid of the ``patches`` triangles ``local`` on the input's indices (rim) and its
    own new vertices from ``n`` up; ``lid`` (the same hole's) where it gained no vertex."""
    used = np.unique(local)
    new = used[used >= patches.n_rim]
    if len(new) <= len(lid.new_vertices):
        return lid
    index = np.empty(len(patches.points), dtype=np.int64)
    index[: patches.n_rim] = rim
    index[new] = n + np.arange(len(new))
    pts = patches.points
    a, b, c = pts[local[:, 0]], pts[local[:, 1]], pts[local[:, 2]]
    area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    # A point of a triangle is within triangle_reach of a corner, a corner within
    # `reach` of a rim vertex.
    loop_pts = pts[np.unique(local[local < patches.n_rim])]
    reach = np.zeros(len(pts))
    reach[new] = np.sqrt(((pts[new][:, None, :] - loop_pts[None, :, :]) ** 2).sum(axis=2)).min(1)
    bound = reach[local].min(axis=1) + triangle_reach(a, b, c)
    return Lid(index[local], pts[new], lid.perimeter, area, lid.planarity, False,
               float(bound.max()), faired=True)  # fmt: skip

