"""Does a ray leave a triangle soup without meeting any of its triangles? Asked many
times against the same triangles (the unbounded-cell search of :mod:`repair.hull`), so
the triangles are prepared once: each ray first drops, by the triangles' bounding
spheres, those its line passes far from (a few multiply-adds per triangle on
contiguous columns), and only the few left are tested exactly as before (Moller-Trumbore).

Units are mm; float64. Vectorised numpy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RayCaster", "ray_hits", "ray_hits_any"]

#: Bounding spheres are grown by this fraction of their radius (and the model's size
#: by a smaller one) so that rounding in the cull never drops a triangle the exact-as-
#: float test would hit (its tolerance grows a triangle by ~1e-9 of its edges).
_SPHERE_GROWTH = 1e-3


def ray_hits_any(origin: np.ndarray, direction: np.ndarray, tri: np.ndarray, skip: int) -> bool:
    """Does the ray hit any triangle of ``tri`` (k, 3, 3) but ``skip`` (an index into
    ``tri``, or -1)? Moller-Trumbore, vectorised; edge and vertex hits count as hits
    (conservative)."""
    hit = ray_hits(origin, np.reshape(direction, (1, 3)), tri)[0]
    if skip >= 0:
        hit[skip] = False
    return bool(hit.any())


def ray_hits(origin: np.ndarray, directions: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Which triangles of ``tri`` (k, 3, 3) each ray from ``origin`` along
    ``directions`` (r, 3) hits: (r, k) bool, as :func:`ray_hits_any` tests them."""
    # Column by column: np.cross and einsum cost more in set-up than in arithmetic on
    # the few triangles a ray is tested against (the same products and sums).
    x0, y0, z0 = tri[:, 0, 0], tri[:, 0, 1], tri[:, 0, 2]
    e1x, e1y, e1z = tri[:, 1, 0] - x0, tri[:, 1, 1] - y0, tri[:, 1, 2] - z0
    e2x, e2y, e2z = tri[:, 2, 0] - x0, tri[:, 2, 1] - y0, tri[:, 2, 2] - z0
    d = np.asarray(directions, dtype=np.float64)
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]
    hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    a = e1x * hx + e1y * hy + e1z * hz
    ok = np.abs(a) > 1e-300
    inv = np.divide(1.0, a, out=np.zeros_like(a), where=ok)
    sx, sy, sz = origin[0] - x0, origin[1] - y0, origin[2] - z0
    u = inv * (sx * hx + sy * hy + sz * hz)
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    w = inv * (qx * dx + qy * dy + qz * dz)
    t = inv * (e2x * qx + e2y * qy + e2z * qz)
    tol = 1e-9
    return ok & (u >= -tol) & (w >= -tol) & (u + w <= 1 + tol) & (t > 0)


class RayCaster:
    """Rays against the fixed triangles ``tri`` (k, 3, 3): :meth:`hits_any` answers as
    :func:`ray_hits_any` on all of them does, testing exactly only the triangles whose
    (grown) bounding sphere the ray meets."""

    def __init__(self, tri: np.ndarray) -> None:
        self.tri = np.asarray(tri, dtype=np.float64)
        centre = self.tri.mean(axis=1)
        radius = np.sqrt(((self.tri - centre[:, None]) ** 2).sum(axis=2).max(axis=1))
        size = float(np.abs(self.tri).max()) if len(self.tri) else 1.0
        self.cx, self.cy, self.cz = (np.ascontiguousarray(c) for c in centre.T)
        grown = radius * (1.0 + _SPHERE_GROWTH) + 1e-9 * size
        self.r2 = grown * grown
        self.radius = grown
        self.c2 = self.cx * self.cx + self.cy * self.cy + self.cz * self.cz
        # Rounding of the expanded distance: a few ulps of |c|^2 + |o|^2, o in the box.
        self.slack = 1e-9 * (self.c2 + 3.0 * size * size) + 1e-300

    def candidates(self, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Indices of the triangles whose grown bounding sphere meets the ray (unit
        ``direction``): ahead of the origin by more than minus the radius, and within
        the radius of its line. ``|c - o|^2 - ((c - o).d)^2`` is expanded so that every
        step is a scalar times a column; its rounding (a few ulps of ``|c|^2 + |o|^2``,
        the origin lying within the triangles' box) is covered by a margin of 1e-9 of
        that."""
        ox, oy, oz = (float(x) for x in origin)
        dx, dy, dz = (float(x) for x in direction)
        along = (self.cx * dx + self.cy * dy + self.cz * dz) - (ox * dx + oy * dy + oz * dz)
        ahead = along >= -self.radius
        dist2 = (
            self.c2 - 2.0 * (self.cx * ox + self.cy * oy + self.cz * oz)
            + (ox * ox + oy * oy + oz * oz) - along * along
        )  # fmt: skip
        return np.flatnonzero(ahead & (dist2 <= self.r2 + self.slack))

    def hits_any(self, origin: np.ndarray, direction: np.ndarray, skip: int) -> bool:
        """Does the ray (unit ``direction``) hit any triangle but ``skip``?"""
        near = self.candidates(origin, direction)
        near = near[near != skip]
        if len(near) == 0:
            return False
        return ray_hits_any(origin, direction, self.tri[near], -1)
