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

from repair.clean import degenerate_mask, drop_unreferenced, net_faces
from repair.intersections import intersecting_face_pairs
from repair.rows import unique_ints
from repair.topology import (
    connected_labels,
    edge_ids,
    edge_neighbours,
    face_keys,
    half_edges,
    paired_half_edges,
    split_vertex_fans,
    weld_exact,
)

__all__ = [
    "Mended",
    "classify_patches",
    "manifold_patches",
    "mend_intersections",
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
    #: With ``outside_sheets``: the dropped pieces that bound no solid (outside on both
    #: sides, or coincident copies that cancel; one copy each), rows into ``vertices``.
    sheets: np.ndarray | None = None


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


def manifold_patches(faces: np.ndarray) -> np.ndarray:
    """Label per face of its patch: faces joined across edges used by exactly two faces
    traversed in opposite directions. Patch borders are the non-manifold edges where an
    arrangement's intersection curves run (and edges of inconsistent orientation)."""
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    he = half_edges(f)
    h1, h2, _ = paired_half_edges(edge_ids(f)[0])
    ok = he[h1, 0] == he[h2, 1]
    return connected_labels(len(f), h1[ok] // 3, h2[ok] // 3)


def classify_patches(
    vertices: np.ndarray,
    faces: np.ndarray,
    candidates: np.ndarray | None = None,
    weight: np.ndarray | None = None,
    *,
    nonzero: bool = False,
) -> tuple[np.ndarray, int]:
    """Keep the boundary of the solid a closed polyhedral surface encloses (winding > 0;
    with ``nonzero``, winding != 0: a lobe turned inside out is solid too).

    ``faces`` must form a polyhedron (no two faces cross) whose faces, with their
    orientation, make closed cycles. Every manifold patch (:func:`manifold_patches`) has
    the same windings on its two sides throughout; one face per patch (its largest) is
    evaluated. A patch is kept when exactly one side is inside, oriented to face the
    outside; patches inside (or outside) on both sides are dropped. With ``candidates``
    (a face mask) only patches containing a candidate are judged; the others are kept.

    Returns ``(faces, faces_dropped)``.
    """
    out, keep, _ = _sorted_patches(vertices, faces, candidates, weight, nonzero)
    return out[keep], int(np.count_nonzero(~keep))


def _sorted_patches(
    vertices: np.ndarray, faces: np.ndarray, candidates: np.ndarray | None,
    weight: np.ndarray | None, nonzero: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`classify_patches`' work: every face, turned to face the outside where kept;
    the mask of those kept, and of the faces outside on both sides."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    none = np.zeros(len(f), dtype=bool)
    if len(f) == 0:
        return f, none, none
    lab = manifold_patches(f)
    n = int(lab.max()) + 1
    if n == 1:
        return f, ~none, none
    p = v[f]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    order = np.lexsort((-area, lab))
    rep = order[np.r_[True, lab[order][1:] != lab[order][:-1]]]
    if candidates is not None:
        judged = np.zeros(n, dtype=bool)
        judged[lab[np.asarray(candidates, dtype=bool)]] = True
        rep = rep[judged[lab[rep]]]
    front, back = side_windings(v, f, rep, weight)
    inside_f, inside_b = (front != 0, back != 0) if nonzero else (front > 0, back > 0)
    keep_patch = np.ones(n, dtype=bool)
    flip_patch = np.zeros(n, dtype=bool)
    outside = np.zeros(n, dtype=bool)
    keep_patch[lab[rep]] = inside_f ^ inside_b
    flip_patch[lab[rep]] = inside_f & ~inside_b
    outside[lab[rep]] = ~inside_f & ~inside_b
    out = f.copy()
    fl = flip_patch[lab]
    out[fl] = out[fl][:, ::-1]
    return out, keep_patch[lab], outside[lab]


def mend_intersections(
    vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray | None = None, *,
    nonzero: bool = False, outside_sheets: bool = False,
) -> Mended:
    """Resolve the self-intersections of a closed, oriented surface locally.

    ``pairs`` (k, 2) are the intersecting face pairs if already known (else computed with
    :func:`repair.intersections.intersecting_face_pairs`). Returns the mended surface: exact
    intersection points in float64 (round and check again before writing), faces not
    involved unchanged. The solid kept is where the winding number is > 0, or != 0 with
    ``nonzero`` (see :func:`classify_patches`); ``outside_sheets``: also say which
    dropped pieces bound no solid (``Mended.sheets``), for the caller to thicken.
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
        bad = np.union1d(bad, np.setdiff1d(edge_neighbours(f, deg), deg))
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
    cancelled = _cancelled_copies(allf, keep) if outside_sheets else None
    allf, new = allf[keep], new[keep]
    allf, kept, outside = _sorted_patches(vv, allf, new, weight, nonzero)
    sheets = None if cancelled is None else np.vstack([cancelled, allf[outside]])
    dropped = int(np.count_nonzero(~kept))
    allf = allf[kept]
    if sheets is not None:
        both = drop_unreferenced(vv, np.vstack([allf, sheets]))
        vv, allf, sheets = both[0], both[1][: len(allf)], both[1][len(allf) :]
    else:
        vv, allf = drop_unreferenced(vv, allf)
    return Mended(vv, allf, int(len(pairs)), int(len(bad)), dropped, sheets)


def _cancelled_copies(faces: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """One copy of each set of coincident faces that :func:`repair.clean.net_faces`
    dropped because their orientations cancel (``kept``: its indices)."""
    key = face_keys(faces)
    gone = np.ones(len(faces), dtype=bool)
    gone[kept] = False
    gone &= ~np.isin(key, key[kept])
    idx = np.flatnonzero(gone)
    _, first = unique_ints(key[idx], return_index=True)
    return faces[idx[first]]


def _angles_about(
    v: np.ndarray, edge: np.ndarray, third: np.ndarray
) -> np.ndarray | None:
    """The angle (radians) about the directed ``edge`` (two vertex indices) of each
    face's ``third`` corner (vertex indices), from the first's; None where a face has
    collapsed onto the edge (a repeated corner, or its third corner exactly on the
    edge's line: it has no side of the edge) or the edge onto a point: no angle."""
    a, b = edge
    if a == b or np.any((third == a) | (third == b)):
        return None
    axis = v[b] - v[a]
    axis /= np.linalg.norm(axis)
    d = v[third] - v[a]
    if np.any(np.all(np.cross(d, axis) == 0, axis=1)):
        return None
    x = d[0] - axis * np.dot(d[0], axis)
    x /= np.linalg.norm(x)
    y = np.cross(axis, x)
    return np.arctan2(d @ y, d @ x)


def separate_singular_edges(
    vertices: np.ndarray, faces: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Where a closed, consistently oriented surface touches itself along an edge (2k
    faces on it: k wedges of solid meeting there), give each wedge its own copy of the
    edge's vertices, moved ``step`` mm into its own wedge -- a few float32 ulps, far below
    what a printer resolves, so the parts still print as one, but the written surface is
    edge-manifold. Faces keep their vertices elsewhere; nothing else moves.

    Returns ``(vertices, faces, edges separated)``, or None where the faces around an
    edge do not alternate in orientation (not wedges of one closed solid) or one of them
    has collapsed onto it (its third corner exactly on the edge's line: no side)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    he, eid = half_edges(f), edge_ids(f)[0]
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
        ang = _angles_about(v, he[hs[0]], third[hs])
        if ang is None:
            # A face collapsed onto the edge (a repeated corner) has no side of it: which
            # wedges its neighbours bound is undefined (its angle was NaN, or 0, and the
            # wedges were paired by face order), so none are separated here.
            return None
        a = he[hs[0], 0]
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
    ids = split_vertex_fans(f, np.zeros(3 * len(f), dtype=bool), eid)
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
