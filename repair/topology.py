"""Combinatorial topology of triangle meshes: exact vertex welds, edges and half-edges,
edge census, faces on the same vertex set, and connected components.

Conventions used throughout repair:

- ``faces`` is (m, 3) int64. Half-edge ``3f + k`` runs from corner ``k`` of face ``f``
  to corner ``k + 1`` (mod 3); :func:`half_edges` gives them as a (3m, 2) array.
- An *edge id* numbers the undirected edges ``(lo, hi)`` in lexicographic order; each
  half-edge gets the id of its edge (:func:`edge_ids`).
- Components are labelled ``0..k-1`` in the order of their lowest member (what
  ``scipy.sparse.csgraph.connected_components`` gives), so any two ways of building the
  same partition give the same labels.

Everything is vectorised numpy. ``trimesh.grouping`` / ``trimesh.graph`` were
measured against it on a 1M-face torus: they are no faster (edge ids and face grouping
within noise, components and the exact weld slower) and number edges and groups in hash
order, where the repair's results depend on this module's defined orders. Units: mm.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import numpy as np

from repair.rows import sort_with_positions, unique_rows

__all__ = [
    "EdgeTopology",
    "connected_labels",
    "count_duplicate_faces",
    "edge_components",
    "edge_ids",
    "edge_neighbours",
    "edge_stats",
    "edge_topology",
    "edge_topology_memo",
    "face_keys",
    "half_edges",
    "is_cycle",
    "paired_half_edges",
    "split_vertex_fans",
    "undirected_edges",
    "unique_faces",
    "vertex_components",
    "weld_exact",
]


# --------------------------------------------------------------------------- vertex weld


def weld_exact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with exactly equal coordinates; faces are re-indexed, not dropped.

    ``vertices`` may be float64 or float32 (compared in their own precision, which is
    faster for STL data). Returns ``(unique_vertices float64, faces int64)``; the order of
    the unique vertices is unspecified. Units unchanged. ``-0.0`` and ``+0.0`` are the
    same coordinate.
    """
    src = np.asarray(vertices)
    dtype = np.float32 if src.dtype == np.float32 else np.float64
    # +0.0 and -0.0 are the same point: normalise (x + 0.0), then compare bit patterns.
    v = np.ascontiguousarray(src, dtype=dtype).reshape(-1, 3) + dtype(0.0)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(v) == 0:
        return v.astype(np.float64), f
    bits = v.view(np.uint32 if dtype == np.float32 else np.uint64)
    order, same_row = _rows_in_hash_order(bits, dtype == np.float32)
    new_group = np.r_[True, ~same_row]
    ids = np.cumsum(new_group) - 1
    remap = np.empty(len(v), dtype=np.int64)
    remap[order] = ids
    return v[order[new_group]].astype(np.float64), remap[f]


def _rows_in_hash_order(bits: np.ndarray, is_float32: bool) -> tuple[np.ndarray, np.ndarray]:
    """An order of the coordinate rows (their bit patterns, (n, 3)) in which equal rows are
    neighbours, and for each neighbour pair whether the rows are equal."""
    # Sort by a 64-bit hash of the three coordinates (one sort instead of a lexsort),
    # then verify: rows with equal hashes must be bit-identical, else fall back.
    b0, b1, b2 = (bits[:, i].astype(np.uint64) for i in range(3))
    h = b0 * np.uint64(0x9E3779B97F4A7C15)
    h ^= b1 * np.uint64(0xC2B2AE3D27D4EB4F) + (h >> np.uint64(29))
    h ^= b2 * np.uint64(0x165667B19E3779F9) + (h >> np.uint64(31))
    # Columns to verify equal hashes with (1-D gathers are much cheaper than 2-D ones).
    cols = ((b0 << np.uint64(32)) | b1, b2) if is_float32 else (b0, b1, b2)
    del b0, b1, b2
    # One plain sort of (hash high bits | index) instead of an argsort: several times
    # faster; a collision of the shortened hash only costs the exact fallback below.
    n = len(bits)
    shift = np.uint64(max(int(n).bit_length(), 1))
    packed = np.sort(((h >> shift) << shift) | np.arange(n, dtype=np.uint64))
    order = (packed & ((np.uint64(1) << shift) - np.uint64(1))).astype(np.int64)
    hs = packed >> shift
    del packed
    same_hash = hs[1:] == hs[:-1]
    del hs
    # Equal neighbours in hash order, compared exactly on all bits. Equal rows have equal
    # hashes, so they are neighbours unless a different row with the same hash sits
    # between them: then (equal hash, different row) shows up somewhere -> fall back.
    same_row = np.ones(n - 1, dtype=bool)
    for c in cols:
        cs = c[order]
        same_row &= cs[1:] == cs[:-1]
    del cols
    if np.any(same_hash & ~same_row):
        order = np.lexsort((bits[:, 2], bits[:, 1], bits[:, 0]))
        sb = bits[order]
        same_row = np.all(sb[1:] == sb[:-1], axis=1)
    return order, same_row


# --------------------------------------------------------------------------- edges


def half_edges(faces: np.ndarray) -> np.ndarray:
    """Directed half-edges (3m, 2) in face order: half-edge ``3f + k`` runs from corner
    ``k`` of face ``f`` to corner ``k + 1``."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    return np.stack([f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)], axis=1)


def _sorted_edge_keys(
    faces: np.ndarray, n_vertices: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, order, first, counts)``: each half-edge's start and end (3m,), the
    half-edges sorted by undirected edge (ties in half-edge order), where each edge's run
    starts in that order, and the run lengths (use count of each edge, in id order)."""
    a = faces.reshape(-1)
    b = faces[:, [1, 2, 0]].reshape(-1)
    key = np.minimum(a, b) * np.int64(max(n_vertices, 1)) + np.maximum(a, b)
    order, skey = sort_with_positions(key)
    first = np.r_[True, skey[1:] != skey[:-1]]
    counts = np.diff(np.r_[np.flatnonzero(first), len(skey)])
    return a, b, order, first, counts


def edge_ids(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The undirected edge id of each half-edge (3m,) -- edges numbered in ``(lo, hi)``
    order -- and each edge's use count (how many faces use it)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    known = _memoized(f)  # the same sort, done by edge_topology (copied: a caller may write)
    if known is not None:
        return known.eid.copy(), known.counts.copy()
    _, _, order, first, counts = _sorted_edge_keys(f, int(f.max()) + 1)
    eid = np.empty(len(order), dtype=np.int64)
    eid[order] = np.cumsum(first) - 1
    return eid, counts


def undirected_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The undirected edges (k, 2) ``lo < hi`` in lexicographic order and how many faces
    use each (``np.unique`` of the sorted half-edges, with counts)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64)
    a, b, order, first, counts = _sorted_edge_keys(f, int(f.max()) + 1)
    one = order[first]  # one half-edge of each edge, in edge id order
    return np.stack([np.minimum(a[one], b[one]), np.maximum(a[one], b[one])], axis=1), counts


def paired_half_edges(eid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the edges used by exactly two half-edges (``eid``: an edge id per half-edge):
    the first and the second of the two, in half-edge order. Also the use count of each
    half-edge's edge (3m,)."""
    eid = np.asarray(eid, dtype=np.int64)
    cnt = np.bincount(eid)
    order, se = sort_with_positions(eid)
    two = cnt[se] == 2
    first = np.r_[True, se[1:] != se[:-1]]
    starts = order[first & two]
    seconds = order[np.flatnonzero(first & two) + 1]
    return starts, seconds, cnt[eid]


@dataclass(frozen=True)
class EdgeTopology:
    """The edges and shells of one face array, from one sort of its edge keys
    (:func:`edge_topology`). A stage whose faces have not changed is handed this instead
    of sorting the same edges again; :meth:`of` says whether it describes given faces.

    ``eid``: undirected edge id per half-edge (3m,), as :func:`edge_ids`; ``counts``: the
    faces using each edge; ``shells``: edge-connected component per face (m,), as
    :func:`edge_components`; ``boundary``/``nonmanifold``/``misoriented``: edges used by
    one face, by more than two, by two in the same direction."""

    faces: np.ndarray
    eid: np.ndarray
    counts: np.ndarray
    shells: np.ndarray
    boundary: int
    nonmanifold: int
    misoriented: int

    @property
    def n_shells(self) -> int:
        return int(self.shells.max()) + 1 if len(self.shells) else 0

    def of(self, faces: np.ndarray) -> bool:
        """Whether these are the faces described (the same array, or equal ones)."""
        return faces is self.faces or (
            faces.shape == self.faces.shape and np.array_equal(faces, self.faces)
        )


#: The topologies found inside :func:`edge_topology_memo` (None outside one).
_MEMO: ContextVar[list[EdgeTopology] | None] = ContextVar("edge_topology_memo", default=None)
#: How many recent topologies the memo keeps.
_MEMO_SIZE = 4


@contextmanager
def edge_topology_memo() -> Iterator[None]:
    """Within this block :func:`edge_topology` sorts each face array once: a repair's
    stages ask again for faces an earlier one saw (the union's result is counted by the
    union, split into shells by the hull, counted again by the check). The last
    :data:`_MEMO_SIZE` topologies are kept, on private copies of their faces, their
    arrays read-only; nothing outlives the block."""
    token = _MEMO.set([])
    try:
        yield
    finally:
        _MEMO.reset(token)


def _memoized(f: np.ndarray) -> EdgeTopology | None:
    """The topology of the (m, 3) int64 faces ``f`` if :func:`edge_topology` found it
    inside the current :func:`edge_topology_memo`, else None (nothing is computed)."""
    for t in _MEMO.get() or ():
        if t.of(f):
            return t
    return None


def edge_topology(faces: np.ndarray) -> EdgeTopology:
    """The :class:`EdgeTopology` of ``faces`` (m, 3); inside :func:`edge_topology_memo`,
    the one found before for equal faces (read-only arrays)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    memo = _MEMO.get()
    if memo is None:
        return _edge_topology(f)
    known = _memoized(f)
    if known is not None:
        return known
    t = _edge_topology(f.copy())
    for a in (t.faces, t.eid, t.counts, t.shells):
        a.flags.writeable = False
    memo.append(t)
    del memo[:-_MEMO_SIZE]
    return t


def _edge_topology(f: np.ndarray) -> EdgeTopology:
    if len(f) == 0:
        none = np.zeros(0, dtype=np.int64)
        return EdgeTopology(f, none, none, none, 0, 0, 0)
    a, b, order, first, counts = _sorted_edge_keys(f, int(f.max()) + 1)
    eid = np.empty(len(order), dtype=np.int64)
    eid[order] = np.cumsum(first) - 1
    fwd = np.add.reduceat((a < b)[order].astype(np.int64), np.flatnonzero(first))
    # Edge-connected components: link each half-edge's face to the next use of the same
    # undirected edge (consecutive in the sorted order), then label the face graph.
    link = np.flatnonzero(~first)
    shells = connected_labels(len(f), order[link - 1] // 3, order[link] // 3)
    return EdgeTopology(
        f, eid, counts, shells,
        boundary=int(np.count_nonzero(counts == 1)),
        nonmanifold=int(np.count_nonzero(counts > 2)),
        misoriented=int(np.count_nonzero((counts == 2) & (fwd != 1))),
    )  # fmt: skip


def edge_stats(faces: np.ndarray) -> tuple[int, int, int, int, np.ndarray]:
    """``(boundary, nonmanifold, misoriented, shells, labels)``: undirected edges used by
    one face, by more than two, by two in the same direction; the number of
    edge-connected components (shells) and the label (int64, 0..k-1) of each face's."""
    t = edge_topology(faces)
    return t.boundary, t.nonmanifold, t.misoriented, t.n_shells, t.shells


def edge_components(faces: np.ndarray, eid: np.ndarray | None = None) -> np.ndarray:
    """Label (int64, 0..k-1) of the edge-connected component (shell) of each face: faces
    sharing an undirected edge, however many use it, are in one component. ``eid``: the
    :func:`edge_ids` of ``faces`` if known (then no sort is needed)."""
    if eid is None:
        return edge_stats(faces)[4]
    m = len(eid) // 3
    n_edges = int(eid.max()) + 1 if len(eid) else 0
    # Bipartite face-edge graph: faces 0..m-1, edges m..m+n_edges-1.
    return connected_labels(m + n_edges, np.repeat(np.arange(m), 3), m + eid)[:m]


def edge_neighbours(faces: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Sorted indices of the faces sharing an edge with a face in ``which`` (those
    included)."""
    eid, counts = edge_ids(faces)
    eid = eid.reshape(-1, 3)
    hit = np.zeros(len(counts), dtype=bool)
    hit[eid[which].reshape(-1)] = True
    return np.flatnonzero(hit[eid].any(axis=1))


def is_cycle(faces: np.ndarray) -> bool:
    """True when every undirected edge is traversed as often in one direction as in the
    other: the faces bound a region (a closed surface, perhaps touching itself), so
    winding numbers are well defined off it."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    known = _memoized(f)
    if known is not None:  # the check just sorted these edges: count on its edge ids
        a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
        sign = (a < b).astype(np.int64) - (a > b)  # a repeated corner adds nothing
        return bool(np.all(np.bincount(known.eid, weights=sign) == 0))
    he = half_edges(f)
    he = he[he[:, 0] != he[:, 1]]  # a face with a repeated corner adds nothing
    if len(he) == 0:
        return True
    _, inv = unique_rows(np.sort(he, axis=1), return_inverse=True)
    sign = np.where(he[:, 0] < he[:, 1], 1, -1)
    return bool(np.all(np.bincount(inv, weights=sign) == 0))


def split_vertex_fans(
    faces: np.ndarray, cut: np.ndarray, eid: np.ndarray | None = None
) -> np.ndarray:
    """Give every manifold fan of corners its own vertex: corners (3f+k) of two faces are
    merged across each edge not ``cut`` (bool per half-edge) that two consistently
    oriented faces share (``eid``: an edge id per half-edge, by default
    :func:`edge_ids`). Returns the new vertex id per corner (3m,) -- the split faces are
    ``ids.reshape(-1, 3)``."""
    m = len(faces)
    he = half_edges(faces)
    eid = edge_ids(faces)[0] if eid is None else eid
    h1, h2, _ = paired_half_edges(eid)
    ok = ~cut[h1] & ~cut[h2] & (he[h1, 0] == he[h2, 1])
    h1, h2 = h1[ok], h2[ok]
    nxt = np.array([1, 2, 0])
    # h1 runs a->b in face f1 (corners k1, k1+1); h2 runs b->a in f2 (corners k2, k2+1).
    c1a, c1b = h1, (h1 // 3) * 3 + nxt[h1 % 3]
    c2b, c2a = h2, (h2 // 3) * 3 + nxt[h2 % 3]
    return connected_labels(3 * m, np.r_[c1a, c1b], np.r_[c2a, c2b])


# --------------------------------------------------------------------------- faces


def face_keys(faces: np.ndarray, n_vertices: int | None = None) -> np.ndarray:
    """One sortable key per face, equal for faces on the same vertex set (any order).
    Keys of two face lists are comparable when both give the same ``n_vertices`` (more
    than any index, less than ``2**21``)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    s = np.sort(f, axis=1)
    n = int(s[:, 2].max()) + 1 if n_vertices is None else int(n_vertices)
    if n < 2**21:  # n**3 < 2**63
        return (s[:, 0] * n + s[:, 1]) * n + s[:, 2]
    return unique_rows(s, return_inverse=True)[1].reshape(-1).astype(np.int64)


def unique_faces(faces: np.ndarray) -> np.ndarray:
    """Sorted indices of the first face of each vertex set (either orientation).

    Keeping these leaves one *layer* of the soup (Attene Def. 3.1).
    """
    if len(faces) < 2:
        return np.arange(len(faces))
    order, sk = sort_with_positions(face_keys(faces))
    return np.sort(order[np.r_[True, sk[1:] != sk[:-1]]])


def count_duplicate_faces(faces: np.ndarray) -> int:
    """Faces on the same vertex set as an earlier face (any orientation)."""
    if len(faces) < 2:
        return 0
    sk = np.sort(face_keys(faces))
    return int(np.count_nonzero(sk[1:] == sk[:-1]))


# --------------------------------------------------------------------------- components


def connected_labels(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Component label (int64, 0..k-1, in order of each component's lowest node) of the
    nodes ``0..n-1`` of the undirected graph with edges ``a[i] -- b[i]``.

    Hooking and pointer jumping in numpy: each round hooks the root of every edge's
    larger end onto the smaller end's root, then compresses every node to its root, and
    drops the edges whose ends now share one. A root is always its component's lowest
    node, so the labels are those of ``scipy.sparse.csgraph.connected_components`` --
    without importing scipy.sparse (~0.5 s of a command-line repair's start-up).
    """
    parent = np.arange(n, dtype=np.int64)
    a = np.asarray(a, dtype=np.int64).reshape(-1)
    b = np.asarray(b, dtype=np.int64).reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    linked = lo != hi
    lo, hi = lo[linked], hi[linked]
    while len(lo):
        np.minimum.at(parent, hi, lo)  # hi is a root here: it now points lower
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
        ra, rb = parent[lo], parent[hi]
        apart = ra != rb
        lo, hi = np.minimum(ra[apart], rb[apart]), np.maximum(ra[apart], rb[apart])
    roots = parent == np.arange(n)
    return (np.cumsum(roots) - 1)[parent]


def vertex_components(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """Label (int64) of each vertex's component: vertices joined by the faces' edges
    (an unused vertex is a component of its own)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    return connected_labels(n_vertices, np.r_[f[:, 0], f[:, 1]], np.r_[f[:, 1], f[:, 2]])
