"""Attene's deviation D: how far the repaired surface strays from the input.

``D = max over points p of the output surface of dist(p, input)``, where the input is
its non-degenerate triangles plus the segments its degenerate triangles stood for.
Estimated on the output's vertices, face centroids, edge midpoints and a few random
points per face (deterministic seed). Bounded without samples: output faces that are
input faces (perhaps with their corners rounded to float32), and pieces of input faces
named by a hint (a union keeps the input's triangles and says which each piece is of),
each verified by its corners' distance to that triangle. Units are mm. Vectorised
(libigl AABB tree).
"""

from __future__ import annotations

import numpy as np

from repair.rows import ranges, unique_ints, unique_rows
from repair.topology import face_keys

__all__ = ["max_deviation", "point_triangle_d2"]


def _surface_samples(v: np.ndarray, f: np.ndarray, max_points: int) -> np.ndarray:
    """Where D is estimated on ``(v, f)`` (mm): the vertices, then :func:`_face_samples`."""
    return np.vstack([v, _face_samples(v, f, max_points)[0]])


def _face_samples(v: np.ndarray, f: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The samples of :func:`_surface_samples` other than the vertices -- centroids, edge
    midpoints, then a few random points per face if ``max_points`` allows -- and the face
    each lies on."""
    p = v[f]
    m = np.arange(len(f))
    pts, owner = [p.mean(axis=1), 0.5 * (p + p[:, [1, 2, 0]]).reshape(-1, 3)], [m, m.repeat(3)]
    extra = max(0, min(4, (max_points - len(v) - 4 * len(f)) // max(len(f), 1)))
    if extra:
        rng = np.random.default_rng(0)
        w = rng.dirichlet(np.ones(3), size=(len(f), extra))  # (m, extra, 3)
        pts.append(np.einsum("mek,mkd->med", w, p).reshape(-1, 3))
        owner.append(m.repeat(extra))
    return np.vstack(pts), np.concatenate(owner)


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
    """Mask of the output faces that are not input faces, and a bound (mm) on the
    distance of the others from the input.

    An output face on exactly the corners of an input face is that triangle (distance 0
    everywhere), so it needs no samples. Nor does one whose corners are those corners
    rounded to float32: every point of it lies within its largest corner displacement of
    the input triangle (a convex combination of the corners, each moved that far at most),
    so that displacement bounds its distance."""
    if len(inf) == 0 or len(iv) == 0:
        return np.ones(len(of), dtype=bool), 0.0
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
        return np.ones(len(of), dtype=bool), 0.0
    # Only input faces on matched corners can be an output face's (84k of counter's, few).
    matched = np.zeros(n, dtype=bool)
    matched[fid[known].reshape(-1)] = True
    kin = face_keys(inf[matched[inf].all(axis=1)], n)
    kout = face_keys(fid[known], n)
    same = np.zeros(len(of), dtype=bool)
    same[np.flatnonzero(known)] = np.isin(kout, kin)
    bound = float(moved[of[same]].max()) if np.any(same) else 0.0
    return ~same, bound


def point_triangle_d2(q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Squared distance (mm²) from each point ``q`` (k, 3) to its triangle ``abc`` (k, 3)
    each: the closest point by Voronoi region of the corners, edges and face (Ericson,
    *Real-Time Collision Detection* 5.1.5), vectorised."""
    ab, ac, ap = b - a, c - a, q - a
    bp, cp = q - b, q - c

    def dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", x, y)

    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        den = va + vb + vc
        v, w = vb / den, vc / den
        # NaN on a zero-area triangle (den 0): an edge or corner region is chosen below.
        inner = a + ab * v[:, None] + ac * w[:, None]
    conds = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),
        (d6 >= 0) & (d5 <= d6),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
    ]
    with np.errstate(invalid="ignore"):  # a collapsed edge's t is inf or NaN, not chosen
        choices = [a, b, a + ab * t_ab[:, None], c, a + ac * t_ac[:, None],
                   b + (c - b) * t_bc[:, None]]  # fmt: skip
    closest = inner
    for cond, choice in zip(conds[::-1], choices[::-1], strict=True):  # the first region that holds
        closest = np.where(cond[:, None], choice, closest)
    d = q - closest
    return dot(d, d)


#: Inputs of this many triangles get a tree over the triangles near a few points only.
LOCAL_TREE_MIN_FACES = 50_000


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

    if len(f) < LOCAL_TREE_MIN_FACES or len(pts) == 0 or len(pts) > len(f):
        return d2_to(f, pts)
    near = _faces_within_vertex_reach(pts, v, f)
    if near is not None:
        return d2_to(f[near], pts) if len(near) else d2_to(f, pts)
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


def _faces_within_vertex_reach(pts: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray | None:
    """For a few points (``len(pts) x`` corners at most ``2^22``): the faces that can hold
    a point's nearest surface point -- those whose box, grown by ``r``, holds a point along
    every axis (:func:`repair.probe_grid.faces_near_points`), ``r`` the largest distance
    from a point to its nearest corner of a face (no nearer face can be farther). Building
    libigl's tree on all of counter's 84k faces for its 60 sample points cost 0.12 s; None
    when the points are too many for the brute-force corner distances or the faces found
    are most of them."""
    from repair.probe_grid import faces_near_points

    corners = v[unique_ints(f.reshape(-1))]
    if len(pts) * len(corners) > 2**22:
        return None
    reach = 0.0
    step = max(1, 2**20 // len(corners))
    for s in range(0, len(pts), step):
        q = pts[s : s + step]
        d2 = sum((q[:, None, k] - corners[None, :, k]) ** 2 for k in range(3))
        reach = max(reach, float(d2.min(axis=1).max()))
    r = np.sqrt(reach) * (1.0 + 1e-9)  # nearest corners, rounding aside
    near = faces_near_points(v, f, pts, r)
    return near if 2 * len(near) < len(f) else None


def _within_input_faces(
    ov: np.ndarray, of: np.ndarray, iv: np.ndarray, tri: np.ndarray,
    on_corner: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Which output faces ``of`` are shown to lie on the input triangles ``tri`` (one
    each, indices into ``iv``), and a bound (mm) on their distance from the input.

    A piece of an input face (a union cuts faces where shells cross) lies in it: every
    point of the output face is within its largest corner distance of that triangle (a
    convex set). Shown where that bound is at float32-rounding scale (4 ulps of the
    largest coordinate); the other faces are left to be sampled. ``on_corner`` (k, 3),
    if known: which corners equal a corner of their triangle (distance 0, the corner
    itself being its nearest point: not measured)."""
    if len(of) == 0:
        return np.zeros(0, dtype=bool), 0.0
    p = ov[of]
    t = iv[tri]
    if on_corner is None:
        on_corner = np.zeros(of.shape, dtype=bool)
    d2 = np.zeros(len(of))
    for k in range(3):
        r = np.flatnonzero(~on_corner[:, k])
        tk = t[r]
        d2[r] = np.maximum(d2[r], point_triangle_d2(p[r, k], tk[:, 0], tk[:, 1], tk[:, 2]))
    tol = 2.0**-21 * max(float(np.abs(iv).max()), float(np.abs(ov).max()), 1.0)
    ok = d2 <= tol * tol
    return ok, (float(np.sqrt(d2[ok].max())) if np.any(ok) else 0.0)


def _neighbour_guesses(
    of: np.ndarray, hint: np.ndarray, which: np.ndarray, limit: int = 200_000
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate input faces for the faces ``which`` of ``of``: the distinct hints of the
    faces sharing a corner with each. Returns ``(rows, input faces)``, one row per
    candidate (at most ``limit``)."""
    if len(which) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # Only hinted faces sharing a corner with one asked about can be a candidate.
    asked = np.zeros(int(of.max()) + 1, dtype=bool)
    asked[of[which].reshape(-1)] = True
    has = np.flatnonzero((hint >= 0) & asked[of].any(axis=1))
    if len(has) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # (vertex, hint) of every hinted face's corners, distinct, sorted by vertex.
    vh = unique_rows(np.stack([of[has].reshape(-1), np.repeat(hint[has], 3)], axis=1))
    corner = of[which].reshape(-1)
    start = np.searchsorted(vh[:, 0], corner, side="left")
    cnt = np.searchsorted(vh[:, 0], corner, side="right") - start
    total = int(cnt.sum())
    if total == 0 or total > limit:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    pos = ranges(start, cnt)
    rows = np.repeat(np.repeat(which, 3), cnt)
    pair = unique_rows(np.stack([rows, vh[pos, 1]], axis=1))
    return pair[:, 0], pair[:, 1]


def max_deviation(
    out_vertices: np.ndarray,
    out_faces: np.ndarray,
    in_vertices: np.ndarray,
    in_faces: np.ndarray,
    in_segments: np.ndarray | None = None,
    *,
    max_points: int = 400_000,
    hint: np.ndarray | None = None,
) -> float:
    """Largest distance (mm) from sampled output surface points to the input.

    ``hint`` (optional, per output face): an input face it is believed to lie on, or -1.
    A guess only: each is verified (:func:`_within_input_faces`), and faces it does not
    hold for are measured as the others.

    Returns 0.0 for an empty output and ``inf`` when the input has nothing to measure to.
    """
    ov = np.asarray(out_vertices, dtype=np.float64)
    of = np.asarray(out_faces, dtype=np.int64)
    if len(of) == 0:
        return 0.0
    iv = np.asarray(in_vertices, dtype=np.float64)
    inf = np.asarray(in_faces, dtype=np.int64)
    new = np.ones(len(of), dtype=bool)
    bound = 0.0
    if hint is not None and len(inf):
        h = np.asarray(hint, dtype=np.int64)
        h = np.where(h < len(inf), h, -1)
        guess = np.flatnonzero(h >= 0)
        # The hinted face itself (corners equal in any order): distance 0.
        p, t = ov[of[guess]], iv[inf[h[guess]]]
        eq = np.ones((len(guess), 3, 3), dtype=bool)
        for k in range(3):  # corner i of p equals corner j of t, coordinate by coordinate
            eq &= p[:, :, None, k] == t[:, None, :, k]
        on_corner = eq.any(axis=2)
        same = on_corner.all(axis=1)
        new[guess[same]] = False
        guess = guess[~same]
        shown, bound = _within_input_faces(ov, of[guess], iv, inf[h[guess]], on_corner[~same])
        new[guess[shown]] = False
        # A face cut again later (a mend after rounding) has no hint of its own, but
        # usually lies on the input face of a face sharing one of its corners.
        rows, tri = _neighbour_guesses(of, h, np.flatnonzero(new))
        shown, b = _within_input_faces(ov, of[rows], iv, inf[tri])
        new[rows[shown]] = False
        bound = max(bound, b)
    if np.any(new):
        left = np.flatnonzero(new)
        still, b = _new_faces(ov, of[left], iv, inf)
        new[left[~still]] = False
        bound = max(bound, b)
    of = of[new]
    if len(of) == 0:
        return bound
    # Only the vertices of new faces: the others are (rounded) input vertices.
    used, local = unique_ints(of.reshape(-1), return_inverse=True)
    return max(_max_sample_distance(ov[used], local.reshape(-1, 3), iv, inf, in_segments,
                                    max_points), bound)  # fmt: skip


def _max_sample_distance(
    v: np.ndarray, f: np.ndarray, iv: np.ndarray, inf: np.ndarray,
    segments: np.ndarray | None, max_points: int,
) -> float:
    """Largest distance (mm) from the samples of ``(v, f)`` (:func:`_surface_samples`) to
    the input triangles ``inf`` and ``segments``, measured where it can be the largest.

    The corners are measured first. Faces on which the distance cannot reach the largest
    one measured, less a margin for rounding (:data:`BOUND_MARGIN` of the coordinates'
    size), are left out (:func:`_faces_reaching`); then the samples of the others that
    are no farther than that from the input, by ``d(c) + |p - c|`` for each corner ``c``
    (the distance to a set is 1-Lipschitz) or by their distance to the input triangle
    nearest to a corner. On a thickened sheet a face offset from an input face is bounded
    by that face, far below the largest distance: chair measures 4 of 9.5k samples,
    mikedh_target 6 of 164k, mikedh_teapot 14.9k of 168k. Where most faces reach it (a
    plateau, noise everywhere) the samples are measured without bounds. The same answer
    as measuring every sample: a sample left out is nearer than one measured. Fewer than
    :data:`BOUND_MIN_SAMPLES` samples are measured at once, as are a few on a large input
    (on a tree of the triangles near them, :func:`_point_mesh_d2`)."""
    pts, owner = _face_samples(v, f, max_points)
    segments = None if segments is None or len(segments) == 0 else np.asarray(
        segments, dtype=np.float64)  # fmt: skip
    few = len(v) + len(pts) < BOUND_MIN_SAMPLES or (
        len(inf) >= LOCAL_TREE_MIN_FACES and len(v) + len(pts) <= len(inf))  # fmt: skip
    if len(inf) == 0 or few:
        every = np.vstack([v, pts])
        d2 = _point_mesh_d2(every, iv, inf) if len(inf) else np.full(len(every), np.inf)
        if segments is not None:
            d2 = np.minimum(d2, _point_segment_d2(every, segments))
        return float(np.sqrt(d2.max()))
    import igl

    iv = np.ascontiguousarray(iv, dtype=np.float64)
    inf = np.ascontiguousarray(inf, dtype=np.int64)
    tree = igl.AABB()
    tree.init(iv, inf)

    def d2_to_input(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d2, face, _ = tree.squared_distance(iv, inf, np.ascontiguousarray(q))
        if segments is not None:
            d2 = np.minimum(d2, _point_segment_d2(q, segments))
        return np.asarray(d2), np.asarray(face, dtype=np.int64)

    d2, near = d2_to_input(v)
    dc = np.sqrt(d2)
    scale = max(float(np.abs(v).max()), float(np.abs(iv).max()), 1.0)
    best = float(dc.max())
    below = best - BOUND_MARGIN * scale
    if not below > 0:  # nothing can be left out
        return max(best, float(np.sqrt(d2_to_input(pts)[0].max()))) if len(pts) else best
    # Whole faces first, then the samples of the others -- unless most faces reach it
    # (a plateau, noise everywhere): then their samples are measured, not bounded.
    live = _faces_reaching(v, f, dc, iv, inf[near], below)
    ask = np.flatnonzero(np.isin(owner, live))
    bounded = 4 * len(live) <= 3 * len(f)
    if bounded:
        reach = pts[ask, None] - v[f[owner[ask]]]  # (k, 3, 3): to each corner of its face
        bound = (dc[f[owner[ask]]] + np.sqrt(np.einsum("kcd,kcd->kc", reach, reach))).min(
            axis=1)  # fmt: skip
        ask = ask[~(bound < below)]  # NaN bounds are asked
    for j in range(3 if bounded else 0):  # the input triangle nearest to each corner
        t = iv[inf[near[f[owner[ask], j]]]]
        before = len(ask)
        ask = ask[~(point_triangle_d2(pts[ask], t[:, 0], t[:, 1], t[:, 2]) < below * below)]
        if 4 * len(ask) > 3 * before:  # a plateau at the largest distance: measure them
            break
    if len(ask):
        best = max(best, float(np.sqrt(d2_to_input(pts[ask])[0].max())))
    return best


def _faces_reaching(
    v: np.ndarray, f: np.ndarray, dc: np.ndarray, iv: np.ndarray, tri: np.ndarray,
    below: float,
) -> np.ndarray:
    """The faces of ``(v, f)`` (indices) on which the distance to the input may reach
    ``below`` (mm), given their corners' distances ``dc`` and the input triangles ``tri``
    (corners indexing ``iv``) nearest to each vertex. On a face, the distance is at most
    ``d(c) + `` the farthest corner from ``c`` for each corner ``c`` (1-Lipschitz), and at
    most the largest of the corners' distances to one triangle (a convex function)."""
    p = v[f]
    edge = np.sqrt(np.einsum("mkd,mkd->mk", p - p[:, [1, 2, 0]], p - p[:, [1, 2, 0]]))
    far = np.maximum(edge, edge[:, [2, 0, 1]])  # corner k: its two edges, k and k - 1
    live = np.flatnonzero(~((dc[f] + far).min(axis=1) < below))
    for j in range(3):
        t = iv[tri[f[live, j]]]
        top = np.max([point_triangle_d2(p[live, k], t[:, 0], t[:, 1], t[:, 2]) for k in range(3)],
                     axis=0)  # fmt: skip
        before = len(live)
        live = live[~(top < below * below)]
        if 16 * len(live) > 15 * before:  # nearly all faces reach it: the samples will tell
            break
    return live


#: Fewer samples than this are measured without bounds: bounding them costs more.
BOUND_MIN_SAMPLES = 2048
#: Rounding margin (a fraction of the largest coordinate, mm) by which a sample's bound
#: must stay below the largest distance measured to be left out: far above the error of
#: a double-precision point-triangle distance at that scale.
BOUND_MARGIN = 2.0**-20
