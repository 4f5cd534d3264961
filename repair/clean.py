"""Stage 1 of the repair (Attene Sec. 4.1): from an STL triangle soup to one regular layer.

Units are mm. Arrays: vertices float64 (n, 3), faces int64 (m, 3), segments float64
(k, 2, 3). Every function is vectorised; the only per-item Python work is the exact
collinearity test of the few faces whose floating-point cross product cannot decide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.check import Printability, degenerate_face_mask
from repair.halves import split_copies
from repair.rows import unique_ints, unique_rows
from repair.topology import (
    connected_labels,
    edge_components,
    face_keys,
    half_edges,
    unique_faces,
    weld_exact,
)

__all__ = [
    "Cleaned",
    "cancel_opposite_faces",
    "clean_checked",
    "clean_soup",
    "degenerate_mask",
    "drop_unreferenced",
    "hanging_needles",
    "needle_mask",
    "net_faces",
    "orient_needles",
    "split_at_fillers",
    "split_copies",
]

#: A face is flat at float32 resolution when its height over its longest side is under
#: this many float32 ulps of its largest coordinate (a CAD export's midpoint rounded).
NEEDLE_ULPS = 4.0


def degenerate_mask(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with a repeated vertex index or exactly collinear corners (exact predicate)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    return degenerate_face_mask(vertices, faces)


def needle_mask(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces flat at float32 resolution (bool per face): the height over the longest
    side is under :data:`NEEDLE_ULPS` float32 ulps of the largest corner coordinate (mm).
    A zero-area triangle whose corners were rounded to float32 is one; a face of a
    tessellation, however thin, is thousands of ulps high."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    p = np.asarray(vertices, dtype=np.float64)[faces]  # (m, 3, 3)
    sides = p[:, [1, 2, 0]] - p
    longest = np.sqrt(np.einsum("mkd,mkd->mk", sides, sides).max(axis=1))
    twice_area = np.linalg.norm(np.cross(sides[:, 0], sides[:, 2]), axis=1)
    ulp = np.spacing(np.abs(p).max(axis=(1, 2)).astype(np.float32)).astype(np.float64)
    return twice_area < NEEDLE_ULPS * ulp * np.maximum(longest, 1e-300)


def hanging_needles(
    vertices: np.ndarray, faces: np.ndarray, flat: np.ndarray | None = None
) -> np.ndarray:
    """The faces flat at float32 resolution (:func:`needle_mask`) that hang off the
    surface: each group of them none of whose edges exactly one face outside the group
    uses -- dropping it opens no edge, and a zero-area group adds nothing printable (a
    needle on an edge the surface already closes, or a needle itself split at a point).
    Needles are grouped across the edges no other face uses (a fan's inner edges): a
    sliver added on an edge that an exporter's own needle shares with the surface is
    a group of its own. A group that closes a crack (a T-junction's filler: an edge it
    shares with one other face) stays: :func:`split_at_fillers`. ``flat``:
    :func:`needle_mask`, if known. Returns a bool mask per face."""
    flat = needle_mask(vertices, faces) if flat is None else flat
    if not np.any(flat):
        return flat
    f = np.asarray(faces, dtype=np.int64)
    n = int(f.max()) + 1
    e = np.sort(half_edges(f), axis=1)
    key = (e[:, 0] * n + e[:, 1]).reshape(-1, 3)
    idx = np.flatnonzero(flat)
    mine = key[idx].reshape(-1)
    alone = _edge_uses(key[~flat].reshape(-1), mine) == 0
    # Needles joined across edges only needles use.
    order = np.argsort(mine, kind="stable")
    same = np.flatnonzero((mine[order][1:] == mine[order][:-1]) & alone[order][1:])
    group = connected_labels(len(idx), order[same] // 3, order[same + 1] // 3)
    # Uses of each needle edge by faces outside its group: all uses, less the group's.
    g3 = np.repeat(group, 3)
    inside = unique_ints(g3 * (int(mine.max()) + 1) + mine, return_inverse=True)[1]
    outside = _edge_uses(key.reshape(-1), mine) - np.bincount(inside)[inside]
    once = (outside == 1).reshape(-1, 3)
    opens = np.bincount(group, weights=once.any(axis=1), minlength=int(group.max()) + 1)
    out = np.zeros(len(f), dtype=bool)
    out[idx[opens[group] == 0]] = True
    return out


def _edge_uses(keys: np.ndarray, of: np.ndarray) -> np.ndarray:
    """How many times each key of ``of`` occurs in ``keys``."""
    k = np.sort(keys)
    return np.searchsorted(k, of, "right") - np.searchsorted(k, of, "left")


def split_at_fillers(
    vertices: np.ndarray, faces: np.ndarray, flat: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """Faces with each T-junction filler replaced by the split it stands for, and how
    many filler faces were (:func:`_split_once`, repeated while it splits: a neighbour
    with fillers on two or three of its edges is split at one per round, the next
    round finds the next one on the piece that keeps that edge; at most three)."""
    f = np.asarray(faces, dtype=np.int64)
    f, total = _split_once(vertices, f, flat)
    for _ in range(2):
        if not total or not np.any(flat := needle_mask(vertices, f)):
            break
        f, k = _split_once(vertices, f, flat)
        if k == 0:
            break
        total += k
    return f, total


def _split_once(
    vertices: np.ndarray, faces: np.ndarray, flat: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """Faces with each T-junction filler replaced by the split it stands for, and how
    many filler faces were.

    A filler is an edge-connected group of needles (``flat``: :func:`needle_mask`) on
    points ``a, m1 .. mk, b`` of one line, ``k`` faces with ``k + 2`` boundary edges,
    ``a-b`` used by one other face and no inner edge used by another face: an exporter
    split a face at ``k`` points of its neighbour's edge ``a-b`` and closed the slit with
    zero-area triangles (one, or a fan; a side left open is a crack for the stitch). The
    neighbour across ``a-b`` is split at the points instead (one filler per neighbour,
    the first; the others wait for the next round), so both sides run through the same
    vertices and no zero-area face is left to the arrangement, which thickened it as a
    sheet (D = 0.2 mm) or refused.
    Whichever way the filler was written, the new faces keep the neighbour's orientation.
    No vertex moves: the surface is the same point set. Replaced faces go, the new ones
    are appended."""
    f = np.asarray(faces, dtype=np.int64)
    flat = needle_mask(vertices, f) if flat is None else flat
    idx = np.flatnonzero(flat)
    if len(idx) == 0:
        return f, 0
    v = np.asarray(vertices, dtype=np.float64)
    n = int(f.max()) + 1
    key = np.sort(half_edges(f), axis=1)
    key = key[:, 0] * n + key[:, 1]
    surface = np.repeat(~flat, 3)
    mine = key.reshape(-1, 3)[idx].reshape(-1)
    inner = _edge_uses(key[~surface], mine) > 1  # an edge two needles of a group share
    used = _edge_uses(key[surface], mine)
    group = edge_components(f[idx])
    g3 = np.repeat(group, 3)
    # A group qualifies when no surface face uses its inner edges and it is a
    # triangulated polygon: k faces, k + 2 boundary edges, k + 2 vertices.
    bad = inner & (used != 0)
    n_groups = int(group.max()) + 1
    size = np.bincount(group, minlength=n_groups)
    rim = np.bincount(g3[~inner], minlength=n_groups)
    corners = unique_rows(np.stack([g3, f[idx].reshape(-1)], axis=1))
    verts = np.bincount(corners[:, 0], minlength=n_groups)
    # Its points must be apart (a side at float32 resolution would be a new needle).
    he = half_edges(f[idx])
    length = np.linalg.norm(v[he[:, 1]] - v[he[:, 0]], axis=1)
    ulp = np.spacing(np.float32(np.abs(v).max())).astype(np.float64)
    bad |= length < NEEDLE_ULPS * ulp
    ok = (np.bincount(g3[bad], minlength=n_groups) == 0) & (rim == size + 2) & (verts == size + 2)
    # Each group's long edge a-b: its longest boundary edge.
    cand = np.flatnonzero(~inner & ok[g3])
    cand = cand[np.lexsort((-length[cand], g3[cand]))]
    first = cand[np.r_[True, g3[cand][1:] != g3[cand][:-1]]] if len(cand) else cand
    first = first[used[first] == 1]
    # The surface half-edge on it: its face is the neighbour to split.
    on = np.flatnonzero(surface)
    order = on[np.argsort(key[on], kind="stable")]
    h = order[np.searchsorted(key[order], mine[first])]
    nb = h // 3
    one = np.unique(nb, return_index=True)[1]
    first, h, nb = first[one], h[one], nb[one]
    if len(nb) == 0:
        return f, 0
    k = h % 3
    g0, g1, d = f[nb, k], f[nb, (k + 1) % 3], f[nb, (k + 2) % 3]
    gid = g3[first]
    slot = np.full(n_groups, -1)
    slot[gid] = np.arange(len(gid))
    rim_e = np.flatnonzero(~inner & (slot[g3] >= 0))
    rim_rows = np.column_stack([slot[g3[rim_e]], np.sort(he[rim_e], axis=1)])
    chain, s, fan_ok = _chains(v, corners[slot[corners[:, 0]] >= 0], slot, g0, g1, rim_rows)
    gid, nb = gid[fan_ok], nb[fan_ok]
    fan = np.column_stack([chain, d[s]])
    drop = np.zeros(len(f), dtype=bool)
    drop[nb] = True
    drop[idx[np.isin(group, gid)]] = True
    return np.vstack([f[~drop], fan]), int(np.count_nonzero(np.isin(group, gid)))


def _chains(
    v: np.ndarray, pts: np.ndarray, slot: np.ndarray, g0: np.ndarray, g1: np.ndarray,
    rim_rows: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chain ``g0 .. g1`` of each candidate filler: its corners (``pts``: rows (group,
    vertex)) ordered along the neighbour's edge ``g0-g1``, as consecutive pairs (k, 2)
    with their candidate (``slot`` of the group), and whether each candidate is a fan on
    that line (bool per candidate): every consecutive pair is a side of its rim
    (``rim_rows``: (candidate, lo, hi)). A group that also holds a needle off the chain
    (a sliver face of the surface 3e-5 mm wide, split by the same export, flat at float32
    resolution beside the fan) has a rim that doubles back along the line: it stays."""
    s = slot[pts[:, 0]]
    t = np.einsum("kd,kd->k", v[pts[:, 1]] - v[g0[s]], v[g1[s]] - v[g0[s]])
    order = np.lexsort((t, s))
    pts, s = pts[order], s[order]
    nxt = np.flatnonzero(s[1:] == s[:-1])
    chain, s = np.stack([pts[nxt, 1], pts[nxt + 1, 1]], axis=1), s[nxt]
    rows = np.vstack([rim_rows, np.column_stack([s, np.sort(chain, axis=1)])])
    inv = unique_rows(rows, return_inverse=True)[1]
    off = ~np.isin(inv[len(rim_rows):], inv[: len(rim_rows)])
    fan_ok = np.bincount(s[off], minlength=len(g0)) == 0
    keep = fan_ok[s]
    return chain[keep], s[keep], fan_ok


def orient_needles(
    vertices: np.ndarray, faces: np.ndarray, flat: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """Faces with each edge-connected group of needles (``flat``: :func:`needle_mask`)
    turned to match the faces around it, and how many were turned.

    A face flat at float32 resolution has no orientation of its own: an exporter's
    zero-area filler of a T-junction's slit, written the wrong way round, makes every
    edge it shares with the surface misoriented and the slit an inconsistent seam the
    stitch cannot close. A group is turned when more of its edges are used the same way
    than the opposite way by the other faces (ties stay), so that each edge it shares
    is then used once each way. No vertex moves: the surface is the same point set."""
    f = np.asarray(faces, dtype=np.int64)
    flat = needle_mask(vertices, f) if flat is None else flat
    idx = np.flatnonzero(flat)
    if len(idx) == 0:
        return f, 0
    group = edge_components(f[idx])
    n = int(f.max()) + 1
    he = half_edges(f)
    others = np.sort((he[:, 0] * n + he[:, 1])[np.repeat(~flat, 3)])
    mine = half_edges(f[idx])

    def used(key: np.ndarray) -> np.ndarray:
        return np.searchsorted(others, key, "right") - np.searchsorted(others, key, "left")

    score = used(mine[:, 0] * n + mine[:, 1]) - used(mine[:, 1] * n + mine[:, 0])
    turn = idx[np.bincount(np.repeat(group, 3), weights=score)[group] > 0]
    if len(turn) == 0:
        return f, 0
    out = f.copy()
    out[turn] = out[turn][:, ::-1]
    return out, len(turn)


def net_faces(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident faces by signed multiplicity.

    Faces on the same vertex set count +1 or -1 by orientation (relative to the first);
    a set whose copies cancel goes, otherwise one copy oriented like the sum stays, with
    the sum's size as its weight. Returns ``(sorted indices into faces, weight)``. A
    closed cycle of faces stays one when each kept face counts ``weight`` times.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    _, first, inv = unique_ints(face_keys(f), return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    # Orientation parity: a face and its sorted row are related by an even or odd
    # permutation.
    par = _even_permutation(f)
    sign = np.where(par == par[first][inv], 1, -1)
    total = np.bincount(inv, weights=sign).astype(np.int64)
    # Among each surviving group keep one face whose sign matches the sum.
    cand = np.flatnonzero((total[inv] != 0) & ((sign > 0) == (total[inv] > 0)))
    _, one = unique_ints(inv[cand], return_index=True)
    idx = np.sort(cand[one])
    return idx, np.abs(total[inv[idx]])


def cancel_opposite_faces(faces: np.ndarray) -> np.ndarray:
    """Sorted indices of the faces left when coincident faces of a *solid* cancel.

    Faces on the same vertex set count +1 or -1 by orientation (relative to the first);
    opposite pairs cancel (two solids touching, or a wedge collapsed flat) and one face is
    kept, with the sign of the sum, when it is non-zero (:func:`net_faces` without the
    weights). Unlike :func:`unique_faces`, this keeps a closed oriented surface closed.
    """
    if len(faces) < 2:
        return np.arange(len(faces))
    return net_faces(faces)[0]


def _even_permutation(faces: np.ndarray) -> np.ndarray:
    """True where the face's vertex order is an even permutation of its sorted order."""
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    # Rotations of (lo, mid, hi) are even: exactly one "descent" among the cyclic pairs.
    return ((a < b).astype(int) + (b < c) + (c < a)) == 2


def drop_unreferenced(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove vertices no face uses; faces are re-indexed (order preserved)."""
    if len(faces) == 0:
        return vertices[:0], faces.reshape(0, 3)
    f = np.asarray(faces, dtype=np.int64)
    mark = np.zeros(len(vertices), dtype=bool)
    mark[f.reshape(-1)] = True
    used = np.flatnonzero(mark)
    new_id = np.cumsum(mark) - 1  # no sort: vertex ids are dense
    return vertices[used], new_id[f].reshape(-1, 3)


def _not_on_edges(degenerate: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The degenerate faces whose segment is not an edge of ``faces`` (a collapsed
    triangle at the pole of a sphere spans an edge the surface already has: no wire)."""
    if len(degenerate) == 0 or len(faces) == 0:
        return degenerate
    # The segment of a collinear triangle joins its two outer corners; both of its other
    # sides lie on it too. It is a surface edge when all its distinct sides are.
    n = int(max(degenerate.max(), faces.max())) + 1
    e = np.sort(half_edges(faces), axis=1)
    surface = np.unique(e[:, 0] * n + e[:, 1])
    d = np.sort(half_edges(degenerate), axis=1)
    key = d[:, 0] * n + d[:, 1]
    on = np.isin(key, surface) | (d[:, 0] == d[:, 1])
    return degenerate[~on.reshape(-1, 3).all(axis=1)]


def _segments_of(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The segment spanned by each degenerate face: its two farthest corners.

    Faces collapsed to a point give no segment. Returns (k, 2, 3) float64.
    """
    if len(faces) == 0:
        return np.zeros((0, 2, 3))
    p = vertices[faces]  # (k, 3, 3)
    pairs = np.array([[0, 1], [1, 2], [2, 0]])
    d = np.linalg.norm(p[:, pairs[:, 0]] - p[:, pairs[:, 1]], axis=2)  # (k, 3)
    best = np.argmax(d, axis=1)
    seg = np.stack(
        [p[np.arange(len(p)), pairs[best, 0]], p[np.arange(len(p)), pairs[best, 1]]], axis=1
    )
    seg = seg[d[np.arange(len(p)), best] > 0]
    if len(seg) == 0:
        return np.zeros((0, 2, 3))
    # One copy of each segment, whatever its direction.
    a, b = seg[:, 0], seg[:, 1]
    flip = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (
        (a[:, 1] > b[:, 1]) | ((a[:, 1] == b[:, 1]) & (a[:, 2] > b[:, 2]))))
    seg[flip] = seg[flip][:, ::-1]
    _, first = unique_rows(seg.reshape(-1, 6), return_index=True)
    return seg[np.sort(first)]


@dataclass(frozen=True)
class Cleaned:
    """A regular, duplicate-free layer of an STL soup plus its degenerate faces as segments.

    ``vertices``/``faces``: welded (exactly coincident vertices merged), no unreferenced
    vertices. ``segments``: (k, 2, 3) mm, the wires the degenerate faces stood for.
    """

    vertices: np.ndarray
    faces: np.ndarray
    segments: np.ndarray
    degenerate_removed: int
    duplicates_removed: int


def clean_soup(vertices: np.ndarray, faces: np.ndarray, *, solid: bool = False) -> Cleaned:
    """Weld exactly equal vertices, move degenerate faces to segments, drop the needles
    flat at float32 resolution that hang off the surface (:func:`hanging_needles`), turn
    the others to match their neighbours (:func:`orient_needles`), keep one layer.

    With ``solid=True`` (closed oriented input) coincident faces cancel by orientation
    (:func:`cancel_opposite_faces`) instead, and flat faces are not dropped.
    """
    v, f = weld_exact(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    deg = degenerate_mask(v, f)
    segments = _segments_of(v, _not_on_edges(f[deg], f[~deg]))
    f = f[~deg]
    # An input's needles only: a solid's own clean (a union's result and prisms) keeps
    # its faces as the union made them.
    needles, split, repeated, halves = np.zeros(len(f), dtype=bool), 0, 0, 0
    if not solid:
        # Halves of a face written whole too go before a needle's filler splits one of
        # them again (a sliver written on a half's edge): then they are no pair.
        one = unique_faces(f)
        key = face_keys(f)
        early = np.isin(key, key[one[split_copies(v, f[one])]])  # with their repeats
        f, halves = f[~early], int(np.count_nonzero(early))
        flat = needle_mask(v, f)
        if np.any(flat):  # a needle written twice is one needle (a filler is one group)
            again = flat & ~np.isin(np.arange(len(f)), unique_ints(face_keys(f), True)[1])
            f, flat, repeated = f[~again], flat[~again], int(np.count_nonzero(again))
        needles = hanging_needles(v, f, flat)
        f, flat = f[~needles], flat[~needles]
        f, split = split_at_fillers(v, f, flat)
        f = orient_needles(v, f, needle_mask(v, f) if split else flat)[0]
    keep = cancel_opposite_faces(f) if solid else unique_faces(f)
    dup = len(f) - len(keep) + repeated + halves
    f = f[keep]
    if not solid:  # a face written whole and split too: one layer
        halves = split_copies(v, f)
        f, dup = f[~halves], dup + int(np.count_nonzero(halves))
    v, f = drop_unreferenced(v, f)
    removed = np.count_nonzero(deg) + np.count_nonzero(needles) + split
    return Cleaned(v, f, segments, int(removed), int(dup))


def clean_checked(vertices: np.ndarray, faces: np.ndarray, verdict: Printability) -> Cleaned:
    """:func:`clean_soup` of a mesh whose ``verdict`` was found on exactly these
    coordinates (``as_float32``, welded the same way): when that check found no
    degenerate and no duplicate face, no face is a needle (:func:`needle_mask`: one
    to drop, split at or turn) and none a half of a face written whole too
    (:func:`split_copies`, looked for when an edge has more than two faces), there is
    nothing to remove: the welded input is the
    cleaned input."""
    if verdict.degenerate_faces == 0 and verdict.duplicate_faces == 0:
        v, f = weld_exact(vertices, faces)
        if not np.any(needle_mask(v, f)) and not (
            verdict.nonmanifold_edges and np.any(split_copies(v, f))
        ):
            v, f = drop_unreferenced(v, f)
            return Cleaned(v, f, np.zeros((0, 2, 3)), 0, 0)
    return clean_soup(vertices, faces)
