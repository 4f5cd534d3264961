"""Faces written twice, one copy split (a CAD export's patch written twice, one copy
of a face split at a point of its edge): the halves of a face also written whole, a
half whose twin is missing, two pairs of halves of one triangle. Each is the surface
written twice, of which one layer is kept. Vertices float (n, 3) mm, faces int (m, 3);
vectorised numpy (one sort of the half-edges).
"""

from __future__ import annotations

import numpy as np

from repair.topology import face_keys, half_edges

__all__ = ["split_copies"]


def _needle_mask(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    from repair.clean import needle_mask  # clean imports this module

    return needle_mask(v, f)


#: A piece's corner on its whole face's edge lies this far inside it at least (a share
#: of the edge): a CAD solid's sliver between corners 3e-5 mm apart is no piece.
_INSIDE = 0.01


def split_copies(vertices: np.ndarray, faces: np.ndarray, gamma: float = 0.0) -> np.ndarray:
    """Faces that are halves of a face also written whole (bool per face): two faces
    ``(a, m, c)`` and ``(m, b, c)`` sharing the edge ``m-c``, ``m`` between ``a`` and
    ``b`` on their line at float32 resolution (:func:`repair.clean.needle_mask` of ``(a, m, b)``),
    while a face on ``a, b, c`` exists -- a patch written twice, one copy of a face
    split at a point of its edge (each half then shares ``a-c`` or ``b-c`` with the
    whole face and its neighbour: an edge of three or more faces). They cover that
    face: the surface written twice, of which one layer is kept (the whole face, which
    its neighbour across ``a-b`` shares an edge with). So is a half whose twin is
    missing (:func:`_lone_halves`). With ``gamma`` (mm), ``m`` may lie up to ``gamma``
    off the line ``a-b``: a stitched crack's halves, whose midpoint moved by the crack
    had nothing to snap to."""
    v = np.asarray(vertices, dtype=np.float64)
    return _paired_halves(v, faces, gamma) | _lone_halves(v, faces)


def _paired_halves(vertices: np.ndarray, faces: np.ndarray, gamma: float = 0.0) -> np.ndarray:
    """The pairs of halves of :func:`split_copies` (bool per face)."""
    f = np.asarray(faces, dtype=np.int64)
    out = np.zeros(len(f), dtype=bool)
    if len(f) < 3:
        return out
    n = int(f.max()) + 1
    he = half_edges(f)
    key = np.sort(he, axis=1) @ np.array([n, 1])
    order = np.argsort(key, kind="stable")
    sk = key[order]
    start = np.r_[0, np.flatnonzero(sk[1:] != sk[:-1]) + 1]
    uses = np.diff(np.r_[start, len(sk)])
    # A face of an edge of three or more faces: the surface written twice there. So is
    # a face of an open edge, once its pair covers the same triangle as another pair.
    many = np.zeros(len(f), dtype=bool)
    many[order[np.repeat(uses, uses) > 2] // 3] = True
    rim = np.zeros(len(f), dtype=bool)
    rim[order[np.repeat(uses, uses) == 1] // 3] = True
    pair = np.flatnonzero(sk[1:] == sk[:-1])
    h1, h2 = order[pair], order[pair + 1]
    sel = many[h1 // 3] | many[h2 // 3] | (rim[h1 // 3] & rim[h2 // 3])
    h1, h2, many = h1[sel], h2[sel], many[h1[sel] // 3] | many[h2[sel] // 3]
    if len(h1) == 0:
        return out
    # The corner opposite each half-edge: the next corner after its end.
    corner = f.reshape(-1)
    a, b = corner[h1 - h1 % 3 + (h1 % 3 + 2) % 3], corner[h2 - h2 % 3 + (h2 % 3 + 2) % 3]
    whole = np.sort(face_keys(f, n))
    v = np.asarray(vertices, dtype=np.float64)
    alone = []  # (whole key, first face, second face) of pairs whose whole face is not
    for m, c in ((he[h1, 0], he[h1, 1]), (he[h1, 1], he[h1, 0])):
        on = (a != b) & (
            _needle_mask(v, np.stack([a, m, b], axis=1)) | _near_line(v, a, m, b, gamma)
        )
        on &= np.einsum("ij,ij->i", v[a] - v[m], v[b] - v[m]) < 0
        k = face_keys(np.stack([a, b, c], axis=1), n)
        hit = on & many & (whole[np.minimum(np.searchsorted(whole, k), len(whole) - 1)] == k)
        out[h1[hit] // 3] = out[h2[hit] // 3] = True
        alone.append(np.c_[k, h1 // 3, h2 // 3][on & ~hit])
    # A face written twice and each copy split at a different edge: two pairs of halves
    # of one triangle; the pair facing as its neighbours do stays, else the earlier.
    k, g1, g2 = np.vstack(alone).T
    if len(k) > 1:
        score = _facing(f, k, g1, g2, n)
        order = np.lexsort((np.minimum(g1, g2), -score, k))
        again = order[1:][k[order][1:] == k[order][:-1]]
        out[g1[again]] = out[g2[again]] = True
    return out


def _near_line(
    v: np.ndarray, a: np.ndarray, m: np.ndarray, b: np.ndarray, gamma: float
) -> np.ndarray:
    """Whether each point ``m`` lies within ``gamma`` (mm) of the line ``a-b`` (bool)."""
    if gamma <= 0:
        return np.zeros(len(m), dtype=bool)
    ab, am = v[b] - v[a], v[m] - v[a]
    cross = np.linalg.norm(np.cross(ab, am), axis=1)
    return cross <= gamma * np.linalg.norm(ab, axis=1)


def _facing(f: np.ndarray, k: np.ndarray, g1: np.ndarray, g2: np.ndarray, n: int) -> np.ndarray:
    """How well each pair of halves ``(g1, g2)`` of a triangle ``k`` written twice
    faces as the surface around it does: its half-edges the other faces use the other
    way minus those they use the same way (a copy written the wrong way round, split at
    a different edge, scores below its twin). The pairs of a triangle with more than
    one pair do not count for each other."""
    doubled = _repeated(k)
    mine = np.zeros(len(f), dtype=bool)
    mine[g1[doubled]] = mine[g2[doubled]] = True
    he = half_edges(f)
    others = np.sort((he[:, 0] * n + he[:, 1])[np.repeat(~mine, 3)])

    def used(key: np.ndarray) -> np.ndarray:
        return np.searchsorted(others, key, "right") - np.searchsorted(others, key, "left")

    own = half_edges(f[np.stack([g1, g2], axis=1).reshape(-1)])
    per = used(own[:, 1] * n + own[:, 0]) - used(own[:, 0] * n + own[:, 1])
    return per.reshape(len(k), 6).sum(axis=1)


def _repeated(k: np.ndarray) -> np.ndarray:
    """Whether each key occurs more than once in ``k`` (bool per entry)."""
    _, inv, cnt = np.unique(k, return_inverse=True, return_counts=True)
    return cnt[inv.reshape(-1)] > 1


def _lone_halves(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Halves of a face written whole whose twin is missing (bool per face): a face
    ``(m, b, c)`` with two open edges, sharing ``b-c`` with a face on ``a, b, c``, ``m``
    on that face's edge ``a-b`` at float32 resolution and well inside it
    (:data:`_INSIDE`) -- the split copy of a face with a hole where the other half was.
    Neither face is flat (:func:`repair.clean.needle_mask`): a sliver's corners are all on one line.
    Dropping it opens no edge."""
    f = np.asarray(faces, dtype=np.int64)
    out = np.zeros(len(f), dtype=bool)
    if len(f) < 3:
        return out
    he = half_edges(f)
    key = np.sort(he, axis=1) @ np.array([int(f.max()) + 1, 1])
    order = np.argsort(key, kind="stable")
    sk = key[order]
    lo = np.searchsorted(sk, key, "left")
    uses = np.searchsorted(sk, key, "right") - lo
    one = (uses == 1).reshape(-1, 3)
    cand = np.flatnonzero(one.sum(axis=1) == 2)
    h1 = cand * 3 + np.argmin(one[cand], axis=1)  # the piece's shared half-edge
    if len(h1) == 0:
        return out
    # Each other face on that edge as the whole one.
    k = uses[h1]
    row = np.repeat(np.arange(len(h1)), k)
    h2 = order[np.repeat(lo[h1], k) + np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)]
    h1 = h1[row]
    v = np.asarray(vertices, dtype=np.float64)
    flat = _needle_mask(v, f)
    sel = (h2 != h1) & ~flat[h1 // 3] & ~flat[h2 // 3]
    h1, h2 = h1[sel], h2[sel]
    # The corner opposite each half-edge: the next corner after its end.
    corner = f.reshape(-1)
    m, b = corner[h1 - h1 % 3 + (h1 % 3 + 2) % 3], corner[h2 - h2 % 3 + (h2 % 3 + 2) % 3]
    for a in he[h1].T:  # m between either end of the shared edge and b, not at one
        on = (m != b) & _needle_mask(v, np.stack([a, m, b], axis=1))
        t = np.einsum("ij,ij->i", v[m] - v[a], v[b] - v[a])
        t /= np.maximum(np.einsum("ij,ij->i", v[b] - v[a], v[b] - v[a]), 1e-300)
        out[h1[on & (t > _INSIDE) & (t < 1 - _INSIDE)] // 3] = True
    return out
