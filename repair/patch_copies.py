"""Which open patches of a cracked body written twice are the copy to drop, when the
faces copied between patches (corners within the stitch distance, turned the same way)
do not say it by patch order alone, and whether dropping them orphans a piece of the
copy (:func:`repair.union.duplicate_shells`). Patches
are labels of edge-connected faces; vectorised numpy but for a loop over the few
patches linked by copies.
"""

from __future__ import annotations

import numpy as np

from repair.topology import EdgeTopology, half_edges

__all__ = ["covered", "orphaned", "two_bodies"]

#: At most this many patches are split into two bodies (:func:`two_bodies`).
MAX_BODY_PATCHES = 64


def covered(pairs: np.ndarray, labels: np.ndarray, gone: np.ndarray) -> bool:
    """Whether every face of a dropped patch keeps a copy: ``pairs`` (k, 2) faces that
    are copies of each other, ``labels`` their patches, ``gone`` per patch."""
    pairs = np.vstack([pairs, pairs[:, ::-1]])
    kept = np.zeros(len(labels), dtype=bool)
    kept[pairs[~gone[labels[pairs[:, 1]]], 0]] = True
    return bool(np.all(kept[gone[labels]]))


def two_bodies(pairs: np.ndarray, labels: np.ndarray, is_open: np.ndarray) -> np.ndarray:
    """Per patch: whether it belongs to the copy of a body written twice, the patches
    linked by copied faces (``pairs`` (k, 2) faces, ``labels`` their patches) split in
    two bodies -- each patch, largest first, on the side away from the one it shares
    more faces with -- the side of the earliest patch kept. None is dropped unless each
    face dropped keeps a copy and the faces kept twice are fewer than those dropped."""
    n = len(is_open)
    none = np.zeros(n, dtype=bool)
    links = labels[pairs]
    links = links[links[:, 0] != links[:, 1]]
    ids = np.unique(links)
    if len(ids) > MAX_BODY_PATCHES:
        return none
    at = np.searchsorted(ids, links)
    w = np.zeros((len(ids), len(ids)))
    np.add.at(w, (at[:, 0], at[:, 1]), 1.0)
    w += w.T
    side = np.full(len(ids), -1)
    for p in np.argsort(-np.bincount(labels, minlength=n)[ids], kind="stable"):
        pull = [w[p, side == s].sum() for s in (0, 1)]
        side[p] = 0 if pull[1] > pull[0] else 1 if pull[0] > 0 else 0
    gone = none.copy()
    gone[ids] = side != side[0]  # ids sorted: the earliest patch's side stays
    twice = np.count_nonzero(~gone[links[:, 0]] & ~gone[links[:, 1]])
    once = np.count_nonzero(gone[links[:, 0]] != gone[links[:, 1]])
    ok = is_open[gone].all() and twice < once and covered(pairs, labels, gone)
    return gone if ok else none


def orphaned(
    v: np.ndarray, topology: EdgeTopology, gone: np.ndarray, twin: np.ndarray, gamma: float
) -> bool:
    """Whether dropping the patches ``gone`` (per label of ``topology``) would leave a
    piece of their copy behind: a kept patch with a rim point nearer (within ``gamma``
    mm) a dropped patch's rim point than any other kept patch's rim, and not that
    point's ``twin`` (its own point in the copy kept). A body cracked after it was
    written twice has cracks that cut its copies differently; only some of the copy's
    patches are copies, and the rest, stitched to the kept body, would fold over it."""
    from scipy.spatial import cKDTree

    bnd = np.flatnonzero(topology.counts[topology.eid] == 1)
    pts, first = np.unique(half_edges(topology.faces)[bnd].reshape(-1), return_index=True)
    lab = topology.shells[np.repeat(bnd, 2)[first] // 3]
    drop = gone[lab]
    if not drop.any() or drop.all():
        return False
    kept, lab_k = pts[~drop], lab[~drop]
    d_drop, near = cKDTree(v[pts[drop]]).query(v[kept], distance_upper_bound=gamma)
    k = min(16, len(kept))
    dk, nk = cKDTree(v[kept]).query(v[kept], k=k, distance_upper_bound=gamma)
    dk, nk = dk.reshape(len(kept), k), nk.reshape(len(kept), k)
    other = np.isfinite(dk) & (lab_k[np.minimum(nk, len(kept) - 1)] != lab_k[:, None])
    d_keep = np.where(other, dk, np.inf).min(axis=1)
    hit = np.isfinite(d_drop)
    own = np.zeros(len(kept), dtype=bool)
    own[hit] = twin[pts[drop][near[hit]]] == kept[hit]
    # A point of the copy kept is matched as _is_copy matches: its twin nearest once the
    # copy's mean shift is taken out (a CAD step's sliver 3e-5 mm wide, the copy moved
    # farther, has the twin of its other corner nearer).
    moved = np.flatnonzero(twin != np.arange(len(twin)))
    if len(moved):
        shift = (v[moved] - v[twin[moved]]).mean(axis=0)
        back = cKDTree(v[pts[drop]] - shift).query(v[kept], distance_upper_bound=gamma)[1]
        ok = hit & np.isin(kept, twin[moved]) & (back < np.count_nonzero(drop))
        own[ok] |= twin[pts[drop][back[ok]]] == kept[ok]
    return bool(np.any(hit & ~own & (d_drop < d_keep)))
