"""Geometry helpers for the slicer: placement, layer heights, slicing, 2-D hatching.

Units are mm. Heavy work is done by manifold3d (slicing, offsets, booleans) or vectorised
numpy (hatch-line clipping); nothing here loops over triangles or polygon vertices in Python.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from slicer.errors import SliceError


def bead_spacing(width: float, height: float) -> float:
    """Centre-to-centre distance of touching beads: w − h·(1 − π/4) (rounded-rectangle bead)."""
    return width - height * (1.0 - math.pi / 4.0)


def bead_area(width: float, height: float) -> float:
    """Cross-section of one bead, mm²: h·(w − h·(1 − π/4))."""
    return height * bead_spacing(width, height)


def merge_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weld bit-identical vertices (STL soup → indexed mesh, ``-0.0`` = ``+0.0``) with the
    repair's exact weld (:func:`repair.topology.weld_exact`), then drop the faces left
    with a repeated vertex."""
    from repair.topology import weld_exact

    v, f = weld_exact(np.asarray(vertices, dtype=np.float64), faces)
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return v, f[keep]


def place_on_bed(
    vertices: np.ndarray, build_volume: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Drop the model onto z = 0 and centre its bounding box on the bed.

    Returns (placed vertices, size xyz). Raises SliceError when the model is larger than the
    build volume; the message gives both sizes.
    """
    lo = vertices.min(axis=0)
    hi = vertices.max(axis=0)
    size = hi - lo
    bv = np.asarray(build_volume, dtype=np.float64)
    if np.any(size > bv + 1e-9):
        raise SliceError(
            "model is {:.1f} × {:.1f} × {:.1f} mm, larger than the build volume "
            "{:.0f} × {:.0f} × {:.0f} mm".format(*size, *bv)
        )
    shift = np.array([bv[0] / 2 - (lo[0] + hi[0]) / 2, bv[1] / 2 - (lo[1] + hi[1]) / 2, -lo[2]])
    return vertices + shift, size


def layer_tops(height: float, first_layer_height: float, layer_height: float) -> np.ndarray:
    """Top z of every layer (mm). Layer k is printed if its mid-plane lies below ``height``."""
    if height <= 0:
        return np.zeros(0)
    if first_layer_height / 2 >= height:
        return np.zeros(0)
    n_rest = int(math.floor((height - first_layer_height) / layer_height + 0.5 - 1e-9))
    n_rest = max(n_rest, 0)
    # the mid-plane of the last layer must still be inside the model
    while n_rest > 0 and first_layer_height + (n_rest - 0.5) * layer_height >= height:
        n_rest -= 1
    return first_layer_height + layer_height * np.arange(0, n_rest + 1, dtype=np.float64)


def contours(cs) -> list[np.ndarray]:
    """Contours of a CrossSection as float64 (n, 2) arrays (outer CCW, holes CW)."""
    return [np.asarray(p, dtype=np.float64) for p in cs.to_polygons() if len(p) >= 3]


def shape_key(cs) -> tuple[bytes, ...]:
    """A CrossSection's exact identity (its contours' bytes): equal keys, equal shapes. Layers
    of prismatic parts repeat, and what is planned for one serves them all."""
    return tuple(np.asarray(p).tobytes() for p in cs.to_polygons())


def shape_ids(sections: list) -> list[int]:
    """Per CrossSection, a small number naming its exact shape (equal shapes, equal
    numbers, in order of first appearance): layers compare by it without their contours."""
    ids: dict[tuple[bytes, ...], int] = {}
    return [ids.setdefault(shape_key(cs), len(ids)) for cs in sections]


def polygon_edges(polys: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """All edges of closed polygons as two (E, 2) arrays of start and end points."""
    if not polys:
        z = np.zeros((0, 2))
        return z, z
    a = np.concatenate(polys)
    counts = np.fromiter((len(p) for p in polys), dtype=np.int64, count=len(polys))
    ends = np.cumsum(counts)
    following = np.arange(1, len(a) + 1)
    following[ends - 1] = ends - counts  # each polygon's last corner closes to its first
    return a, a[following]


def hatch(
    polys: list[np.ndarray], angle_deg: float, spacing: float, phase: float = 0.0,
    min_length: float = 0.0,
) -> np.ndarray:
    """Clip the parallel lines ``y' = phase + k·spacing`` (in a frame rotated by ``angle_deg``)
    against the even-odd interior of ``polys``.

    Returns segments (k, 2, 2) in bed coordinates, sorted by scanline then position, every
    other scanline reversed (serpentine), so that consecutive segments are near each other.
    Vectorised: cost is O(edges + crossings) numpy work.
    """
    a, b = polygon_edges(polys)
    if len(a) == 0 or spacing <= 0:
        return np.zeros((0, 2, 2))
    th = math.radians(angle_deg)
    c, s = math.cos(th), math.sin(th)
    rot = np.array([[c, -s], [s, c]])  # columns: rotated-frame axes in bed coordinates
    ra = a @ rot
    rb = b @ rot
    y0, y1 = ra[:, 1], rb[:, 1]
    ylo = np.minimum(y0, y1)
    yhi = np.maximum(y0, y1)
    kmin = np.ceil((ylo - phase) / spacing).astype(np.int64)
    kmax = np.ceil((yhi - phase) / spacing).astype(np.int64) - 1  # half-open [ylo, yhi)
    count = np.maximum(kmax - kmin + 1, 0)
    total = int(count.sum())
    if total == 0:
        return np.zeros((0, 2, 2))
    edge = np.repeat(np.arange(len(a)), count)
    starts = np.cumsum(count) - count
    k = kmin[edge] + (np.arange(total) - np.repeat(starts, count))
    y = phase + k * spacing
    t = (y - y0[edge]) / (y1[edge] - y0[edge])
    x = ra[edge, 0] + t * (rb[edge, 0] - ra[edge, 0])
    order = np.lexsort((x, k))
    k = k[order]
    x = x[order]
    if len(k) % 2:  # numerically inconsistent input; drop the odd crossing out safely
        k = k[:-1]
        x = x[:-1]
    k0, k1 = k[0::2], k[1::2]
    x0, x1 = x[0::2], x[1::2]
    ok = (k0 == k1) & (x1 - x0 > max(min_length, 1e-6))
    k0, x0, x1 = k0[ok], x0[ok], x1[ok]
    yy = phase + k0 * spacing
    # serpentine: reverse direction on odd scanlines
    flip = (k0 % 2) == 1
    xs = np.where(flip, x1, x0)
    xe = np.where(flip, x0, x1)
    seg = np.empty((len(k0), 2, 2))
    seg[:, 0, 0], seg[:, 0, 1] = xs, yy
    seg[:, 1, 0], seg[:, 1, 1] = xe, yy
    return seg @ rot.T


class EdgeSet:
    """Edges a[j] → b[j] prepared once for many crossing and inside tests (a router tests the
    same outline and fence many times per layer): what depends on the edges alone is
    computed here, so each test is a few matrix products."""

    def __init__(self, a: np.ndarray, b: np.ndarray) -> None:
        self.a, self.b = a, b

    @cached_property
    def _sides(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The origin and the (3, m) factors of both orientation tests."""
        a, b = self.a, self.b
        origin = a[0]
        # coordinates relative to the first edge keep the products' size small
        ra, rb = a - origin, b - origin
        e = rb - ra
        one = np.ones(len(a))
        # cross(b - a, x - a) = ex·xy − ey·xx + (ey·ax − ex·ay), for x = p and x = q
        edge_side = np.stack([e[:, 0], -e[:, 1], e[:, 1] * ra[:, 0] - e[:, 0] * ra[:, 1]])
        return (origin, edge_side, np.stack([ra[:, 1], ra[:, 0], one]),
                np.stack([rb[:, 1], rb[:, 0], one]))

    @cached_property
    def _rows(self) -> tuple[np.ndarray, ...]:
        """The edges' ay, by, ax, bx − ax and by − ay as (1, m) rows."""
        a, b = self.a, self.b
        return (a[None, :, 1], b[None, :, 1], a[None, :, 0], b[None, :, 0] - a[None, :, 0],
                b[None, :, 1] - a[None, :, 1])

    def __len__(self) -> int:
        return len(self.a)

    def crossed_by(self, p: np.ndarray, q: np.ndarray, chunk: int = 2_000_000) -> np.ndarray:
        """For each segment p[i]→q[i], does it properly cross any edge? (bool (n,))."""
        n, m = len(p), len(self.a)
        out = np.zeros(n, dtype=bool)
        if n == 0 or m == 0:
            return out
        origin, edge_side, at, bt = self._sides
        p, q = p - origin, q - origin
        u = q - p
        # cross(q - p, y - p) = ux·yy − uy·yx + (uy·px − ux·py), for y = a and y = b
        seg_side = np.empty((n, 3))
        seg_side[:, 0] = u[:, 0]
        np.negative(u[:, 1], out=seg_side[:, 1])
        seg_side[:, 2] = u[:, 1] * p[:, 0] - u[:, 0] * p[:, 1]
        pt, qt = np.ones((n, 3)), np.ones((n, 3))  # the rows (y, x, 1) of both ends
        pt[:, :2] = p[:, ::-1]
        qt[:, :2] = q[:, ::-1]
        step = max(1, chunk // m)
        if step >= n:  # one chunk (the usual case): no slicing
            hit = (seg_side @ at) * (seg_side @ bt) < 0
            hit &= (pt @ edge_side) * (qt @ edge_side) < 0
            return hit.any(axis=1)
        for i0 in range(0, n, step):
            rows = slice(i0, i0 + step)
            hit = (seg_side[rows] @ at) * (seg_side[rows] @ bt) < 0
            hit &= (pt[rows] @ edge_side) * (qt[rows] @ edge_side) < 0
            out[rows] = hit.any(axis=1)
        return out

    def contains(self, pts: np.ndarray, chunk: int = 2_000_000) -> np.ndarray:
        """Even-odd test of points (k, 2) against the closed polygons these edges bound."""
        out = np.zeros(len(pts), dtype=bool)
        m = len(self.a)
        if m == 0 or len(pts) == 0:
            return out
        ay, by, ax, dx, dy = self._rows
        step = max(1, chunk // m)
        for i0 in range(0, len(pts), step):
            px = pts[i0:i0 + step, 0]
            py = pts[i0:i0 + step, 1]
            # a point's level crosses few edges: where its ray meets an edge is computed for
            # those pairs alone (the same arithmetic per pair as on the whole table)
            row, col = np.nonzero((ay > py[:, None]) != (by > py[:, None]))
            x_cross = ax[0, col] + (py[row] - ay[0, col]) * dx[0, col] / dy[0, col]
            crossings = np.bincount(row[px[row] < x_cross], minlength=len(px))
            out[i0:i0 + step] = (crossings % 2) == 1
        return out


def segments_cross(
    p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray, chunk: int = 2_000_000
) -> np.ndarray:
    """For each segment p[i]→q[i], does it properly cross any edge a[j]→b[j]? (bool (n,)).

    Both orientation tests are linear in the tested point, so each is one (n, 3) @ (3, m)
    matrix product (coordinates taken relative to the first edge, to keep their size small)
    instead of a dozen (n, m) temporaries."""
    return EdgeSet(a, b).crossed_by(p, q, chunk)


def points_inside(polys: list[np.ndarray], pts: np.ndarray, chunk: int = 2_000_000,
                  edges: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Even-odd test of points (k, 2) against closed polygons; bool (k,). Vectorised.
    ``edges``: the polygons' ``polygon_edges``, when the caller has them already."""
    return EdgeSet(*(polygon_edges(polys) if edges is None else edges)).contains(pts, chunk)
