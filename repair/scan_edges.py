"""The edge structure the scan cleanup (:mod:`repair.scan`) keeps up to date through
its steps: one sort of the half-edges at the start, then subsets and collapses renumber
edges without sorting again, and the cleaned faces' :class:`repair.topology.EdgeTopology`
is built from it for the stages after.

Arrays: faces int64 (m, 3); half-edge ``3f + k`` runs from corner ``k`` of face ``f`` to
corner ``k + 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.topology import EdgeTopology, edge_ids

__all__ = ["ScanEdges", "edge_pairs", "edge_topology_of"]


@dataclass(frozen=True)
class ScanEdges:
    """Edge structure of a face list, computed once (one sort): each half-edge's edge id
    ``eid`` (3m,), the edges' ends ``ends`` (k, 2), ``lo < hi``, numbered in that
    lexicographic order, and the edges of exactly two faces as their half-edges ``h1``,
    ``h2``."""

    eid: np.ndarray
    ends: np.ndarray
    h1: np.ndarray
    h2: np.ndarray

    @staticmethod
    def of(f: np.ndarray, topology: EdgeTopology | None = None) -> ScanEdges:
        if topology is not None and topology.of(f):
            eid, cnt = topology.eid, topology.counts
        else:
            eid, cnt = edge_ids(f)
        a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
        ends = np.empty((len(cnt), 2), dtype=np.int64)
        ends[eid, 0] = np.minimum(a, b)
        ends[eid, 1] = np.maximum(a, b)
        return ScanEdges(eid, ends, *edge_pairs(eid, cnt))

    def subset(self, keep: np.ndarray) -> ScanEdges:
        """The edges of the faces ``keep`` (bool per face) only, faces renumbered in
        order: edge ids stay (some edges now unused), pairs are taken again."""
        eid = self.eid.reshape(-1, 3)[keep].reshape(-1)
        cnt = np.bincount(eid, minlength=len(self.ends))
        return ScanEdges(eid, self.ends, *edge_pairs(eid, cnt))

    def collapsed(self, n: int, remap: np.ndarray, keep: np.ndarray) -> ScanEdges:
        """The edges of ``remap[f][keep]`` (vertices merged by ``remap``, the faces that
        lost a side dropped), as :meth:`of` would number them, without sorting them
        again: only the few edges at merged vertices get new ends; they are merged with
        the edges they now coincide with, and the used edges renumbered in order."""
        eid = self.eid.reshape(-1, 3)[keep].reshape(-1)
        used = np.bincount(eid, minlength=len(self.ends)) > 0
        moved = used & (remap[self.ends] != self.ends).any(axis=1)
        stay = np.flatnonzero(used & ~moved)
        stay_key = self.ends[stay, 0] * np.int64(n) + self.ends[stay, 1]  # ascending
        m_ends = np.sort(remap[self.ends[moved]], axis=1)
        m_key, m_inverse = np.unique(m_ends[:, 0] * np.int64(n) + m_ends[:, 1],
                                     return_inverse=True)  # fmt: skip
        at = np.minimum(np.searchsorted(stay_key, m_key), max(len(stay_key) - 1, 0))
        known = stay_key[at] == m_key if len(stay_key) else np.zeros(len(m_key), dtype=bool)
        added = m_key[~known]  # sorted: new edges between stay_key's
        new_id = np.full(len(self.ends), -1, dtype=np.int64)
        new_id[stay] = np.arange(len(stay)) + np.searchsorted(added, stay_key)
        m_id = np.empty(len(m_key), dtype=np.int64)
        m_id[known] = new_id[stay[at[known]]]
        m_id[~known] = np.arange(len(added)) + np.searchsorted(stay_key, added)
        new_id[np.flatnonzero(moved)] = m_id[m_inverse.reshape(-1)]
        ends = np.empty((len(stay) + len(added), 2), dtype=np.int64)
        ends[new_id[stay]] = self.ends[stay]
        ends[m_id[~known], 0], ends[m_id[~known], 1] = added // n, added % n
        eid = new_id[eid]
        return ScanEdges(eid, ends, *edge_pairs(eid, np.bincount(eid, minlength=len(ends))))

    def components(self) -> np.ndarray:
        """Edge-connected component of each face (faces sharing an edge, however many
        use it): each half-edge's face linked to the face of its edge's first half-edge,
        labelled by scipy's graph search (linear; the hooking of
        :func:`repair.topology.connected_labels` takes many rounds on a scan's long
        surface)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        m = len(self.eid) // 3
        idx = np.arange(len(self.eid))
        first = np.zeros(len(self.ends), dtype=np.int64)
        first[self.eid[::-1]] = idx[::-1]  # the last write wins: the smallest index
        graph = coo_matrix((np.ones(len(idx), dtype=np.int8), (idx // 3, first[self.eid] // 3)),
                           shape=(m, m))  # fmt: skip
        return connected_components(graph, directed=False)[1].astype(np.int64)


def edge_pairs(eid: np.ndarray, cnt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two half-edges of each edge of exactly two faces, without a sort: the first
    and the last half-edge of each edge, by two scatters."""
    idx = np.arange(len(eid))
    first = np.empty(len(cnt), dtype=np.int64)
    first[eid[::-1]] = idx[::-1]  # the last write wins: the smallest index
    last = np.empty(len(cnt), dtype=np.int64)
    last[eid] = idx
    two = np.flatnonzero(cnt == 2)
    return first[two], last[two]



def edge_topology_of(f: np.ndarray, e: ScanEdges, comp: np.ndarray) -> EdgeTopology:
    """The :func:`repair.topology.edge_topology` of ``f`` from its edges ``e`` (ids in
    lexicographic order, some unused) and its faces' components ``comp``: the used edges
    renumbered in order, the components in order of their first face."""
    counts = np.bincount(e.eid, minlength=len(e.ends))
    used = counts > 0
    eid = (np.cumsum(used) - 1)[e.eid]
    counts = counts[used]
    if len(comp):
        first = np.full(int(comp.max()) + 1, len(comp))
        first[comp[::-1]] = np.arange(len(comp))[::-1]  # the last write wins: the first face
        rank = np.zeros(len(first), dtype=np.int64)
        rank[np.argsort(first)] = np.arange(len(first))
        comp = rank[comp]
    a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
    forward = np.bincount(eid, weights=a < b, minlength=len(counts))
    return EdgeTopology(
        f, eid, counts, comp,
        boundary=int(np.count_nonzero(counts == 1)),
        nonmanifold=int(np.count_nonzero(counts > 2)),
        misoriented=int(np.count_nonzero((counts == 2) & (forward != 1))),
    )  # fmt: skip
