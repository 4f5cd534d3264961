"""What a stitch leaves or meets that is not a crack (:mod:`repair.stitch`): flaps and
caps (an exporter's sliver on an edge, joined to both sides or cracked off with its
patch), faces the stitch made copies of others (a patch written twice, then cracked),
and edges of more than two faces that make a surface worse. Units are mm; vertices
float64 (n, 3), faces int64 (m, 3); vectorised numpy.
"""

from __future__ import annotations

import numpy as np

from repair.halves import split_copies
from repair.topology import EdgeTopology, edge_topology, half_edges, unique_faces

__all__ = ["one_layer", "unpaired_edges", "without_caps", "without_flaps"]


def unpaired_edges(t: EdgeTopology) -> int:
    """Edges of more than two faces that are not used as often one way as the other: an
    edge two solids share (two cubes touching along it, four faces, two each way) is a
    closed surface's edge, and a crack along it is stitched back into one."""
    if t.nonmanifold == 0:
        return 0
    he = half_edges(t.faces)
    way = np.bincount(t.eid, weights=np.where(he[:, 0] < he[:, 1], 1.0, -1.0),
                      minlength=len(t.counts))  # fmt: skip
    return int(np.count_nonzero((t.counts > 2) & (way != 0)))


def without_flaps(v: np.ndarray, f: np.ndarray, gamma: float) -> np.ndarray:
    """``f`` without its flaps: faces with two boundary edges and the third on more than
    two faces, no wider than ``gamma`` mm (the apex's distance from the line of the
    longest edge) -- an exporter's sliver on an edge (its apex on the edge, its other two
    edges the slit of a T-junction) that a stitch has joined to both sides of the edge.
    Its apex lies within ``gamma`` of the edge, as far as the stitch moves a point: a
    sliver cracked off with its patch (each corner moved by noise, cgal_cubes' shared
    edge 2e-5 mm wide) is one as much as a sliver up to the rounding of its coordinates."""
    t = edge_topology(f)
    count = t.counts[t.eid].reshape(-1, 3)
    cand = np.flatnonzero(((count == 1).sum(axis=1) == 2) & (count > 2).any(axis=1))
    if len(cand) == 0:
        return f
    p = v[f[cand]]
    twice_area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    longest = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2).max(axis=1)
    flap = cand[twice_area <= gamma * longest]
    return np.delete(f, flap, axis=0) if len(flap) else f


def one_layer(v: np.ndarray, f: np.ndarray, gamma: float = 0.0) -> np.ndarray:
    """``f`` with one layer where the stitch made faces copies of others: a patch
    written twice, then cracked, has its copies on different vertices until stitched;
    on the same ones, a face's repeat (same vertex set, either way round) and the
    halves of a face written whole too (:func:`repair.halves.split_copies`) go, as the
    clean drops them from an uncracked soup -- when that leaves fewer edges of more
    than two faces not used as often one way as the other, and no more open edges (a
    body written twice closer than the stitch distance, its copies joined face to
    face, stays two layers: the union makes one body of them). With ``gamma`` (mm), so
    does a repeat whose apex the stitch left apart (:func:`_loose_repeats`)."""
    t = edge_topology(f)
    if t.nonmanifold == 0:
        return f
    keep = unique_faces(f)
    g = f[keep] if len(keep) < len(f) else f
    if gamma > 0:
        loose = _loose_repeats(v, g, gamma)
        if loose.any():
            g = g[~loose]
    halves = split_copies(v, g, gamma)
    if halves.any():
        g = g[~halves]
    if g is f:
        return f
    tg = edge_topology(g)
    return g if tg.boundary <= t.boundary and unpaired_edges(tg) < unpaired_edges(t) else f


def _loose_repeats(v: np.ndarray, f: np.ndarray, gamma: float) -> np.ndarray:
    """Faces that repeat another but for their apex (bool per face): two open edges,
    the third shared, either way round, with a face whose opposite corner lies within
    ``gamma`` mm of the apex -- a face written again (or turned), cracked off alone
    with its own apex, which no rim of the surface met to snap it to."""
    t = edge_topology(f)
    count = t.counts[t.eid].reshape(-1, 3)
    out = np.zeros(len(f), dtype=bool)
    cand = np.flatnonzero(((count == 1).sum(axis=1) == 2) & (count > 2).any(axis=1))
    if len(cand) == 0:
        return out
    k = np.argmax(count[cand] > 2, axis=1)  # the shared edge's slot: from k to k+1
    a, b = f[cand, k], f[cand, (k + 1) % 3]
    apex = f[cand, (k + 2) % 3]
    n = int(f.max()) + 1
    he = np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)
    key = he.min(axis=1) * n + he.max(axis=1)
    order = np.argsort(key, kind="stable")
    want = np.minimum(a, b) * n + np.maximum(a, b)
    lo = np.searchsorted(key[order], want, "left")
    hi = np.searchsorted(key[order], want, "right")
    for j in range(int((hi - lo).max(initial=0))):  # the few faces on each edge
        has = lo + j < hi
        other = order[np.minimum(lo + j, len(order) - 1)] // 3
        opp = f[other, (order[np.minimum(lo + j, len(order) - 1)] % 3 + 2) % 3]
        near = np.linalg.norm(v[opp] - v[apex], axis=1) <= gamma
        out[cand[has & (other != cand) & near & ~out[other]]] = True
    return out


def without_caps(
    v: np.ndarray, f: np.ndarray, gamma: float, topology: EdgeTopology | None = None
) -> np.ndarray:
    """``f`` without its loose caps: faces no wider than ``gamma`` mm (the apex's
    distance from the longest edge) whose two shorter edges are open and each longer
    than ``gamma``, the apex a point of no other face -- an exporter's sliver (a,
    midpoint, b) on an edge, cracked off with its patch: its corners moved by noise
    made it a needle, no longer of zero area, hanging off its patch by the edge a-b.
    It made the patch one face more than its copy's (cgal_part written twice, slivers,
    a crack: no copy seen, 14 % of the volume). Dropping it moves no surface farther
    than ``gamma``. A needle with a short edge (a CAD step's genuine sliver face,
    3e-5 mm wide) is not a cap; nor is a face whose apex other faces use. ``topology``:
    that of ``f`` if known."""
    t = topology if topology is not None and topology.of(f) else edge_topology(f)
    open_edge = (t.counts[t.eid] == 1).reshape(-1, 3)
    cand = np.flatnonzero(open_edge.sum(axis=1) == 2)
    if len(cand) == 0:
        return f
    k = np.argmin(open_edge[cand], axis=1)  # the closed edge (k, k + 1); apex k + 2
    apex = f[cand, (k + 2) % 3]
    p = v[f[cand]]
    edge = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2)  # edge i: corners (i, i + 1)
    row = np.arange(len(cand))
    base = edge[row, k]
    short = np.minimum(edge[row, (k + 1) % 3], edge[row, (k + 2) % 3])
    twice_area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    alone = np.bincount(f.reshape(-1), minlength=len(v))[apex] == 1
    cap = alone & (short > gamma) & (base >= edge.max(axis=1)) & (twice_area <= gamma * base)
    return np.delete(f, cand[cap], axis=0) if cap.any() else f
