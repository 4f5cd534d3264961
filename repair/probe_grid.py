"""Probes a hair off a mesh's faces that another face comes near: the search behind
:func:`repair.hairline.hairline_suspects` on faces in no shared plane.

Each probe lies a distance ``d`` (a few float32 ulps of the part's size) off the centroid
of its own face, along its normal; the question is whether a face other than its own
comes nearer than ``0.999 d``. libigl's nearest-face query answers it by finding the
nearest face of every probe, though almost every probe is far from all but its own face
(bunny's 32.5k probes against 16.3k faces: 60-80 ms CPU). A uniform grid answers it from
the few faces listed in each probe's cell, box, plane, then exact distance tests deciding
(the same answer; 45-55 ms there, 6 ms instead of 22-30 for box's curved faces).

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Vectorised numpy.
"""

from __future__ import annotations

import numpy as np

from repair.deviation import point_triangle_d2
from repair.rows import ranges, sort_with_positions

__all__ = ["GRID_BIG_TESTS", "GRID_PAIRS_PER_FACE", "faces_near_points", "in_disjoint_slabs",
           "probes_near_faces", "slivers_probed_clear", "unit_normals"]

#: The grid gives way to libigl's tree when its cells would pair each face asked about
#: with more faces than this on average (meshes of crowded small faces beside large ones:
#: chair; Ghostkeeper_extra_surface's cylinder of 35 mm slivers crowded cubic cells, 190,
#: but not cells as long as its faces).
GRID_PAIRS_PER_FACE = 24
#: ... or when the faces too large for the cells (boxes over 27 cells), each tested box
#: against every face asked about, would take more box tests than this.
GRID_BIG_TESTS = 1 << 19
#: :func:`slivers_probed_clear` decides nothing beyond this many (probe, face) box tests.
SLIVER_TESTS = 1 << 22


def unit_normals(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals of the triangles ``p`` (m, 3, 3) (zero for a degenerate one) and their
    cross products' lengths (twice the areas, mm²)."""
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1)
    return np.divide(n, length[:, None], out=np.zeros_like(n), where=length[:, None] > 0), length


def probes_near_faces(
    v: np.ndarray, f: np.ndarray, rest: np.ndarray, q: np.ndarray, c: np.ndarray,
    n: np.ndarray, idx: np.ndarray, d: float,
) -> np.ndarray | None:
    """Mask over the probes ``q`` -- ``c + d n`` then ``c - d n`` for the faces ``idx``
    (centroids ``c``, unit normals ``n``, mm) -- of those that a face of ``rest`` other
    than their own comes nearer than ``0.999 d`` to: exactly what libigl's
    ``point_mesh_squared_distance(q, v, f[rest])`` says when the nearest face is not the
    probe's own and lies nearer than that. None when the grid would pair the faces with
    more than :data:`GRID_PAIRS_PER_FACE` faces each (the caller asks libigl then)."""
    m = len(idx)
    fr = f[rest]
    # Box and plane tests are necessary conditions, with a margin for rounding; a probe
    # lies d from its centroid, so the boxes are grown by 2 d round the centroids.
    grow = d + 2.0**-48 * float(np.abs(v).max())
    lo = np.empty((3, len(rest)))
    hi = np.empty((3, len(rest)))
    for k in range(3):
        x = np.ascontiguousarray(v[:, k])
        a, b, e = x[fr[:, 0]], x[fr[:, 1]], x[fr[:, 2]]
        lo[k] = np.minimum(np.minimum(a, b), e) - (grow + d)
        hi[k] = np.maximum(np.maximum(a, b), e) + (grow + d)
    pairs = _centroids_in_boxes(lo, hi, c)
    if pairs is None:
        return None
    own, fac = pairs
    keep = rest[fac] != idx[own]
    own, fac = own[keep], fac[keep]
    tri = v[fr[fac]]
    nrm = unit_normals(tri)[0]
    # Off the plane of a face by t + u (the + probe) or t - u (the - probe).
    t = np.einsum("ij,ij->i", nrm, c[own] - tri[:, 0])
    u = d * np.einsum("ij,ij->i", nrm, n[own])
    near = np.zeros(2 * m, dtype=bool)
    # A face is no nearer to a probe than its plane: one farther than 0.999 d from that,
    # rounding aside, is not (a coplanar neighbour's plane lies d off both probes).
    reach = 0.999 * d + 2.0**-48 * float(np.abs(v).max())
    for sign, probe in ((1.0, own), (-1.0, own + m)):
        hit = np.abs(t + sign * u) <= reach  # a degenerate face (no normal) always
        pts, pt = probe[hit], tri[hit]
        d2 = point_triangle_d2(q[pts], pt[:, 0], pt[:, 1], pt[:, 2])
        near[pts[d2 < (0.999 * d) ** 2]] = True
    return near


def _centroids_in_boxes(
    lo: np.ndarray, hi: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """Pairs ``(point, box)`` with point ``c[point]`` inside the closed box ``lo[:, box]``
    .. ``hi[:, box]`` (3, k), found in a grid of cells (:func:`_grid_pairs`): cubes the
    size of the median box; where those are crowded, cells as long along each axis as
    the median box is there (a fan of long thin faces, as a cylinder's sides, fills
    every cube as large as they are long, but not cells long one way and thin the
    others). None when both would take too many tests."""
    origin = np.minimum(lo.min(axis=1), c.min(axis=0))
    span = np.maximum(hi.max(axis=1), c.max(axis=0)) - origin
    ext = hi - lo
    mid = len(ext[0]) // 2
    least = float(span.max()) / 1024.0
    cube = max(float(np.partition(ext.max(axis=0), mid)[mid]), least)
    pairs = _grid_pairs(lo, hi, c, origin, span, np.full(3, cube))
    if pairs is not None:
        return pairs
    h = np.maximum(np.partition(ext, mid, axis=1)[:, mid], least)
    if np.all(h > 0.5 * cube):  # nearly the same cells
        return None
    return _grid_pairs(lo, hi, c, origin, span, h)


def _grid_pairs(
    lo: np.ndarray, hi: np.ndarray, c: np.ndarray, origin: np.ndarray, span: np.ndarray,
    h: np.ndarray,
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_centroids_in_boxes` in a grid of cells ``h`` (3,) long from ``origin``
    (the grid spans ``span``, mm): each box listed under the (at most 27) cells it meets,
    each point tested against the boxes of its cell; boxes meeting more cells are few
    and tested against every point. None when that would take more than
    :data:`GRID_PAIRS_PER_FACE` tests per point or :data:`GRID_BIG_TESTS` for the large
    boxes."""
    m = len(c)
    lo_c = np.floor((lo.T - origin) / h).astype(np.int64)
    dims = np.floor((hi.T - origin) / h).astype(np.int64) - lo_c + 1
    cover = dims.prod(axis=1)
    big = np.flatnonzero(cover > 27)
    if len(big) * m > GRID_BIG_TESTS or len(big) == len(cover):
        return None
    cover[big] = 0
    side = (span / h).astype(np.int64) + 2
    listed = np.repeat(np.arange(len(cover)), cover)
    local = np.arange(len(listed)) - np.repeat(np.cumsum(cover) - cover, cover)
    dl = dims[listed]
    cell = lo_c[listed] + np.stack(
        [local // (dl[:, 1] * dl[:, 2]), (local // dl[:, 2]) % dl[:, 1], local % dl[:, 2]],
        axis=1,
    )
    order, keys = sort_with_positions((cell[:, 0] * side[1] + cell[:, 1]) * side[2] + cell[:, 2])
    listed = listed[order]
    # Each listed cell once: where its boxes start in the listing, and how many.
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    cells, runs = keys[starts], np.diff(np.r_[starts, len(keys)])
    cc = np.floor((c - origin) / h).astype(np.int64)
    ck = (cc[:, 0] * side[1] + cc[:, 1]) * side[2] + cc[:, 2]
    at = np.minimum(np.searchsorted(cells, ck), len(cells) - 1)
    count = np.where(cells[at] == ck, runs[at], 0)
    if int(count.sum()) > GRID_PAIRS_PER_FACE * m:
        return None
    box = listed[ranges(starts[at], count)]
    own = np.repeat(np.arange(m), count)
    keep = np.ones(len(box), dtype=bool)
    for k in range(3):  # axis by axis, on ever fewer pairs
        own, box = own[keep], box[keep]
        x = c[own, k]
        keep = (x >= lo[k][box]) & (x <= hi[k][box])
    own, box = own[keep], box[keep]
    if len(big):
        inside = np.ones((len(big), m), dtype=bool)
        for k in range(3):
            inside &= (c[:, k] >= lo[k][big, None]) & (c[:, k] <= hi[k][big, None])
        b_big, b_own = np.nonzero(inside)
        own, box = np.r_[own, b_own], np.r_[box, big[b_big]]
    return own, box


def in_disjoint_slabs(
    x: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """Pairs ``(i, j)`` with ``lo[j] < x[i] < hi[j]`` when the open slabs are disjoint (a
    box's parallel walls, farther apart than their reach): then only the slab of the
    largest ``lo`` below ``x[i]`` can hold it, one binary search per value among the few
    slabs instead of a test against each. None when two slabs overlap."""
    by_lo = np.argsort(lo, kind="stable")
    sl, sh = lo[by_lo], hi[by_lo]
    if np.any(sh[:-1] > sl[1:]):
        return None
    j = np.searchsorted(sl, x, side="left") - 1
    i = np.flatnonzero((j >= 0) & (x < sh[np.maximum(j, 0)]))
    return i, by_lo[j[i]]


def faces_near_points(v: np.ndarray, f: np.ndarray, q: np.ndarray, r: float) -> np.ndarray:
    """Faces whose bounding box, grown by ``r`` (mm), holds some point of ``q`` along
    each axis (a point within ``r`` of a face is: not always the same point per axis,
    a superset). Per axis one sort of the points and two searches, on the faces the
    axes before left (a few points near a large mesh leave few after the first)."""
    cand = np.arange(len(f))
    corners = [f[:, 0], f[:, 1], f[:, 2]]
    for k in range(3):
        x = np.ascontiguousarray(v[:, k])
        a, b, c = (x[i] for i in corners)  # 1-D gathers: faster than rows
        lo = np.minimum(np.minimum(a, b), c) - r
        hi = np.maximum(np.maximum(a, b), c) + r
        s = np.sort(q[:, k])
        keep = np.searchsorted(s, hi, side="right") > np.searchsorted(s, lo, side="left")
        cand = cand[keep]
        corners = [i[keep] for i in corners]
    return cand


def slivers_probed_clear(v: np.ndarray, f: np.ndarray, which: np.ndarray, d: float) -> np.ndarray:
    """Mask over the faces ``which``: those the two-sided winding test
    (:func:`repair.junk.face_winding_sides`, probe distance ``d``) cannot fail. A sliver
    (height under 10 d) is probed only a tenth of its height off its centroid; no other
    face within 1.01 times that of either probe (exact distances), the segment from the
    face to the probe crosses nothing, so the winding number there is the one just off
    the face: 0 outside, 1 inside, on a printable mesh -- where the probe is far enough
    off the face (height at least d / 64) for the test's sums to say so. Faces too thin
    to be probed at all are never counted as failing. Other faces: False (not decided
    here)."""
    p = v[f[which]]
    n, length = unit_normals(p)
    longest = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2).max(axis=1)
    height = np.divide(length, longest, out=np.zeros_like(longest), where=longest > 0)
    unprobed = ~((length > 0) & (height >= d * 2.0**-20))
    # Probed nearer than 1/640 of d, a face's own solid angle is rounding noise (its
    # sides may read anything, as on the test itself): those are left to it.
    sliver = np.flatnonzero(~unprobed & (0.1 * height < d) & (height >= d / 64))
    clear = unprobed.copy()
    if len(sliver) == 0:
        return clear
    di = 0.1 * height[sliver]
    c = p[sliver].mean(axis=1)
    q = np.vstack([c + di[:, None] * n[sliver], c - di[:, None] * n[sliver]])
    r = np.r_[di, di] * 1.01 + 2.0**-48 * float(np.abs(v).max())
    owner = np.r_[which[sliver], which[sliver]]
    near_faces = faces_near_points(v, f, q, float(r.max()))
    if len(near_faces) * len(q) > SLIVER_TESTS:
        return clear  # probes spread over a large mesh: not worth deciding here
    tri = v[f[near_faces]]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    hit = np.zeros(len(q), dtype=bool)
    for s in range(0, len(q), 64):  # probes x faces near any, box-tested first
        k = np.arange(s, min(s + 64, len(q)))
        pk, fk = np.nonzero(((q[k, None] >= lo[None] - r[k, None, None])
                             & (q[k, None] <= hi[None] + r[k, None, None])).all(axis=2))
        pk = k[pk]
        other = near_faces[fk] != owner[pk]
        pk, fk = pk[other], fk[other]
        t = tri[fk]
        with np.errstate(invalid="ignore"):  # a needle's distance may come out NaN: near
            d2 = point_triangle_d2(q[pk], t[:, 0], t[:, 1], t[:, 2])
        hit[pk[~(d2 > r[pk] ** 2)]] = True
    m = len(sliver)
    clear[sliver] = ~(hit[:m] | hit[m:])
    return clear
