"""Exact self-intersection test of triangle meshes: CGAL's exact predicates through
libigl (``igl.copyleft.cgal.remesh_self_intersections(..., detect_only=True)``), on
large meshes in slabs tested side by side in forked processes.

Faces that share a vertex or an edge and otherwise only touch along it are not
intersecting; any other contact (crossing, touching at a point, coplanar overlap) is.
Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.errors import BudgetExceeded
from repair.rows import unique_rows

__all__ = [
    "MAX_BOX_PAIRS",
    "PARALLEL_MIN_FACES",
    "check_box_pair_budget",
    "intersecting_face_pairs",
    "intersecting_pairs_with",
]


#: Meshes with at least this many faces are tested in slabs, one per CPU (forked workers).
PARALLEL_MIN_FACES = 8_000


def intersecting_face_pairs(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unordered pairs (k, 2) of faces that intersect, by CGAL's exact predicates.

    Faces must be non-degenerate and not combinatorial duplicates (libigl skips those).
    Faces sharing a vertex/edge count only if they meet beyond the shared element.
    Pairs are sorted (i < j) and unique, as indices into ``faces``.

    libigl's test runs on one core; a large mesh is cut into slabs along its longest axis,
    tested side by side in forked processes (see :func:`_pairs_in_slabs`).
    """
    if len(faces) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    from repair.workers import cpu_workers

    check_box_pair_budget(v, f)
    workers = cpu_workers()
    if len(f) >= PARALLEL_MIN_FACES and workers > 1:
        pairs = _pairs_in_slabs(v, f, workers)
    else:
        pairs = _pairs(v, f)
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return unique_rows(np.sort(pairs, axis=1))


#: CGAL's test holds every pair of faces whose bounding boxes meet (libigl collects them
#: before testing any): about 12 bytes and 0.4 us of CPU each (measured: 20.8M pairs of
#: a mesh of crossing slabs, 245 MB). A test is allowed ``max(MAX_BOX_PAIRS, 64 * faces)``
#: of them: 400 MB at most on a mesh below 520k faces. A tessellated surface has 7-40
#: per face (the corpus, sampled as :func:`check_box_pair_budget` does); the slabs that
#: took 2.3 GB before CGAL's ``bad_alloc`` (259k faces) had 900.
MAX_BOX_PAIRS = 1 << 25
#: Faces whose box is tested against all others to estimate the pairs of a mesh.
_BUDGET_SAMPLES = 32


def check_box_pair_budget(vertices: np.ndarray, faces: np.ndarray) -> None:
    """Raise :class:`repair.errors.BudgetExceeded` when the exact test of ``faces`` would
    hold more candidate pairs (faces whose bounding boxes meet) than
    :data:`MAX_BOX_PAIRS` or 64 per face allow. The count is estimated from evenly spaced
    faces, each tested against all boxes (``32 * faces`` box tests; none below 8,192
    faces, where the bound cannot be reached)."""
    m = len(faces)
    limit = max(MAX_BOX_PAIRS, 64 * m)
    if m * (m - 1) // 2 <= limit:
        return
    v = np.asarray(vertices, dtype=np.float64)
    p = [v[faces[:, i]] for i in range(3)]
    lo = np.minimum(np.minimum(p[0], p[1]), p[2]).T.copy()
    hi = np.maximum(np.maximum(p[0], p[1]), p[2]).T.copy()
    meets = 0
    pick = np.linspace(0, m - 1, _BUDGET_SAMPLES).astype(np.int64)
    for i in pick:
        hit = (lo[0] <= hi[0, i]) & (hi[0] >= lo[0, i])
        for d in (1, 2):
            hit &= (lo[d] <= hi[d, i]) & (hi[d] >= lo[d, i])
        meets += int(np.count_nonzero(hit)) - 1
    estimate = m * meets / (2 * len(pick))
    if estimate > limit:
        raise BudgetExceeded(
            f"the exact intersection test of {m} faces would hold about {estimate:.3g} "
            f"pairs of overlapping boxes, over its budget of {limit:.3g}"
        )


def intersecting_pairs_with(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray, others: np.ndarray
) -> np.ndarray:
    """The pairs (k, 2) that :func:`intersecting_face_pairs` finds among the faces
    ``which`` and ``others`` (indices into ``faces``, disjoint) that hold a face of
    ``which``: sorted (i < j), unique, as indices into ``faces``.

    Only those pairs are tested: ``which`` and the faces of ``others`` that have a corner
    at a corner of one of them in one self-intersection test (shared corners read as
    adjacency there), ``which`` against the rest of ``others`` -- faces with no corner
    at theirs, so any contact is an intersection -- by libigl's ``intersect_other`` on
    the same exact predicates, testing no pair of two ``others``. Where few faces changed
    among many near them, that spares testing all the pairs among the unchanged.
    """
    f = np.ascontiguousarray(faces, dtype=np.int64)
    which = np.asarray(which, dtype=np.int64)
    others = np.asarray(others, dtype=np.int64)
    if len(which) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # libigl's self test reads two corners at one point as shared even under two
    # indices: faces are paired by the points of their corners.
    v = np.asarray(vertices, dtype=np.float64)
    used, corner = _used_vertices(np.r_[f[which], f[others]].reshape(-1), len(v))
    bits = (v[used] + 0.0).view(np.int64)  # -0 is 0
    point = unique_rows(bits, return_inverse=True)[1][corner].reshape(-1, 3)
    on_which = np.zeros(len(used), dtype=bool)
    on_which[point[: len(which)].reshape(-1)] = True
    touching = on_which[point[len(which) :]].any(axis=1)
    # In index order: libigl's verdict on two faces sharing an edge can depend on
    # which of them comes first, so keep the order a test of the whole region has.
    near = np.sort(np.r_[which, others[touching]])
    apart = others[~touching]
    from repair.workers import cpu_workers

    workers = cpu_workers()
    if workers > 1 and len(near) >= PARALLEL_MIN_FACES and (
        len(which) + len(apart) >= BESIDE_MIN_FACES
    ):
        found = _apart_beside(vertices, f, near, which, apart)
    elif SPLIT_MIN_FACES <= len(near) < PARALLEL_MIN_FACES and workers > 1:
        found = _near_and_apart_forked(vertices, f, near, which, apart)
    else:
        found = [near[intersecting_face_pairs(vertices, f[near])]]
        if len(apart):
            found.append(_pairs_between(vertices, f, which, apart))
    pairs = np.sort(np.vstack(found), axis=1)
    in_which = np.zeros(len(f), dtype=bool)
    in_which[which] = True
    pairs = pairs[in_which[pairs].any(axis=1)]
    return unique_rows(pairs) if len(pairs) else np.zeros((0, 2), dtype=np.int64)


#: From this many faces on, the self test of :func:`intersecting_pairs_with` (below
#: :data:`PARALLEL_MIN_FACES`, where :func:`intersecting_face_pairs` slabs it anyway) is
#: cut in two slabs, the second tested in a forked child beside the first and the test
#: against the faces apart: mikedh_box's finish, 6,221 faces, 77 ms of CPU in one test,
#: 40 + 35 in two, with a fork of ~4 ms.
SPLIT_MIN_FACES = 3_000


#: What the test between ``which`` and the faces apart costs per face of both, in faces of a
#: self test (mikedh_box's finish: 3,941 + 4,663 faces apart 5.45 ms, 3,149 near 20 ms;
#: its forked test, best of 12: 28.7 ms balanced by faces, 26.6 at 0.1, 27.2 at 0.15).
APART_COST = 0.1


def _near_and_apart_forked(
    v: np.ndarray, f: np.ndarray, near: np.ndarray, which: np.ndarray, apart: np.ndarray
) -> list[np.ndarray]:
    """The pairs :func:`intersecting_pairs_with` finds among ``near`` (one test of them,
    as :func:`_pairs_in_slabs` splits it) and between ``which`` and ``apart``: slab 1 in
    a forked child, slab 0 and the faces apart here."""
    from repair.workers import map_forked

    check_box_pair_budget(v, f[near])
    # Slab 0 is tested here beside the faces apart: it holds fewer faces, by their cost.
    head = APART_COST * (len(which) + len(apart)) / len(near) if len(apart) else 0.0
    slabs = face_slabs(v, f[near], 2, head)

    def test(job: np.ndarray | None) -> tuple[np.ndarray]:
        if job is None:
            return (_pairs_between(v, f, which, apart) if len(apart) else _no_pairs(),)
        return (near[job[_pairs(v, f[near[job]])]],)

    found = map_forked(test, [slabs[0], None, slabs[1]], [[0, 1], [2]])
    return [r[0].reshape(-1, 2) for r in found]


#: From this many faces (``which`` and the faces apart) on, :func:`intersecting_pairs_with`
#: tests ``which`` against the faces apart in a forked child beside the self test of a
#: region of :data:`PARALLEL_MIN_FACES` or more (slabbed as usual), not after it:
#: mikedh_counter's finish, 8,097 faces near and 6,347 + 43,112 apart, 23 ms + 27 ms.
BESIDE_MIN_FACES = 8_000


def _apart_beside(
    v: np.ndarray, f: np.ndarray, near: np.ndarray, which: np.ndarray, apart: np.ndarray
) -> list[np.ndarray]:
    """The pairs :func:`intersecting_pairs_with` finds among ``near`` (in slabs, as
    :func:`intersecting_face_pairs` tests them, from here) and between ``which`` and
    ``apart`` (in a forked child); unsorted, maybe repeated."""
    import igl.copyleft.cgal  # noqa: F401 -- imported here, not in the child

    from repair.workers import cpu_workers, map_forked

    v = np.ascontiguousarray(v, dtype=np.float64)
    check_box_pair_budget(v, f[near])  # raised before any child is forked

    def test(job: np.ndarray | None) -> tuple[np.ndarray]:
        if job is None:
            return (_pairs_between(v, f, which, apart),)
        return (job[_pairs_in_slabs(v, f[job], cpu_workers())],)

    found = map_forked(test, [near, None], [[0], [1]])
    return [r[0].reshape(-1, 2) for r in found]


def _no_pairs() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.int64)


def _pairs_between(v: np.ndarray, f: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairs (face of ``a``, face of ``b``) that meet at all (libigl ``intersect_other``,
    CGAL's exact ``do_intersect``), as indices into ``f``; each side is given only the
    vertices it uses."""
    import igl.copyleft.cgal as cgal

    va, fa = _compact(v, f[a])
    vb, fb = _compact(v, f[b])
    hits = cgal.intersect_other(va, fa, vb, fb, detect_only=True)[0]
    hits = np.asarray(hits, dtype=np.int64).reshape(-1, 2)
    return np.stack([a[hits[:, 0]], b[hits[:, 1]]], axis=1)


def _compact(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices ``f`` uses (same coordinates) and ``f`` re-indexed into them."""
    used, inverse = _used_vertices(f.reshape(-1), len(v))
    verts = np.ascontiguousarray(np.asarray(v, dtype=np.float64)[used])
    return verts, np.ascontiguousarray(inverse.reshape(-1, 3), dtype=np.int64)


def _used_vertices(corners: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(corners, return_inverse=True)`` for vertex indices below ``n``: the
    used ones (sorted) and each corner's position among them. A mark per vertex instead
    of a sort (counter's finish, 50k faces of 44k vertices: 10.7 ms -> 1 ms)."""
    mark = np.zeros(n, dtype=bool)
    mark[corners] = True
    used = np.flatnonzero(mark)
    pos = np.empty(n, dtype=np.int64)
    pos[used] = np.arange(len(used), dtype=np.int64)
    return used, pos[corners]


def _pairs(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """libigl's detection on all of ``f``: pairs (k, 2), unsorted, maybe repeated."""
    import igl.copyleft.cgal as cgal

    pairs = cgal.remesh_self_intersections(v, f, detect_only=True)[2]
    return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


def _pairs_in_slabs(v: np.ndarray, f: np.ndarray, k: int) -> np.ndarray:
    """The pairs of ``f``, found slab by slab, ``k`` slabs tested at once.

    Slab ``i`` is ``[c_i, c_i+1)`` along the longest axis (cuts at quantiles of the face
    centres); it holds every face whose extent along that axis meets it. Two faces that
    intersect share a point, which lies in some slab, and both faces meet that slab, so
    each pair is found in at least one slab. Each slab is tested on all vertices with the
    faces' own indices, so adjacency (shared vertices) reads the same as in one test.
    Slabs 1.. run in forked children (:func:`repair.workers.map_forked`).
    """
    from repair.workers import map_forked

    slabs = face_slabs(v, f, k)

    def test(idx: np.ndarray) -> tuple[np.ndarray]:
        return (idx[_pairs(v, f[idx])],)

    found = map_forked(test, slabs, [[i] for i in range(k)])
    return np.vstack([r[0].reshape(-1, 2) for r in found])


def face_slabs(v: np.ndarray, f: np.ndarray, k: int, head: float = 0.0) -> list[np.ndarray]:
    """The faces (indices into ``f``) of each of ``k`` slabs along the longest axis, as
    :func:`_pairs_in_slabs` tests them. ``head``: other work (as a fraction of ``f``'s
    faces) done by the process that tests slab 0, which then holds that many fewer."""
    axis = int(np.argmax(v.max(axis=0) - v.min(axis=0)))
    x = np.ascontiguousarray(v[:, axis])
    x0, x1, x2 = x[f[:, 0]], x[f[:, 1]], x[f[:, 2]]  # 1-D gathers and element-wise min/max:
    lo = np.minimum(np.minimum(x0, x1), x2)  # several times faster than a reduction over
    hi = np.maximum(np.maximum(x0, x1), x2)  # rows of three
    # The cuts balance the slabs of a sample of the faces (any cuts find every pair; a
    # balanced split only keeps the children equally busy): no sort of all of them.
    step = max(1, len(f) // _CUT_SAMPLE)
    edges = np.r_[-np.inf, _even_cuts(lo[::step], hi[::step], k, head), np.inf]
    return [np.flatnonzero((lo < edges[i + 1]) & (hi >= edges[i])) for i in range(k)]


#: About this many faces (every n-th) place the slab cuts of a large mesh.
_CUT_SAMPLE = 50_000


def _even_cuts(lo: np.ndarray, hi: np.ndarray, k: int, head: float = 0.0) -> np.ndarray:
    """``k - 1`` cuts along an axis so that the ``k`` slabs ``[c_i, c_i+1)`` hold about
    as many faces each (extents ``[lo, hi]``; a face spanning a cut is in both slabs),
    the first ``head * len(lo)`` fewer (its process has that much other work).

    Slab ``[a, b)`` holds ``#(lo < b) - #(hi < a)`` faces, so for a target ``t`` each
    cut is the low end of rank ``t + #(hi < previous cut)`` (the first, of ``t - head``);
    ``t`` is bisected until the last slab holds about ``t`` too."""
    sl, sh = np.sort(lo), np.sort(hi)
    m = len(lo)
    less = int(head * m)

    def cuts_for(t: int) -> tuple[list[float], int]:
        out, prev = [], -np.inf
        for i in range(k - 1):
            below = int(np.searchsorted(sh, prev, side="left"))
            c = float(sl[min(max(t - less * (i == 0), 0) + below, m - 1)])
            out.append(c)
            prev = c
        return out, m - int(np.searchsorted(sh, prev, side="left"))

    a, b = (m + k - 1) // k, m
    while a < b:  # the smallest target whose last slab is no larger than it
        t = (a + b) // 2
        if cuts_for(t)[1] <= t:
            b = t
        else:
            a = t + 1
    return np.asarray(cuts_for(a)[0])
