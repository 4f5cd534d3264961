"""Lids for the holes of a shell (Bøhn & Wozny's shell closure, the lid-making part).

A hole is a closed loop of boundary (lamina) edges, its vertices listed in *lid order*
(against the orientation of the faces round its rim, so a lid in that order continues the
shell's orientation; :func:`repair.loops.boundary_loops` traces them). Its lid is a
triangulation of the loop's own vertices, found by dynamic programming over the loop
(every triangulation of a polygon without new vertices is one split (i, m, j) and two
smaller polygons):

- a *planar* loop (all its vertices within a rounding tolerance of one plane) gets the
  triangulation that maximises the smallest angle among those whose triangles all face
  the way the loop turns -- a valid triangulation of the planar polygon, no new vertex,
  no crossing: an exactly planar hole gets an exact lid (Bøhn & Wozny eliminate the
  smallest angle and flip edges to raise the minimum angle; the max-min triangulation is
  the optimum that procedure heads for);
- any other loop gets the minimal-area triangulation (Barequet & Sharir, Liepa's hole
  filling weight without the dihedral term);
- a loop longer than :data:`MAX_DP_VERTICES` (the programme is cubic in its length) gets a
  fan from its centroid (one new vertex).

Units are mm. Arrays: vertices float64 (n, 3), loops int64 (k,). Vectorised over each
diagonal of the programme's table; the only Python loops run once per table diagonal and
once per lid triangle when the table is read back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_DP_VERTICES", "Lid", "loop_lid", "loop_planarity", "triangle_reach"]

#: Longest loop triangulated by the dynamic programme (O(k^3) work, k^2 memory).
MAX_DP_VERTICES = 160
#: A loop is planar when no vertex is further from its plane than this fraction of its
#: largest coordinate or its diameter, whichever is larger (float32 rounding is 6e-8).
PLANAR_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Lid:
    """One lid: its triangles (vertex indices; index ``n`` and up are the new vertices in
    ``new_vertices``), the loop's ``perimeter`` (mm), the lid's ``area`` (mm²), its
    ``planarity`` (mm: largest distance of a loop vertex from the loop's plane), whether it
    was made as a planar lid, and ``radius`` (mm): every lid point lies within it of a
    loop vertex, hence of the rim; ``faired``: refined and faired (:mod:`repair.fair`)."""

    triangles: np.ndarray
    new_vertices: np.ndarray
    perimeter: float
    area: float
    planarity: float
    planar: bool
    radius: float
    faired: bool = False

    def to_dict(self) -> dict[str, float | int | bool]:
        return {
            "vertices": int(len(np.unique(self.triangles))),
            "triangles": int(len(self.triangles)),
            "perimeter": round(float(self.perimeter), 9),
            "area": round(float(self.area), 9),
            "planarity": float(self.planarity),
            "planar": bool(self.planar),
            "faired": bool(self.faired),
            "new_vertices": int(len(self.new_vertices)),
        }


def loop_planarity(p: np.ndarray) -> tuple[float, np.ndarray, bool]:
    """``(planarity mm, unit normal, planar?)`` of a loop's points (k, 3) in lid order: the
    normal is Newell's (the direction the loop turns round, right-handed), the planarity
    the largest distance of a point from the plane through the centroid with that normal."""
    q = np.roll(p, -1, axis=0)
    newell = np.array([
        np.sum((p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2])),
        np.sum((p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0])),
        np.sum((p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])),
    ])  # fmt: skip
    size = float(np.linalg.norm(newell))
    if size == 0.0:
        return float("inf"), np.zeros(3), False
    n = newell / size
    dev = float(np.abs((p - p.mean(axis=0)) @ n).max())
    scale = max(float(np.abs(p).max()), float(np.ptp(p, axis=0).max()), 1e-12)
    return dev, n, dev <= PLANAR_TOLERANCE * scale


def _tri_measures(a: np.ndarray, b: np.ndarray, c: np.ndarray, normal: np.ndarray | None):
    """Area of triangles (…, 3) and a quality: with ``normal``, the smallest angle
    (radians) of triangles turning its way and -1 for the others; without, -area."""
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=-1)
    if normal is None:
        return area, -area
    ab = np.linalg.norm(b - a, axis=-1)
    bc = np.linalg.norm(c - b, axis=-1)
    ca = np.linalg.norm(a - c, axis=-1)
    longest = np.maximum(np.maximum(ab, bc), ca)
    # Smallest angle: opposite the shortest side; sin = 2 area / (product of the others).
    shortest = np.minimum(np.minimum(ab, bc), ca)
    others = np.maximum(ab * bc * ca / np.maximum(shortest, 1e-300), 1e-300)
    angle = np.arcsin(np.clip(2.0 * area / others, 0.0, 1.0))
    forward = (cr @ normal) > 1e-12 * np.maximum(longest, 1e-300) ** 2
    return area, np.where(forward, angle, -1.0)


#: Candidate triangles measured together by :func:`_gap_measures` (memory: ~100 bytes each).
_MEASURED_AT_ONCE = 1 << 16


def _gap_measures(p: np.ndarray, normal: np.ndarray | None):
    """For each gap 2..k-1 of the polygon ``p`` (k, 3), in order: ``(gap, area,
    quality)`` of the triangles (i, i + t, i + gap), rows i, columns t - 1
    (:func:`_tri_measures`) -- measured many gaps at a time, not one numpy pass each."""
    k = len(p)
    gaps = np.arange(2, k)
    n_gap = (k - gaps) * (gaps - 1)
    start = 0
    while start < len(gaps):
        stop = max(start + 1, int(np.searchsorted(np.cumsum(n_gap[start:]), _MEASURED_AT_ONCE,
                                                  side="right")) + start)  # fmt: skip
        at = np.r_[0, np.cumsum(n_gap[start:stop])]
        g = np.repeat(gaps[start:stop], n_gap[start:stop])
        local = np.arange(int(at[-1])) - np.repeat(at[:-1], n_gap[start:stop])
        i = local // (g - 1)
        m = i + 1 + local % (g - 1)
        area, quality = _tri_measures(p[i], p[m], p[i + g], normal)
        for row, gap in enumerate(gaps[start:stop].tolist()):
            shape = (k - gap, gap - 1)
            yield gap, area[at[row] : at[row + 1]].reshape(shape), quality[
                at[row] : at[row + 1]
            ].reshape(shape)
        start = stop


def _dp_triangulation(p: np.ndarray, normal: np.ndarray | None) -> np.ndarray | None:
    """Triangles (k-2, 3) of local indices 0..k-1: max-min angle among the forward
    triangulations (``normal`` given) or minimal area (``normal`` None). None when no
    triangulation avoids backward or zero-area triangles."""
    k = len(p)
    # best[i, j]: score of the sub-polygon i..j (higher is better); split[i, j]: its apex.
    best = np.full((k, k), -np.inf)
    idx = np.arange(k - 1)
    best[idx, idx + 1] = np.inf if normal is not None else 0.0
    split = np.zeros((k, k), dtype=np.int64)
    for gap, area, quality in _gap_measures(p, normal):
        i = np.arange(k - gap)
        j = i + gap
        m = i[:, None] + np.arange(1, gap)[None, :]
        left, right = best[i[:, None], m], best[m, j[:, None]]
        if normal is not None:
            score = np.minimum(np.minimum(left, right), quality)
            score = np.where(quality > 0, score, -np.inf)
        else:
            score = np.where(area > 0, left + right + quality, -np.inf)
        pick = np.argmax(score, axis=1)
        rows = np.arange(len(i))
        best[i, j] = score[rows, pick]
        split[i, j] = m[rows, pick]
    if best[0, k - 1] == -np.inf:
        return None
    tris = []
    stack = [(0, k - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        m = int(split[i, j])
        tris.append((i, m, j))
        stack.extend(((i, m), (m, j)))
    return np.asarray(tris, dtype=np.int64)


def triangle_reach(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Per triangle (rows of corners, mm): a bound on how far its points lie from its
    nearest corner -- the circumradius, or the longest edge where that is smaller."""
    ab, bc, ca = (np.linalg.norm(x, axis=1) for x in (b - a, c - b, a - c))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    with np.errstate(over="ignore"):  # a degenerate triangle's circumradius: inf
        circum = ab * bc * ca / np.maximum(4.0 * area, 1e-300)
    return np.minimum(circum, np.maximum(np.maximum(ab, bc), ca))


def _radius(p: np.ndarray, tris: np.ndarray) -> float:
    """:func:`triangle_reach`'s largest over the triangles ``tris`` of points ``p``."""
    return float(triangle_reach(p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]).max())


def loop_lid(vertices: np.ndarray, loop: np.ndarray, first_new: int) -> Lid:
    """The lid of one hole. ``loop``: vertex indices in lid order (at least 3);
    ``first_new``: the index a new vertex (a fan's centre) would get."""
    p = np.asarray(vertices, dtype=np.float64)[loop]
    k = len(loop)
    perimeter = float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())
    planarity, normal, planar = loop_planarity(p)
    local = None
    if k == 3:
        local = np.array([[0, 1, 2]], dtype=np.int64)
    elif k <= MAX_DP_VERTICES:
        if planar:
            local = _dp_triangulation(p, normal)
        planar = planar and local is not None
        if local is None:
            local = _dp_triangulation(p, None)
    if local is not None:
        tris = loop[local]
        pts, new = p, np.zeros((0, 3))
    else:  # a fan from the centroid
        planar = False
        centre = p.mean(axis=0)
        tris = np.stack([loop, np.roll(loop, -1), np.full(k, first_new)], axis=1)
        local = np.stack([np.arange(k), np.roll(np.arange(k), -1), np.full(k, k)], axis=1)
        pts, new = np.vstack([p, centre]), centre[None, :]
    a, b, c = pts[local[:, 0]], pts[local[:, 1]], pts[local[:, 2]]
    area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    return Lid(tris, new, perimeter, area, planarity, bool(planar), _radius(pts, local))
