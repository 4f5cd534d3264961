"""Clean travel: routes that stay inside the part, and aligned seams.

A travel whose straight line would cross the layer's outline is routed inside the island
that holds both its ends: the shortest path through a visibility graph over the reflex
corners of the island shrunk by half a bead spacing (routes run along the external
perimeter's middle line, or further in). A leg between two corners is usable when it
crosses no edge of a fence just inside the outline (the outline shrunk and simplified by
an eighth of a bead: few edges, all inside the part); legs from the travel's own ends are
tested against the outline itself. Graphs are built lazily, once per island per layer, only
for islands a travel needs to cross; travels between islands, or islands too intricate for
a small graph, keep the straight line and count as leaving the part (the writer retracts).
So do travels between parts of an island joined only by a neck narrower than a bead (a
thin wall): the routes keep half a bead inside the outline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from manifold3d import CrossSection, JoinType

from slicer.geometry import contours, points_inside, polygon_edges, segments_cross

MAX_NODES = 120


@dataclass
class _Island:
    shape: CrossSection
    polys: list[np.ndarray]
    fence_a: np.ndarray | None = None  # edges of the outline shrunk and simplified within it
    fence_b: np.ndarray | None = None
    edge_a: np.ndarray | None = None  # the outline's own edges
    edge_b: np.ndarray | None = None
    nodes: np.ndarray | None = None  # (n, 2) graph corners
    dist: np.ndarray | None = None  # (n, n) shortest distances inside, inf: no way
    pred: np.ndarray | None = None  # (n, n) predecessor of j on the way from i


@dataclass(frozen=True)
class TravelPlan:
    """Per travel: waypoints between its ends (None: straight), whether it leaves the part,
    and its length along the route (mm)."""

    waypoints: list[np.ndarray | None]
    leaves: np.ndarray
    length: np.ndarray


def all_shortest_paths(legs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Floyd–Warshall over a dense symmetric matrix of leg lengths (0: no leg), one
    vectorised relaxation per corner (n ≤ MAX_NODES, so a few ms): (dist, pred) where
    dist[i, j] is the shortest way i → j (inf: none) and pred[i, j] the corner before j
    on it (-1: none). In numpy because importing scipy's graph module cost more CPU than all
    of a small model's routing."""
    n = len(legs)
    dist = np.where(legs > 0, legs, np.inf)
    np.fill_diagonal(dist, 0.0)
    pred = np.where(np.isfinite(dist), np.arange(n)[:, None], -1)
    np.fill_diagonal(pred, -1)
    for k in range(n):
        via = dist[:, k, None] + dist[None, k, :]
        better = via < dist
        if better.any():
            dist = np.where(better, via, dist)
            pred = np.where(better, pred[None, k, :], pred)
    return dist, pred


def _reflex_corners(polys: list[np.ndarray]) -> np.ndarray:
    """Corners where the region turns right (outer loops CCW, holes CW): shortest paths
    inside the region bend only there."""
    out = []
    for p in polys:
        e_in = p - np.roll(p, 1, axis=0)
        e_out = np.roll(p, -1, axis=0) - p
        out.append(p[e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0] < 0])
    return np.concatenate(out) if out else np.zeros((0, 2))


class TravelRouter:
    """Routes travels of one layer inside its cross-section ``section``."""

    def __init__(self, section: CrossSection, spacing: float) -> None:
        self.section = section
        self.spacing = spacing
        self._islands: list[_Island] | None = None
        self._polys = contours(section)
        self._a, self._b = polygon_edges(self._polys)
        # legs are tested against a "fence": the outline shrunk by τ and simplified within τ,
        # so it lies inside the outline with far fewer edges; a leg with both ends inside the
        # fence that crosses none of its edges stays inside the part
        tau = spacing / 4
        self._fence = contours(section.offset(-tau, JoinType.Miter).simplify(tau))
        self._fa, self._fb = polygon_edges(self._fence)

    def _all_islands(self) -> list[_Island]:
        if self._islands is None:
            self._islands = []
            for comp in self.section.decompose():
                self._islands.append(_Island(comp, contours(comp)))
        return self._islands

    def _graph(self, isl: _Island) -> None:
        s = self.spacing
        fence = contours(isl.shape.offset(-s / 8, JoinType.Miter).simplify(s / 8))
        isl.fence_a, isl.fence_b = polygon_edges(fence)
        if isl.edge_a is None:
            isl.edge_a, isl.edge_b = polygon_edges(isl.polys)
        # corners on the external perimeter's middle line (narrow necks stay passable),
        # kept only where they lie inside the fence
        shape = isl.shape.offset(-s / 2, JoinType.Miter)
        tol = s / 8
        nodes = _reflex_corners(contours(shape.simplify(tol)))
        while len(nodes) > MAX_NODES and tol < 8 * s:
            tol *= 2
            nodes = _reflex_corners(contours(shape.simplify(tol)))
        if len(nodes) > MAX_NODES:
            nodes = np.zeros((0, 2))
        nodes = nodes[points_inside(fence, nodes)] if len(nodes) else nodes
        n = len(nodes)
        legs = np.zeros((n, n))
        if n > 1:
            i, j = np.triu_indices(n, 1)
            length = np.hypot(*(nodes[j] - nodes[i]).T)
            length[segments_cross(nodes[i], nodes[j], isl.fence_a, isl.fence_b)] = 0.0
            legs[i, j] = length  # 0: no leg
            legs[j, i] = length
        # all pairs at once (n ≤ MAX_NODES): each route is then a few array look-ups
        isl.dist, isl.pred = all_shortest_paths(legs)
        isl.nodes = nodes

    def _route(self, isl: _Island, p: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        """Shortest inside route p → q: its inner waypoints (k, 2), or None if none."""
        if isl.nodes is None:
            self._graph(isl)
        nodes, n = isl.nodes, len(isl.nodes)
        if n == 0:
            return None
        ends = np.array([p, q])
        # the ends may lie nearer the outline than the fence: their legs are tested against
        # the outline itself
        see = ~segments_cross(np.repeat(ends, n, axis=0), np.tile(nodes, (2, 1)),
                              isl.edge_a, isl.edge_b).reshape(2, n)
        sa, sb = np.flatnonzero(see[0]), np.flatnonzero(see[1])
        if len(sa) == 0 or len(sb) == 0:
            return None
        da = np.hypot(*(nodes[sa] - p).T)
        db = np.hypot(*(nodes[sb] - q).T)
        total = da[:, None] + isl.dist[np.ix_(sa, sb)] + db[None, :]
        k = int(np.argmin(total))
        if not np.isfinite(total.flat[k]):
            return None
        first, last = int(sa[k // len(sb)]), int(sb[k % len(sb)])
        path = [last]
        while path[-1] != first:  # walk the predecessors back from the last corner
            path.append(int(isl.pred[first, path[-1]]))
        return nodes[path[::-1]]

    def plan(self, prev: np.ndarray, starts: np.ndarray, moving: np.ndarray) -> TravelPlan:
        """Routes for the travels prev[i] → starts[i] (only where ``moving``)."""
        m = len(prev)
        length = np.hypot(*(starts - prev).T)
        leaves = np.zeros(m, dtype=bool)
        waypoints: list[np.ndarray | None] = [None] * m
        todo = np.flatnonzero(moving)
        if len(todo) == 0 or len(self._a) == 0:
            return TravelPlan(waypoints, leaves, length)
        # ends inside the fence: testing the fence's few edges is enough; other travels
        # (to the skirt, along thin walls) are tested against the outline itself
        inside = points_inside(self._fence, np.concatenate([prev[todo], starts[todo]]),
                               edges=(self._fa, self._fb))
        fenced = inside[:len(todo)] & inside[len(todo):]
        hit = np.zeros(len(todo), dtype=bool)
        hit[fenced] = segments_cross(prev[todo[fenced]], starts[todo[fenced]], self._fa,
                                     self._fb)
        hit[~fenced] = segments_cross(prev[todo[~fenced]], starts[todo[~fenced]], self._a,
                                      self._b)
        crossing = todo[hit]
        if len(crossing) == 0:
            return TravelPlan(waypoints, leaves, length)
        leaves[crossing] = True
        islands = self._all_islands()
        where = np.full((len(crossing), 2), -1)
        for k, isl in enumerate(islands):
            if isl.edge_a is None:
                isl.edge_a, isl.edge_b = polygon_edges(isl.polys)
            inside = points_inside(isl.polys, np.concatenate([prev[crossing], starts[crossing]]),
                                   edges=(isl.edge_a, isl.edge_b))
            where[inside[:len(crossing)], 0] = k
            where[inside[len(crossing):], 1] = k
        for t, (i0, i1) in zip(crossing, where, strict=True):
            if i0 < 0 or i0 != i1:
                continue
            way = self._route(islands[i0], prev[t], starts[t])
            if way is None:
                continue
            pts = np.vstack([prev[t], way, starts[t]])
            waypoints[t] = way
            leaves[t] = False
            length[t] = float(np.hypot(*np.diff(pts, axis=0).T).sum())
        return TravelPlan(waypoints, leaves, length)


class SeamAligner:
    """``seam_position = aligned``: each external loop starts at the point of the loop nearest
    to a seam of the layer below (a new vertex where that falls inside an edge, so seams do
    not drift by a vertex per layer); on the first layer, at the sharpest concave corner, or
    else at the rear."""

    def __init__(self) -> None:
        self._below = np.zeros((0, 2))
        self._here: list[np.ndarray] = []

    def ring(self, loop: np.ndarray) -> np.ndarray:
        """The closed loop's points, starting and ending at its seam."""
        if len(self._below):
            a = loop
            d = np.roll(loop, -1, axis=0) - a
            rel = self._below[:, None, :] - a[None]  # (s, n, 2)
            t = np.clip((rel * d).sum(axis=2) / np.maximum((d * d).sum(axis=1), 1e-18), 0, 1)
            foot = a[None] + t[..., None] * d[None]
            gap = ((self._below[:, None, :] - foot) ** 2).sum(axis=2)
            s_best, k = np.unravel_index(int(np.argmin(gap)), gap.shape)
            seam = foot[s_best, k]
            ring = np.concatenate([[seam], loop[k + 1:], loop[:k + 1], [seam]])
        else:
            e_in = loop - np.roll(loop, 1, axis=0)
            e_out = np.roll(loop, -1, axis=0) - loop
            turn = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
            sharp = turn / np.maximum(np.hypot(*e_in.T) * np.hypot(*e_out.T), 1e-12)
            k = int(np.argmin(sharp)) if sharp.min() < -0.2 else \
                int(np.lexsort((loop[:, 0], -loop[:, 1]))[0])
            ring = np.concatenate([loop[k:], loop[:k + 1]])
        self._here.append(ring[0])
        return ring

    def next_layer(self) -> None:
        if self._here:
            self._below = np.array(self._here)
        self._here = []
