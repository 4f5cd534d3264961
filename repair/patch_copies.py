"""Which open patches of a cracked body written twice are the copy to drop, when the
faces copied between patches (corners within the stitch distance, turned the same way)
do not say it by patch order alone (:func:`repair.union.duplicate_shells`). Patches
are labels of edge-connected faces; vectorised numpy but for a loop over the few
patches linked by copies.
"""

from __future__ import annotations

import numpy as np

__all__ = ["covered", "two_bodies"]

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
