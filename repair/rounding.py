"""Rounding to float32 (what a binary STL stores): the input's, checked before anything
else (:func:`round_input`, stage 1 of the repair); the result's, without making faces
cross (:func:`round_finding_crossings`); and the crossing pairs of a mesh of which only
a few faces changed (:func:`crossings_after_change`), or that a weld re-indexed
(:func:`pairs_after_weld`).

Each coordinate not exactly representable in float32 has two float32 neighbours; where
the nearest ones make faces cross, the vertices of those faces try the others, and only
the region near the moved faces (:class:`repair.face_grid.FaceGrid`) is tested again by
the exact predicate (:func:`repair.intersections.intersecting_face_pairs`).

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from repair.check import Printability, check_printable_pairs, round_to_float32
from repair.clean import degenerate_mask
from repair.face_grid import FaceGrid
from repair.intersections import intersecting_face_pairs, intersecting_pairs_with
from repair.rows import unique_ints, unique_rows

__all__ = [
    "RoundedInput",
    "crossings_after_change",
    "pairs_after_weld",
    "round_avoiding_crossings",
    "round_finding_crossings",
    "round_input",
]


def round_avoiding_crossings(
    vertices: np.ndarray, faces: np.ndarray, max_tries: int = 8
) -> tuple[np.ndarray, int]:
    """Round vertices to float32 (what a binary STL stores) so that rounding itself makes
    no two faces cross. Returns ``(vertices float64, crossing pairs left)``; see
    :func:`round_finding_crossings`."""
    out, pairs = round_finding_crossings(vertices, faces, max_tries)
    return out, int(len(pairs))


def round_finding_crossings(
    vertices: np.ndarray,
    faces: np.ndarray,
    max_tries: int = 8,
    known: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Round vertices to float32 (what a binary STL stores) so that rounding itself makes
    no two faces cross.

    Each coordinate not exactly representable has two float32 neighbours; the nearest is
    tried first. Where faces cross after rounding, every vertex of the crossing faces that
    rounding moved takes the next of its (up to 8) corner choices, and the faces near the
    moved ones are tested again -- a few rounds of exact tests on the damaged region only.
    No vertex moves by more than one float32 ulp.

    Returns ``(vertices float64, pairs)``: ``pairs`` (k, 2) are all the crossing face
    pairs (i < j) among the non-degenerate faces at the returned coordinates, exactly as
    :func:`repair.intersections.intersecting_face_pairs` finds them (a pair of untouched faces
    cannot change; every pair with a moved face is re-tested, the last choices too), so a
    caller need not test the whole mesh again.

    ``known = (same, pairs)``: ``same`` (bool per face) marks faces whose corners are
    float32 values already, with ``pairs`` all the crossing pairs among them (a mesh
    mended after an earlier check: its untouched faces). Only the faces near the others
    are tested then.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    r = v.astype(np.float32)
    up = np.nextafter(r, np.float32(np.inf))
    down = np.nextafter(r, np.float32(-np.inf))
    other = np.where(v > r.astype(np.float64), up, down)
    exact = r.astype(np.float64) == v
    other[exact] = r[exact]
    choice = np.zeros(len(v), dtype=np.int64)  # bit k set: coordinate k takes "other"
    out = r.astype(np.float64)
    moved = ~exact.all(axis=1)
    pairs = np.zeros((0, 2), dtype=np.int64)
    deg_faces = np.zeros(0, dtype=np.int64)
    region = np.arange(len(f))  # faces to test: all at first, then near the moved ones
    grid = None  # built when first needed; choices move vertices far less than its pad
    changed = np.ones(len(f), dtype=bool)
    if known is not None:
        same = np.asarray(known[0], dtype=bool)
        # Their corners do not round: their pairs stand, however many others changed
        # (the others are tested against them, not they among themselves).
        if np.all(exact[f[same]]):
            changed = ~same
            pairs = np.asarray(known[1], dtype=np.int64).reshape(-1, 2)
            deg_faces = np.flatnonzero(same & degenerate_mask(out, f))
            region, grid = _near(out, f, changed, None)
    for attempt in range(max_tries + 1):
        # Exact and face by face: only the moved faces can have become (non)degenerate.
        is_deg = np.zeros(len(f), dtype=bool)
        is_deg[deg_faces] = True
        deg = is_deg[region]
        moved_here = changed[region]
        deg[moved_here] = degenerate_mask(out, f[region[moved_here]])
        found = _pairs_with_changed(out, f, region[~deg], changed)
        # Keep what involves no moved face; take the rest from this test.
        pairs = np.vstack([pairs[~changed[pairs].any(axis=1)], found[changed[found].any(axis=1)]])
        pairs = unique_rows(np.sort(pairs, axis=1)) if len(pairs) else pairs
        rd = region[deg]
        deg_faces = np.union1d(deg_faces[~changed[deg_faces]], rd[changed[rd]])
        hit = np.r_[pairs.reshape(-1), deg_faces]
        bad_v = np.unique(f[hit].reshape(-1))
        bad_v = bad_v[moved[bad_v]]
        if len(bad_v) == 0 or attempt == max_tries:
            break  # the last choices were tested too: the pairs are all known
        choice[bad_v] += 1
        bits = (choice[bad_v, None] >> np.arange(3)) & 1
        out[bad_v] = np.where(bits == 1, other[bad_v], r[bad_v]).astype(np.float64)
        touched = np.zeros(len(v), dtype=bool)
        touched[bad_v] = True
        changed = touched[f].any(axis=1)
        region, grid = _near(out, f, changed, grid)
    return out, pairs


#: Up to this many (face, changed face) box tests, the faces near a few changed ones
#: are found box against box (a few ms) rather than by building a :class:`FaceGrid`
#: (counter's 88.5k faces: ~50 ms, for the 16 faces a hairline cut changed).
DIRECT_BOX_TESTS = 1 << 22


def _near(
    v: np.ndarray, f: np.ndarray, changed: np.ndarray, grid: FaceGrid | None
) -> tuple[np.ndarray, FaceGrid | None]:
    """The faces near those marked in ``changed`` -- every face whose box meets one of
    theirs, and perhaps more: all an exact test of them needs -- and the grid that
    found them (``grid``, built on ``v`` if None and needed; it stays valid while
    vertices move by float32 ulps). Where over a fifth changed, all faces are near
    (:meth:`FaceGrid.near` answers that too) and no box is tested: the exact test of
    the faces apart from the changed ones costs less than finding them (mikedh_rabbit's
    union, 505 of 1,510 faces cut: its finish -2 ms of 15); fewer changed faces are
    tested box against box at the coordinates ``v`` themselves."""
    which = np.flatnonzero(changed)
    if len(which) == 0:
        return which, grid
    if grid is None:
        if len(which) > len(f) // 5:
            return np.arange(len(f)), grid
        if len(which) * len(f) <= DIRECT_BOX_TESTS:
            return _boxes_meeting(v, f, which), grid
        grid = FaceGrid(v, f)
    return grid.near(which), grid


#: When the faces asked about are at least 1 / this of all, :func:`_boxes_meeting` takes
#: the faces touching theirs without a box test (fewer: marking the corners of all faces
#: costs more than it saves; bunny's 115 of 16k: 3.4 ms instead of 3.1).
TOUCH_FIRST = 16


def _boxes_meeting(v: np.ndarray, f: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Sorted indices of the faces whose bounding box meets (closed boxes, exact
    comparisons) that of a face in ``which``, those included: two faces that share a
    point share it in both boxes, so no other face can meet one of ``which``. Faces with
    a corner at a corner of one of ``which`` meet it there: when ``which`` are many, only
    the others are tested box against box (rabbit's 0.6k of 1.5k faces against 505
    changed ones: 3.0 ms instead of 5.4)."""
    out = np.zeros(len(f), dtype=bool)
    if TOUCH_FIRST * len(which) >= len(f):
        at_corner = np.zeros(len(v), dtype=bool)
        at_corner[f[which].reshape(-1)] = True
        out = at_corner[f].any(axis=1)
    cand = np.flatnonzero(~out)
    w = [v[f[which], k] for k in range(3)]  # (len(which), 3) corners per axis
    w_lo = [x.min(axis=1) for x in w]
    w_hi = [x.max(axis=1) for x in w]
    lo, hi = [], []
    for k in range(3):  # axis by axis, first against the box of all of ``which``
        x = v[:, k]
        x0, x1, x2 = x[f[cand, 0]], x[f[cand, 1]], x[f[cand, 2]]
        lo_k = np.minimum(np.minimum(x0, x1), x2)
        hi_k = np.maximum(np.maximum(x0, x1), x2)
        keep = (lo_k <= w_hi[k].max()) & (hi_k >= w_lo[k].min())
        cand = cand[keep]
        lo = [a[keep] for a in lo] + [lo_k[keep]]
        hi = [a[keep] for a in hi] + [hi_k[keep]]
    hit = np.ones((len(cand), len(which)), dtype=bool)
    for k in range(3):
        hit &= lo[k][:, None] <= w_hi[k][None, :]
        hit &= hi[k][:, None] >= w_lo[k][None, :]
    out[cand[hit.any(axis=1)]] = True
    return np.flatnonzero(out)


def crossings_after_change(
    v: np.ndarray, f: np.ndarray, kept: np.ndarray, changed: np.ndarray
) -> np.ndarray:
    """All crossing face pairs of ``(v, f)`` (as
    :func:`repair.intersections.intersecting_face_pairs` finds them among the
    non-degenerate faces), given ``kept``: every crossing pair of
    two faces not marked in ``changed`` (bool per face). Only the region near the changed
    faces is tested again. Copies of a face each get their pairs (libigl's test is
    pairwise and never pairs two copies)."""
    if not np.any(changed):
        return kept
    region = _near(v, f, changed, None)[0]
    region = region[~degenerate_mask(v, f[region])]
    found = _pairs_with_changed(v, f, region, changed)
    both = np.vstack([np.asarray(kept, dtype=np.int64).reshape(-1, 2), found])
    return unique_rows(np.sort(both, axis=1)) if len(both) else both


def pairs_after_weld(
    f: np.ndarray, v32: np.ndarray, f32: np.ndarray, found: np.ndarray
) -> np.ndarray:
    """All crossing pairs of the welded ``(v32, f32)``, given those ``found`` among the
    same faces before the weld (``f``). A weld moves no point and re-indexes the faces
    one for one: two faces none of whose corners was merged with another vertex share
    exactly the corners they shared before, so their pair stands; only near the faces
    on a merged vertex is the exact test run again."""
    n = int(f.max()) + 1 if len(f) else 1
    links = unique_ints(f32.reshape(-1) * n + f.reshape(-1))  # (welded, original) corners
    merged = np.bincount(links // n, minlength=len(v32)) > 1
    changed = merged[f32].any(axis=1)
    kept = found[~changed[found].any(axis=1)]
    return crossings_after_change(v32, f32, kept, changed)


def _pairs_with_changed(
    v: np.ndarray, f: np.ndarray, region: np.ndarray, changed: np.ndarray
) -> np.ndarray:
    """The crossing pairs among the faces ``region`` (non-degenerate) that hold a face
    marked in ``changed``, as a test of the whole region finds them (i < j, unique). Only
    their pairs are tested (:func:`repair.intersections.intersecting_pairs_with`), not
    all those among the unchanged faces around them -- unless the changed faces are
    over three quarters of the region: then one test of all of it costs no more. (A CAD
    union whose cuts changed a third of its faces, mikedh_box's 3,941 of 10,884: 95 ms
    CPU for the whole region, 54 for their pairs.)"""
    moved = changed[region]
    if np.count_nonzero(moved) * 4 > 3 * len(region):
        found = region[intersecting_face_pairs(v, f[region])]
        return found[changed[found].any(axis=1)]
    return intersecting_pairs_with(v, f, region[moved], region[~moved])


@dataclass(frozen=True)
class RoundedInput:
    """The input rounded to float32 (what a binary STL stores, what the repair writes):
    ``vertices`` (float64, float32 values) and ``faces``; ``rounding``, the largest
    distance (mm) a vertex moved; the check of exactly that mesh (``verdict``) and its
    intersecting face ``pairs`` (indices into ``faces``)."""

    vertices: np.ndarray
    faces: np.ndarray
    rounding: float
    verdict: Printability
    pairs: np.ndarray

    def edge_census(self) -> tuple[int, int, int, int, np.ndarray | None]:
        """:func:`repair.topology.edge_stats` of ``faces``, from the check."""
        p = self.verdict
        return (p.boundary_edges, p.nonmanifold_edges, p.misoriented_edges, p.components,
                p.shells)  # fmt: skip


def round_input(
    vertices: np.ndarray, faces: np.ndarray, unwanted: Callable[[], object] | None = None
) -> RoundedInput:
    """Round the input to float32 and check it. Solid parts come out on their rounded
    corners either way; rounding the input first (as an STL input already is) keeps the
    arrangement from having to round twice. ``unwanted``: as in
    :func:`repair.check.check_printable_pairs`."""
    v32 = round_to_float32(vertices)
    moved = v32 - vertices
    rounding = float(np.sqrt(np.max(np.einsum("ij,ij->i", moved, moved))))
    verdict, pairs = check_printable_pairs(v32, faces, as_float32=True, unwanted=unwanted)
    return RoundedInput(v32, faces, rounding, verdict, pairs)
