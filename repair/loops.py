"""Boundary (lamina) edges traced into loops: the first step of Bøhn & Wozny's shell
closure, shared by the hole closure (:mod:`repair.holes`) and the hairline-gap repair.

Units are mm. Arrays: faces int64 (m, 3). Pure functions; the edge bookkeeping is
vectorised, the only Python loop runs once per boundary vertex to trace loops (and once
per pinch vertex to turn round it).
"""

from __future__ import annotations

import numpy as np

from repair.topology import EdgeTopology, edge_topology, half_edges

__all__ = ["boundary_loops", "rim_half_edges", "traced_loops"]


def boundary_loops(faces: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Closed loops of boundary (lamina) edges, edges used by exactly one face, as Jordan
    curves (Bøhn & Wozny).

    Returns the loops, each an int64 array of vertex indices ordered *against* the rim
    faces' orientation (the order a lid needs to continue that orientation), and the face
    component label (edge-connected) of each loop's rim. Where several boundary edges
    meet at a vertex (two holes touching at a corner), each edge coming in is paired with
    the edge going out that is reached by turning round the vertex through its faces, and
    a closed walk through a vertex twice is split there into simple loops. Boundaries
    that cannot be paired so (edges of more than two faces, faces oriented against each
    other, as many edges in as out not met) give no loop: such a hole is left to the
    sheet thickening.
    """
    f = np.asarray(faces, dtype=np.int64)
    loops, labels, _ = traced_loops(f, edge_topology(f))
    return loops, labels


def rim_half_edges(f: np.ndarray, topology: EdgeTopology, singular: bool = False) -> np.ndarray:
    """The half-edges a hole's rim runs along: those of edges of one face; with
    ``singular``, also one of each edge of an odd number of faces (3, 5, ...) whose
    half-edges one way outnumber those the other way by one -- an edge of four faces
    (two solids sharing it) that lost one of them. ``topology``: that of ``f``."""
    eid, cnt = topology.eid, topology.counts
    bnd = np.flatnonzero(cnt[eid] == 1)
    if not singular or topology.nonmanifold == 0:
        return bnd
    he = half_edges(f)
    odd = (cnt[eid] >= 3) & (cnt[eid] % 2 == 1)
    if not odd.any():
        return bnd
    h = np.flatnonzero(odd)
    up = he[h, 0] < he[h, 1]
    fwd = np.bincount(eid[h], weights=up, minlength=len(cnt))
    net = 2 * fwd - cnt  # half-edges low->high minus high->low, per edge
    lone = h[np.abs(net[eid[h]]) == 1]
    lone = lone[(he[lone, 0] < he[lone, 1]) == (net[eid[lone]] > 0)]  # the majority way
    _, first = np.unique(eid[lone], return_index=True)
    return np.sort(np.r_[bnd, lone[first]])


def traced_loops(
    f: np.ndarray, topology: EdgeTopology, singular: bool = False
) -> tuple[list[np.ndarray], np.ndarray, list[np.ndarray]]:
    """:func:`boundary_loops`, plus each loop's rim faces (one per loop edge);
    ``topology``: that of ``f``; ``singular``: a hole of three edges may run along an
    edge of an odd number of faces too (:func:`rim_half_edges`)."""
    if len(f) == 0:
        return [], np.zeros(0, dtype=np.int64), []
    he = half_edges(f)  # (3m, 2) a->b
    eid, cnt = topology.eid, topology.counts
    bnd = rim_half_edges(f, topology, singular)
    if len(bnd) == 0:
        return [], np.zeros(0, dtype=np.int64), []
    comp = topology.shells
    # A lid edge runs b->a for the rim's a->b.
    src, dst = he[bnd, 1], he[bnd, 0]
    succ = _lid_successors(f, he, eid, cnt, bnd, src, dst)
    loops: list[np.ndarray] = []
    labels: list[int] = []
    rims: list[np.ndarray] = []
    seen = np.zeros(len(bnd), dtype=bool)
    succ_list = succ.tolist()
    for start in range(len(bnd)):
        if seen[start] or succ_list[start] < 0:
            continue
        walk = [start]
        seen[start] = True
        cur = succ_list[start]
        while cur != start and cur >= 0 and not seen[cur]:
            seen[cur] = True
            walk.append(cur)
            cur = succ_list[cur]
        if cur != start:
            continue  # an open chain: not a Jordan curve
        for loop in _simple_loops(src[walk].tolist(), walk):
            if singular and len(loop) > 3 and (cnt[eid[bnd[loop]]] > 1).any():
                continue  # along a shared edge only a missing triangle: a lid is sure
            loops.append(src[loop])
            rims.append(bnd[loop] // 3)
            labels.append(int(comp[bnd[start] // 3]))
    return loops, np.asarray(labels, dtype=np.int64), rims


def _lid_successors(
    f: np.ndarray, he: np.ndarray, eid: np.ndarray, cnt: np.ndarray, bnd: np.ndarray,
    src: np.ndarray, dst: np.ndarray,
) -> np.ndarray:
    """For each lid edge (``src`` -> ``dst``, of rim half-edge ``bnd``): the lid edge that
    follows it, or -1. Unique where one lid edge leaves its end; at a vertex where several
    do, the one reached by turning round the vertex through its faces."""
    n = int(f.max()) + 1
    out_deg = np.bincount(src, minlength=n)
    in_deg = np.bincount(dst, minlength=n)
    leaving = np.full(n, -1)
    leaving[src] = np.arange(len(src))
    succ = np.where(out_deg[dst] == 1, leaving[dst], -1)
    succ[in_deg[dst] != out_deg[dst]] = -1
    pinch = np.flatnonzero((out_deg[dst] > 1) & (in_deg[dst] == out_deg[dst]))
    if len(pinch) == 0:
        return succ
    # Twins of the half-edges of edges with two faces oriented against each other.
    idx = np.arange(len(eid))
    first = np.empty(len(cnt), dtype=np.int64)
    first[eid[::-1]] = idx[::-1]
    last = np.empty(len(cnt), dtype=np.int64)
    last[eid] = idx
    twin = np.where(cnt[eid] == 2, np.where(first[eid] == idx, last[eid], first[eid]), -1)
    ok = twin >= 0
    ok[ok] = he[twin[ok], 0] == he[idx[ok], 1]
    twin[~ok] = -1
    lid_of = np.full(len(eid), -1)
    lid_of[bnd] = np.arange(len(bnd))
    for i in pinch.tolist():
        h = int(bnd[i])  # rim a->b starts at the pinch vertex a
        t = 3 * (h // 3) + (h % 3 + 2) % 3  # the half-edge of that face ending at a
        for _ in range(len(f)):
            if lid_of[t] >= 0:
                succ[i] = lid_of[t]
                break
            w = int(twin[t])
            if w < 0:
                break
            t = 3 * (w // 3) + (w % 3 + 2) % 3
    return succ


def _simple_loops(walk: list[int], edges: list[int]) -> list[list[int]]:
    """A closed walk of vertices (``walk``; ``edges[i]`` leaves ``walk[i]``) split at each
    vertex it passes twice into simple loops, given as their edges (those of fewer than
    three edges dropped)."""
    if len(set(walk)) == len(walk):
        return [edges] if len(edges) >= 3 else []
    loops: list[list[int]] = []
    stack: list[int] = []  # positions in the walk
    where: dict[int, int] = {}
    for pos, vertex in enumerate(walk):
        if vertex in where:
            i = where[vertex]
            loops.append([edges[p] for p in stack[i:]])
            for p in stack[i + 1 :]:
                del where[walk[p]]
            del stack[i:]
        where[vertex] = len(stack)
        stack.append(pos)
    loops.append([edges[p] for p in stack])
    return [lp for lp in loops if len(lp) >= 3]
