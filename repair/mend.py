"""Local mending of a closed surface whose only defects are a few self-intersections.

After a boolean union (manifold3d) or an exact arrangement (CGAL) the result is rounded to
float32, what a binary STL stores. Rounding moves every new vertex by up to half a float32
ulp, and slivers near nearly-coplanar faces then cross their neighbours. Redoing the whole
arrangement and outer hull for a handful of such pairs costs seconds on large meshes and
can chase its own tail; this module resolves them where they are:

1. the faces involved in an intersecting pair (exact CGAL predicate) are re-arranged
   exactly among themselves (libigl ``remesh_self_intersections`` on that subset; the
   rest of the surface meets nothing, so the union is a polyhedron);
2. coincident pieces cancel by orientation (a solid's faces touching face to face);
3. each new piece is kept when exactly one of its sides lies outside the solid --
   generalised winding number 0 -- and oriented to face it; pieces inside the solid
   (winding >= 1 on both sides) are dropped. Faces that were not involved keep their
   place and orientation: nothing crossed them, so nothing changed for them.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Vectorised; the CGAL work is
proportional to the damaged faces only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.check import intersecting_face_pairs, weld_exact
from repair.clean import degenerate_mask, drop_unreferenced, face_keys, net_faces
from repair.rows import ranges, unique_ints, unique_rows

__all__ = [
    "Mended",
    "classify_patches",
    "is_cycle",
    "manifold_patches",
    "mend_intersections",
    "round_avoiding_crossings",
    "round_finding_crossings",
    "crossings_after_change",
    "separate_singular_edges",
    "side_windings",
]


@dataclass(frozen=True)
class Mended:
    """Result of :func:`mend_intersections`: the surface and what was done."""

    vertices: np.ndarray
    faces: np.ndarray
    pairs: int
    faces_rearranged: int
    pieces_dropped: int


#: Ray directions tried in turn when a ray grazes an edge or a vertex (irrational-ish).
_DIRECTIONS = np.array(
    [[0.8723, 0.3941, 0.2895], [-0.3307, 0.8412, -0.4277], [0.2113, -0.5371, 0.8167],
     [-0.6929, -0.2652, 0.6705], [0.5503, -0.7708, -0.3211]]
)  # fmt: skip


def _ray_windings(
    v: np.ndarray, f: np.ndarray, q: np.ndarray, own: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Winding number just after leaving each point ``q[i]`` (on face ``own[i]``) along a
    ray, by signed crossings with every other face; and whether the ray left through the
    front of its face. Rays grazing an edge are retried in another direction."""
    out = np.zeros(len(q), dtype=np.int64)
    front = np.zeros(len(q), dtype=bool)
    todo = np.arange(len(q))
    p = v[f]
    scale = float(np.abs(v).max()) or 1.0
    own_n = np.cross(p[own, 1] - p[own, 0], p[own, 2] - p[own, 0])
    for d in _DIRECTIONS:
        d = d / np.linalg.norm(d)
        u = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        px, py, pz = p @ u, p @ w, p @ d  # (m, 3) each
        lo_x, hi_x = px.min(axis=1), px.max(axis=1)
        lo_y, hi_y = py.min(axis=1), py.max(axis=1)
        area2 = (px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (px[:, 2] - px[:, 0]) * (
            py[:, 1] - py[:, 0]
        )
        left = []
        qu, qw, qd = q @ u, q @ w, q @ d
        near = np.flatnonzero(
            (lo_x <= qu[todo].max()) & (hi_x >= qu[todo].min())
            & (lo_y <= qw[todo].max()) & (hi_y >= qw[todo].min())
        )  # fmt: skip
        nlo_x, nhi_x, nlo_y, nhi_y = lo_x[near], hi_x[near], lo_y[near], hi_y[near]
        for i in todo:
            qx, qy, qz = qu[i], qw[i], qd[i]
            c = near[(nlo_x <= qx) & (qx <= nhi_x) & (nlo_y <= qy) & (qy <= nhi_y)]
            c = c[c != own[i]]
            ax, ay = px[c] - qx, py[c] - qy
            bx, by = ax[:, [1, 2, 0]], ay[:, [1, 2, 0]]
            o = ax * by - ay * bx  # (k, 3) orientation of q against each edge
            # Rounding error of o: a few ulps of the coordinates times the edge vectors.
            tiny = np.abs(o) <= 1e-13 * scale * (
                np.abs(ax) + np.abs(ay) + np.abs(bx) + np.abs(by)
            )
            mixed = ((o > 0) & ~tiny).any(axis=1) & ((o < 0) & ~tiny).any(axis=1)
            on_edge = tiny.any(axis=1)
            graze = on_edge & ~mixed
            hit = ~on_edge & ~mixed
            if np.any(graze):
                left.append(i)
                continue
            if np.any(hit):
                h = c[hit]
                bary = np.abs(o[hit][:, [1, 2, 0]])
                depth = (bary * pz[h]).sum(axis=1) / bary.sum(axis=1)
                ahead = depth > qz
                out[i] = int((np.sign(area2[h][ahead]) * weight[h][ahead]).sum())
            front[i] = float(own_n[i] @ d) > 0
        todo = np.asarray(left, dtype=np.int64)
        if len(todo) == 0:
            break
    if len(todo):
        import igl

        # Last resort: the generalised winding number a hair in front of the face.
        ln = np.linalg.norm(own_n[todo], axis=1, keepdims=True)
        n = np.divide(own_n[todo], ln, out=np.zeros_like(own_n[todo]), where=ln > 0)
        probe = q[todo] + 1e-9 * scale * n
        w = np.asarray(igl.fast_winding_number(v, f, probe), dtype=np.float64)
        out[todo] = np.rint(np.nan_to_num(w)).astype(np.int64)
        front[todo] = True
    return out, front


def side_windings(
    vertices: np.ndarray,
    faces: np.ndarray,
    which: np.ndarray,
    weight: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Winding numbers of the closed surface just in front of and just behind each face
    in ``which`` (integers).

    A ray leaves the face's centroid and the signed crossings with all *other* faces are
    counted (the face itself left out), so nearly coincident layers -- thin wedges between
    faces a rounding error apart -- cannot confuse a probe placed off the face.
    ``weight`` (default 1) is each face's multiplicity (coincident copies merged).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    which = np.asarray(which, dtype=np.int64)
    wt = np.ones(len(f), dtype=np.int64) if weight is None else np.asarray(weight)
    q = v[f[which]].mean(axis=1)
    w, left_front = _ray_windings(v, f, q, which, wt)
    front = np.where(left_front, w, w - wt[which])
    return front, front + wt[which]


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
    :func:`repair.check.intersecting_face_pairs` finds them (a pair of untouched faces
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
    grid = None  # built on the first rounding; choices move vertices far less than its pad
    changed = np.ones(len(f), dtype=bool)
    if known is not None:
        same = np.asarray(known[0], dtype=bool)
        # Their corners do not round: their pairs stand (worth it where few changed).
        if np.count_nonzero(~same) <= len(f) // 5 and np.all(exact[f[same]]):
            changed = ~same
            pairs = np.asarray(known[1], dtype=np.int64).reshape(-1, 2)
            deg_faces = np.flatnonzero(same & degenerate_mask(out, f))
            grid = FaceGrid(out, f)
            region = grid.near(np.flatnonzero(changed)) if np.any(changed) else region[:0]
    for attempt in range(max_tries + 1):
        fr = f[region]
        deg = degenerate_mask(out, fr)
        ok = np.flatnonzero(~deg)
        found = region[ok[intersecting_face_pairs(out, fr[ok])]]
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
        if grid is None:
            grid = FaceGrid(out, f)
        region = grid.near(np.flatnonzero(changed))
    return out, pairs


class FaceGrid:
    """Finds the faces near a few others: those whose bounding box meets the (slightly
    grown) box of one of them, and perhaps a few more -- a superset, which is all an
    exact test of the region needs.

    Built once per mesh: grid cells as large as 99 % of the faces' boxes, and each face
    that fits in a cell listed under the cell of its low corner, sorted by cell. A face
    that fits and meets a box has its low corner between the box's low corner less one
    cell and its high corner, so a query gathers the faces listed under those cells for
    each asked face. Larger faces are listed under every cell their box covers (which a
    box they meet covers too), or, beyond 64 cells, tested box against box. Where cells
    are coarse for the asked faces (a CAD mesh mixes sizes), the gathered faces are
    tested box against box too, while that is cheap (gathered x asked <= 1M). Boxes are
    grown by ``1e-6`` of the largest coordinate, so the grid stays valid while vertices
    move by less than that (float32 rounding choices move them by one float32 ulp, ~6e-8
    of it).
    """

    def __init__(self, v: np.ndarray, f: np.ndarray) -> None:
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        pad = 1e-6 * (float(np.abs(v).max()) if len(v) else 1.0) or 1e-6
        self.lo = np.minimum(np.minimum(a, b), c) - pad
        self.hi = np.maximum(np.maximum(a, b), c) + pad
        self.lo_t, self.hi_t = np.ascontiguousarray(self.lo.T), np.ascontiguousarray(self.hi.T)
        self.m = len(f)
        if self.m == 0:
            return
        self.origin = self.lo.min(axis=0)
        span = float((self.hi.max(axis=0) - self.origin).max())
        ext = (self.hi - self.lo).max(axis=1)
        self.h = max(float(np.quantile(ext, 0.99)), span / 1024.0, 1e-300)
        self.n = int(span / self.h) + 3
        self.fits = ext <= self.h
        listed = np.flatnonzero(self.fits)
        k = self._key(self._cell(self.lo[listed]))
        # Larger faces are listed under every cell their box covers, up to 64 of them.
        big = np.flatnonzero(~self.fits)
        lo_c, hi_c = self._cell(self.lo[big]), self._cell(self.hi[big])
        few = (hi_c - lo_c + 1).prod(axis=1) <= 64
        self.big = big[~few]  # the rest: tested box against box
        if np.any(few):
            bk, rows = self._cells_in(lo_c[few], hi_c[few])
            k = np.r_[k, bk]
            listed = np.r_[listed, big[few][rows]]
        shift = max(int(len(listed)).bit_length(), 1)
        idx = np.arange(len(listed), dtype=np.int64)
        if len(k) and int(k.max()) < (1 << (62 - shift)):
            packed = np.sort((k << shift) | idx)  # one plain sort instead of an argsort
            self.sorted_keys = packed >> shift
            self.sorted_faces = listed[packed & ((1 << shift) - 1)]
        else:
            order = np.argsort(k, kind="stable")
            self.sorted_keys = k[order]
            self.sorted_faces = listed[order]

    def _cells_in(self, lo_c: np.ndarray, hi_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keys of all cells in each box of cells ``lo_c..hi_c`` (k, 3), and for each key
        the row it came from."""
        dims = hi_c - lo_c + 1
        cover = dims.prod(axis=1)
        local = np.arange(int(cover.sum())) - np.repeat(np.cumsum(cover) - cover, cover)
        d = np.repeat(dims, cover, axis=0)
        ijk = np.stack([local // (d[:, 1] * d[:, 2]), (local // d[:, 2]) % d[:, 1],
                        local % d[:, 2]], axis=1)  # fmt: skip
        rows = np.repeat(np.arange(len(lo_c)), cover)
        return self._key(lo_c[rows] + ijk), rows

    def _cell(self, x: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((x - self.origin) / self.h), 0, self.n - 1).astype(np.int64)

    def _key(self, c: np.ndarray) -> np.ndarray:
        return (c[..., 0] * self.n + c[..., 1]) * self.n + c[..., 2]

    def _meet(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Mask over ``a``: faces whose box meets the box of a face of ``b``, box against
        box in chunks of 64 of the shorter list."""
        lo, hi = self.lo, self.hi
        out = np.zeros(len(a), dtype=bool)
        for s in range(0, min(len(a), len(b)), 64):
            if len(a) <= len(b):
                g = a[s : s + 64]
                hit = (lo[g, None] <= hi[None, b]) & (hi[g, None] >= lo[None, b])
                out[s : s + 64] = hit.all(axis=2).any(axis=1)
            else:
                g = b[s : s + 64]
                hit = (lo[None, a] <= hi[g, None]) & (hi[None, a] >= lo[g, None])
                out |= hit.all(axis=2).any(axis=0)
        return out

    def _meeting(
        self, first: np.ndarray, count: np.ndarray, asked: np.ndarray, chunk: int
    ) -> list[np.ndarray]:
        """The faces listed under cells ``first[i] .. first[i] + count[i]`` (positions in
        the sorted listing) whose box meets that of face ``asked[i]`` -- cells can be
        coarse -- box-tested ``chunk`` listings at a time (memory)."""
        out = []
        ends = np.cumsum(count)
        steps = np.arange(1, 1 + int(ends[-1]) // chunk) * chunk
        cuts = np.unique(np.r_[0, np.searchsorted(ends, steps), len(count)])
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            c = count[a:b]
            cand = self.sorted_faces[ranges(first[a:b], c)]
            by = np.repeat(asked[a:b], c)
            for k in range(3):  # axis by axis, on ever fewer pairs
                lo, hi = self.lo_t[k], self.hi_t[k]
                hit = (lo[cand] <= hi[by]) & (hi[cand] >= lo[by])
                cand, by = cand[hit], by[hit]
            out.append(np.unique(cand))
        return out

    def near(self, which: np.ndarray, chunk: int = 2**20) -> np.ndarray:
        """Sorted indices of the faces near ``which`` (``which`` included); cell listings
        are box-tested ``chunk`` at a time."""
        which = np.asarray(which, dtype=np.int64)
        if len(which) == 0 or self.m == 0:
            return which
        if len(which) > self.m // 5:
            return np.arange(self.m)  # most of the mesh: one global test is cheaper
        found = [which]
        # Cells from (low corner - one cell) to the high corner of each asked face.
        lo_c, hi_c = self._cell(self.lo[which] - self.h), self._cell(self.hi[which])
        few = (hi_c - lo_c + 1).prod(axis=1) <= 4096
        if np.any(few):
            keys, rows = self._cells_in(lo_c[few], hi_c[few])
            first = np.searchsorted(self.sorted_keys, keys, side="left")
            count = np.searchsorted(self.sorted_keys, keys, side="right") - first
            if int(count.sum()) <= 8 * self.m + chunk:
                found.extend(self._meeting(first, count, which[few][rows], chunk))
            else:
                # Coarse cells and many asked faces: every face listed in their cells (a
                # superset; box-testing each listing would cost more than it saves).
                keys = np.unique(keys)
                first = np.searchsorted(self.sorted_keys, keys, side="left")
                count = np.searchsorted(self.sorted_keys, keys, side="right") - first
                found.append(np.unique(self.sorted_faces[ranges(first, count)]))
        if len(self.big):
            found.append(self.big[self._meet(self.big, which)])
        huge = which[~few]
        if len(huge):
            found.append(np.flatnonzero(self._meet(np.arange(self.m), huge)))
        return np.unique(np.concatenate(found))


def crossings_after_change(
    v: np.ndarray, f: np.ndarray, kept: np.ndarray, changed: np.ndarray
) -> np.ndarray:
    """All crossing face pairs of ``(v, f)`` (as :func:`repair.check.intersecting_face_pairs`
    finds them among the non-degenerate faces), given ``kept``: every crossing pair of
    two faces not marked in ``changed`` (bool per face). Only the region near the changed
    faces is tested again. Copies of a face each get their pairs (libigl's test is
    pairwise and never pairs two copies)."""
    which = np.flatnonzero(changed)
    if len(which) == 0:
        return kept
    region = FaceGrid(v, f).near(which)
    fr = f[region]
    ok = np.flatnonzero(~degenerate_mask(v, fr))
    found = region[ok[intersecting_face_pairs(v, fr[ok])]]
    found = found[changed[found].any(axis=1)]
    both = np.vstack([np.asarray(kept, dtype=np.int64).reshape(-1, 2), found])
    return unique_rows(np.sort(both, axis=1)) if len(both) else both


def _edge_neighbours(faces: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Faces sharing an edge with any face in ``which`` (including those faces)."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, eid = unique_rows(e, return_inverse=True)
    eid = eid.reshape(-1, 3)
    hit = np.zeros(int(eid.max()) + 1, dtype=bool)
    hit[eid[which].reshape(-1)] = True
    return np.flatnonzero(hit[eid].any(axis=1))


def is_cycle(faces: np.ndarray) -> bool:
    """True when every undirected edge is traversed as often in one direction as in the
    other: the faces bound a region (a closed surface, perhaps touching itself), so
    winding numbers are well defined off it."""
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return True
    a = f.reshape(-1)
    b = f[:, [1, 2, 0]].reshape(-1)
    a, b = a[a != b], b[a != b]  # a face with a repeated corner adds nothing
    n = int(f.max()) + 1
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * n + hi
    sign = np.where(a < b, 1, -1)
    uk, inv = unique_ints(key, return_inverse=True)
    return bool(np.all(np.bincount(inv.reshape(-1), weights=sign, minlength=len(uk)) == 0))


def manifold_patches(faces: np.ndarray) -> np.ndarray:
    """Label per face of its patch: faces joined across edges used by exactly two faces
    traversed in opposite directions. Patch borders are the non-manifold edges where an
    arrangement's intersection curves run (and edges of inconsistent orientation)."""
    from repair.thicken import _components, _edge_pairs, _half_edges

    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    he, eid = _half_edges(f)
    h1, h2, _ = _edge_pairs(eid)
    ok = he[h1, 0] == he[h2, 1]
    return _components(len(f), h1[ok] // 3, h2[ok] // 3).astype(np.int64)


def classify_patches(
    vertices: np.ndarray,
    faces: np.ndarray,
    candidates: np.ndarray | None = None,
    weight: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Keep the boundary of the solid a closed polyhedral surface encloses (winding > 0).

    ``faces`` must form a polyhedron (no two faces cross) whose faces, with their
    orientation, make closed cycles. Every manifold patch (:func:`manifold_patches`) has
    the same windings on its two sides throughout; one face per patch (its largest) is
    evaluated. A patch is kept when exactly one side is inside, oriented to face the
    outside; patches inside (or outside) on both sides are dropped. With ``candidates``
    (a face mask) only patches containing a candidate are judged; the others are kept.

    Returns ``(faces, faces_dropped)``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return f, 0
    lab = manifold_patches(f)
    n = int(lab.max()) + 1
    if n == 1:
        return f, 0
    p = v[f]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    order = np.lexsort((-area, lab))
    rep = order[np.r_[True, lab[order][1:] != lab[order][:-1]]]
    if candidates is not None:
        judged = np.zeros(n, dtype=bool)
        judged[lab[np.asarray(candidates, dtype=bool)]] = True
        rep = rep[judged[lab[rep]]]
    front, back = side_windings(v, f, rep, weight)
    inside_f, inside_b = front > 0, back > 0
    keep_patch = np.ones(n, dtype=bool)
    flip_patch = np.zeros(n, dtype=bool)
    keep_patch[lab[rep]] = inside_f ^ inside_b
    flip_patch[lab[rep]] = inside_f & ~inside_b
    keep = keep_patch[lab]
    out = f.copy()
    fl = flip_patch[lab]
    out[fl] = out[fl][:, ::-1]
    return out[keep], int(np.count_nonzero(~keep))


def mend_intersections(
    vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray | None = None
) -> Mended:
    """Resolve the self-intersections of a closed, oriented surface locally.

    ``pairs`` (k, 2) are the intersecting face pairs if already known (else computed with
    :func:`repair.check.intersecting_face_pairs`). Returns the mended surface: exact
    intersection points in float64 (round and check again before writing), faces not
    involved unchanged.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    degm = degenerate_mask(v, f)
    # Coincident copies are not crossings (their weights are merged below): test one copy
    # of each triple, then re-arrange every copy of a crossing face alike.
    key = face_keys(f)
    if pairs is None:
        ok = np.flatnonzero(~degm)
        _, first = unique_ints(key[ok], return_index=True)
        one = ok[first]
        pairs = one[intersecting_face_pairs(v, f[one])]
    if len(pairs) == 0 and not np.any(degm):
        return Mended(v, f, 0, 0, 0)
    import igl.copyleft.cgal as cgal

    bad = np.unique(np.asarray(pairs, dtype=np.int64).reshape(-1))
    bad = np.flatnonzero(np.isin(key, key[bad]) & ~degm)
    deg = np.flatnonzero(degm)
    if len(deg):
        # A zero-area face leaves a crack; its edge neighbours are re-arranged with the
        # rest, which splits them at the vertex the crack ends on.
        bad = np.union1d(bad, np.setdiff1d(_edge_neighbours(f, deg), deg))
    rest = np.ones(len(f), dtype=bool)
    rest[bad] = False
    rest[deg] = False
    # libigl's cost grows with all the vertices it is given: give it those of f[bad].
    sub_v, sub_f = drop_unreferenced(v, f[bad])
    vv, ff, _, _, im = cgal.remesh_self_intersections(
        np.ascontiguousarray(sub_v), np.ascontiguousarray(sub_f), stitch_all=True,
        cutoff=2**31 - 1,
    )  # fmt: skip
    ff = np.asarray(im, dtype=np.int64)[np.asarray(ff, dtype=np.int64)]
    vv = np.asarray(vv, dtype=np.float64)
    # stitch_all re-orders the vertices: concatenate and weld back by position.
    allf = np.vstack([f[rest], ff + len(v)])
    vv, allf = weld_exact(np.vstack([v, vv]), allf)
    new = np.r_[np.zeros(len(allf) - len(ff), dtype=bool), np.ones(len(ff), dtype=bool)]
    ok = ~degenerate_mask(vv, allf)
    allf, new = allf[ok], new[ok]
    keep, weight = net_faces(allf)
    allf, new = allf[keep], new[keep]
    allf, dropped = classify_patches(vv, allf, new, weight)
    vv, allf = drop_unreferenced(vv, allf)
    return Mended(vv, allf, int(len(pairs)), int(len(bad)), int(dropped))


def separate_singular_edges(
    vertices: np.ndarray, faces: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Where a closed, consistently oriented surface touches itself along an edge (2k
    faces on it: k wedges of solid meeting there), give each wedge its own copy of the
    edge's vertices, moved ``step`` mm into its own wedge -- a few float32 ulps, far below
    what a printer resolves, so the parts still print as one, but the written surface is
    edge-manifold. Faces keep their vertices elsewhere; nothing else moves.

    Returns ``(vertices, faces, edges separated)``, or None where the faces around an
    edge do not alternate in orientation (not wedges of one closed solid)."""
    from repair.thicken import _half_edges, _split_vertices

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    he, eid = _half_edges(f)
    cnt = np.bincount(eid)
    singular = np.flatnonzero(cnt > 2)
    if len(singular) == 0:
        return v, f, 0
    if np.any(cnt[singular] % 2):
        return None
    next_id = int(eid.max()) + 1
    third = f[:, [2, 0, 1]].reshape(-1)  # the corner opposite half-edge 3f+k
    on = np.flatnonzero(np.isin(eid, singular))
    on = on[np.argsort(eid[on], kind="stable")]
    bounds = np.r_[0, np.flatnonzero(np.diff(eid[on])) + 1, len(on)]
    for s, e in zip(bounds[:-1], bounds[1:], strict=True):  # one pass per singular edge
        hs = on[s:e]
        a, b = he[hs[0]]
        axis = v[b] - v[a]
        axis /= np.linalg.norm(axis)
        x = v[third[hs[0]]] - v[a]
        x -= axis * np.dot(x, axis)
        x /= np.linalg.norm(x)
        y = np.cross(axis, x)
        d = v[third[hs]] - v[a]
        ang = np.arctan2(d @ y, d @ x)
        # A face running a->b has its outward normal towards increasing angle, so solid
        # lies from a face running b->a round to the next face (which must run a->b).
        forward = he[hs, 0] == a
        order = np.argsort(ang, kind="stable")
        fw = forward[order]
        if np.all(fw[::2]) and not np.any(fw[1::2]):
            order = np.roll(order, -1)  # start at a b->a face
            fw = forward[order]
        if np.any(fw[::2]) or not np.all(fw[1::2]):
            return None
        pair = next_id + np.arange(len(hs) // 2)
        eid[hs[order[::2]]] = pair
        eid[hs[order[1::2]]] = pair
        next_id += len(hs) // 2
    ids = _split_vertices(f, np.zeros(3 * len(f), dtype=bool), eid)
    n = int(ids.max()) + 1
    orig = np.zeros(n, dtype=np.int64)
    orig[ids] = f.reshape(-1)
    copies = np.bincount(orig, minlength=len(v))
    # Move every copy of a split vertex into its own fan: against its faces' normals.
    p = v[f]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    inward = np.zeros((n, 3))
    for k in range(3):
        np.add.at(inward, ids.reshape(-1, 3)[:, k], -fn)
    ln = np.linalg.norm(inward, axis=1, keepdims=True)
    move = (copies[orig] > 1) & (ln[:, 0] > 0)
    nv = v[orig].copy()
    nv[move] += step * inward[move] / ln[move]
    return nv, ids.reshape(-1, 3), len(singular)
