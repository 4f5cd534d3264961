"""Clean travel: routes that stay inside the part, and aligned seams.

A travel whose straight line would cross the layer's outline is routed inside the island
that holds both its ends: the shortest path through a visibility graph over the reflex
corners of the island shrunk by half a bead spacing (routes run along the external
perimeter's middle line, or further in). A leg between two corners is usable when it
crosses no edge of a fence just inside the outline (the outline shrunk and simplified by
an eighth of a bead: few edges, all inside the part); legs from the travel's own ends are
tested against the outline itself. The shortest way is an A* search that tests the legs from
a corner only when it reaches that corner (a route round one or two corners tests a few rows,
not all pairs). Corners are found lazily, once per island per layer, only for islands a
travel needs to cross; travels between islands, or islands too intricate for
a small graph, keep the straight line and count as leaving the part (the writer retracts).
So do travels between parts of an island joined only by a neck narrower than a bead (a
thin wall): the routes keep half a bead inside the outline.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from manifold3d import CrossSection, JoinType

from slicer.geometry import EdgeSet, contours, polygon_edges

MAX_NODES = 120
PLANS_KEPT = 16  # travel plans a router keeps for layers that repeat


@dataclass
class _Island:
    shape: CrossSection
    polys: list[np.ndarray]
    fence: EdgeSet | None = None  # edges of the outline shrunk and simplified within it
    edges: EdgeSet | None = None  # the outline's own edges
    nodes: np.ndarray | None = None  # (n, 2) graph corners
    legs: np.ndarray | None = None  # (n, n) leg lengths found so far (0: none or not yet)
    known: np.ndarray | None = None  # (n,) corners whose row of ``legs`` is complete


@dataclass(frozen=True)
class TravelPlan:
    """Per travel: waypoints between its ends (None: straight), whether it leaves the part,
    and its length along the route (mm)."""

    waypoints: list[np.ndarray | None]
    leaves: np.ndarray
    length: np.ndarray


def shortest_route(legs_from: Callable[[int], np.ndarray], start: np.ndarray,
                   finish: np.ndarray, guess: np.ndarray) -> tuple[list[int], float]:
    """A* from a virtual start to a virtual end over ``n`` corners: ``start[i]`` / ``finish[i]``
    is the leg start → corner i / corner i → end (inf: none), ``legs_from(i)`` the (n,) leg
    lengths from corner i (0: no leg), ``guess[i]`` a lower bound of corner i's way to the
    end (the straight distance). Returns the corners of the shortest way and its length
    (([], inf): none). Legs are asked for only at the corners the search settles, so a route
    round one or two corners tests a few rows of legs instead of all pairs."""
    g = np.asarray(start, dtype=np.float64).copy()
    n = len(g)
    pred = np.full(n, -1)
    done = np.zeros(n, dtype=bool)
    best, last = np.inf, -1
    rank = np.empty(n)
    while True:
        np.add(g, guess, out=rank)
        rank[done] = np.inf
        u = int(np.argmin(rank)) if n else 0
        if n == 0 or not rank[u] < best:  # nothing left that could beat the best way
            break
        done[u] = True
        if g[u] + finish[u] < best:
            best, last = g[u] + finish[u], u
        legs = legs_from(u)
        via = np.where(legs > 0, g[u] + legs, np.inf)
        better = (via < g) & ~done
        g[better] = via[better]
        pred[better] = u
    if last < 0:
        return [], np.inf
    path = [last]
    while pred[path[-1]] >= 0:
        path.append(int(pred[path[-1]]))
    return path[::-1], float(best)


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
        self._outline = EdgeSet(*polygon_edges(self._polys))
        # legs are tested against a "fence": the outline shrunk by τ and simplified within τ,
        # so it lies inside the outline with far fewer edges; a leg with both ends inside the
        # fence that crosses none of its edges stays inside the part
        tau = spacing / 4
        fence = contours(section.offset(-tau, JoinType.Miter).simplify(tau))
        self._fence = EdgeSet(*polygon_edges(fence))
        self._plans: dict[tuple[bytes, bytes, bytes], TravelPlan] = {}

    def _all_islands(self) -> list[_Island]:
        if self._islands is None:
            self._islands = []
            for comp in self.section.decompose():
                self._islands.append(_Island(comp, contours(comp)))
        return self._islands

    def _graph(self, isl: _Island) -> None:
        """The island's fence and corners; legs between corners are found as routes ask."""
        s = self.spacing
        fence = EdgeSet(*polygon_edges(
            contours(isl.shape.offset(-s / 8, JoinType.Miter).simplify(s / 8))))
        isl.fence = fence
        if isl.edges is None:
            isl.edges = EdgeSet(*polygon_edges(isl.polys))
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
        nodes = nodes[fence.contains(nodes)] if len(nodes) else nodes
        isl.nodes = nodes
        isl.legs = np.zeros((len(nodes), len(nodes)))
        isl.known = np.zeros(len(nodes), dtype=bool)

    def _legs_from(self, isl: _Island, i: int) -> np.ndarray:
        """Lengths of the legs from corner i to every corner (0: the leg leaves the fence),
        kept in the island for later routes. Each pair is tested lower corner first, so a
        leg's answer does not depend on which end asked."""
        if not isl.known[i]:
            nodes = isl.nodes
            other = np.arange(len(nodes))
            lo, hi = nodes[np.minimum(other, i)], nodes[np.maximum(other, i)]
            length = np.hypot(*(hi - lo).T)
            length[isl.fence.crossed_by(lo, hi)] = 0.0
            length[i] = 0.0
            isl.legs[i] = length
            isl.legs[:, i] = length
            isl.known[i] = True
        return isl.legs[i]

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
        see = ~isl.edges.crossed_by(np.repeat(ends, n, axis=0),
                                    np.tile(nodes, (2, 1))).reshape(2, n)
        if not see[0].any() or not see[1].any():
            return None
        to_q = np.hypot(*(nodes - q).T)
        start = np.where(see[0], np.hypot(*(nodes - p).T), np.inf)
        finish = np.where(see[1], to_q, np.inf)
        path, _ = shortest_route(lambda i: self._legs_from(isl, i), start, finish, to_q)
        return nodes[path] if path else None

    def plan(self, prev: np.ndarray, starts: np.ndarray, moving: np.ndarray) -> TravelPlan:
        """Routes for the travels prev[i] → starts[i] (only where ``moving``). The router
        serves a run of layers with the same section, and these repeat their travels (a
        prismatic part's layers alternate a few infill patterns): a plan is a pure function
        of the travels, so the same travels get the plan found before (read-only)."""
        key = (np.ascontiguousarray(prev, dtype=np.float64).tobytes(),
               np.ascontiguousarray(starts, dtype=np.float64).tobytes(),
               np.ascontiguousarray(moving, dtype=bool).tobytes())
        found = self._plans.get(key)
        if found is None:
            if len(self._plans) >= PLANS_KEPT:
                self._plans.clear()
            found = self._plans[key] = self._plan(prev, starts, moving)
        return found

    def _plan(self, prev: np.ndarray, starts: np.ndarray, moving: np.ndarray) -> TravelPlan:
        m = len(prev)
        length = np.hypot(*(starts - prev).T)
        leaves = np.zeros(m, dtype=bool)
        waypoints: list[np.ndarray | None] = [None] * m
        todo = np.flatnonzero(moving)
        if len(todo) == 0 or len(self._outline) == 0:
            return TravelPlan(waypoints, leaves, length)
        # ends inside the fence: testing the fence's few edges is enough; other travels
        # (to the skirt, along thin walls) are tested against the outline itself
        inside = self._fence.contains(np.concatenate([prev[todo], starts[todo]]))
        fenced = inside[:len(todo)] & inside[len(todo):]
        hit = np.zeros(len(todo), dtype=bool)
        hit[fenced] = self._fence.crossed_by(prev[todo[fenced]], starts[todo[fenced]])
        hit[~fenced] = self._outline.crossed_by(prev[todo[~fenced]], starts[todo[~fenced]])
        crossing = todo[hit]
        if len(crossing) == 0:
            return TravelPlan(waypoints, leaves, length)
        leaves[crossing] = True
        # only travels with both ends inside the outline can stay inside an island (those to
        # and from support and skirt cannot): the islands are looked at for these alone
        ends_in = self._outline.contains(np.concatenate([prev[crossing], starts[crossing]]))
        crossing = crossing[ends_in[:len(crossing)] & ends_in[len(crossing):]]
        if len(crossing) == 0:
            return TravelPlan(waypoints, leaves, length)
        islands = self._all_islands()
        where = np.full((len(crossing), 2), -1)
        for k, isl in enumerate(islands):
            if isl.edges is None:
                isl.edges = EdgeSet(*polygon_edges(isl.polys))
            inside = isl.edges.contains(np.concatenate([prev[crossing], starts[crossing]]))
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
