"""Print orientation: which side of the model goes on the bed.

Candidates are "down" directions d (the model direction that will point at the bed): the
outward normals of the convex hull's largest flat faces, plus the six axis directions. Every
candidate is scored at once, as numpy arrays over faces × candidates, by a stated cost (mm²):

    cost = support + VISIBLE_WEIGHT·visible + HEIGHT_WEIGHT·area·height/diagonal
           − CONTACT_WEIGHT·contact + TIPPING_WEIGHT·area·tipping

- ``support``: area needing support, projected onto the bed: faces facing down more steeply
  than ``support_angle`` from vertical (normal within 90° − angle of straight down), except
  faces resting on the bed;
- ``visible``: the part of those faces on the outside of the model (on its convex hull),
  where support scars show;
- ``height``: the model's height in that orientation (taller prints take longer and wobble);
- ``contact``: area of flat faces resting on the bed (adhesion);
- ``tipping``: 0 while the height is at most twice the diameter of the base (the convex
  hull of what rests on the bed), rising to 1 at ten times: a ring stood on its edge or a
  pin on its end would wobble or come loose.

Modes: ``keep`` (as saved), ``auto`` (least cost), ``if-needed`` (the daemon's default: keep,
unless the saved orientation needs support and another one needs none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MODES = ("keep", "auto", "if-needed")
SUPPORT_ANGLE = 50.0  # degrees from vertical
VISIBLE_WEIGHT = 0.5
HEIGHT_WEIGHT = 0.05
CONTACT_WEIGHT = 0.25
TIPPING_WEIGHT = 0.1
HULL_CANDIDATES = 12
NO_SUPPORT_MM2 = 1.0  # below this much support area, an orientation "needs no support"


@dataclass(frozen=True)
class Orientation:
    """The chosen rotation (applied as ``v @ rotation.T``) and why it was chosen."""

    mode: str
    rotation: np.ndarray  # (3, 3)
    down: np.ndarray  # model direction put towards the bed
    terms: dict[str, float]  # cost terms of the chosen orientation
    kept_terms: dict[str, float]  # the same for the orientation as saved
    candidates: int

    @property
    def rotated(self) -> bool:
        return not np.allclose(self.rotation, np.eye(3))

    def report(self) -> dict:
        """JSON-ready: the rotation, its axis and angle, and the cost terms before and after."""
        angle, axis = rotation_axis_angle(self.rotation)
        if not self.rotated:
            why = "kept as saved"
            if self.mode == "if-needed" and self.kept_terms["support_mm2"] >= NO_SUPPORT_MM2:
                why += " (no orientation avoids support entirely)"
            elif self.mode == "auto":
                why += " (the saved orientation has the least cost)"
        else:
            k, c = self.kept_terms, self.terms
            why = (f"support {k['support_mm2']:.0f} → {c['support_mm2']:.0f} mm², "
                   f"contact {k['contact_mm2']:.0f} → {c['contact_mm2']:.0f} mm², "
                   f"height {k['height_mm']:.1f} → {c['height_mm']:.1f} mm")
        return {
            "mode": self.mode, "rotated": self.rotated,
            "rotation": np.round(self.rotation, 6).tolist(),
            "axis": np.round(axis, 6).tolist(), "angle_deg": round(angle, 3),
            "down": np.round(self.down, 6).tolist(), "reason": why,
            "cost": {k: round(v, 3) for k, v in self.terms.items()},
            "cost_as_saved": {k: round(v, 3) for k, v in self.kept_terms.items()},
            "candidates": self.candidates,
        }


def rotation_to_bed(down: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``down`` to (0, 0, −1)."""
    d = np.asarray(down, dtype=np.float64)
    d = d / np.linalg.norm(d)
    target = np.array([0.0, 0.0, -1.0])
    axis = np.cross(d, target)
    s = float(np.linalg.norm(axis))
    c = float(np.dot(d, target))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # half turn about x
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


def rotation_axis_angle(rot: np.ndarray) -> tuple[float, np.ndarray]:
    """(angle in degrees, unit axis) of a rotation matrix."""
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(rot)) - 1.0) / 2.0)))
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    n = float(np.linalg.norm(axis))
    if n < 1e-9:
        if angle < 1e-6:
            return 0.0, np.array([0.0, 0.0, 1.0])
        # half turn: the axis is the eigenvector of eigenvalue 1
        w, vecs = np.linalg.eigh((rot + rot.T) / 2)
        return math.degrees(angle), vecs[:, int(np.argmax(w))]
    return math.degrees(angle), axis / n


HULL_POINTS = 20_000


def _hull(vertices: np.ndarray):
    """Convex hull of the vertices; above HULL_POINTS vertices, of every k-th one plus the
    extreme vertex along each of 256 directions (qhull on a finely curved 300k-triangle
    mesh would take seconds; the candidates only need the hull's large flat faces)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = vertices
    if len(pts) > HULL_POINTS:
        extreme = np.argmax(pts @ _sphere_directions().T, axis=0)
        pts = pts[np.union1d(np.arange(0, len(pts), len(pts) // HULL_POINTS + 1), extreme)]
    try:
        return ConvexHull(pts)
    except (QhullError, ValueError):
        return None  # flat or degenerate point set


def candidate_downs(vertices: np.ndarray, hull=None, count: int = HULL_CANDIDATES) -> np.ndarray:
    """Down directions to try (k, 3): −z first (as saved), the other axes, then the outward
    normals of the ``count`` largest flat faces of the convex hull (coplanar facets merged)."""
    axes = np.array([[0, 0, -1], [0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]],
                    dtype=np.float64)
    cands = [axes]
    if hull is not None:
        eq = hull.equations  # (m, 4): outward unit normal, offset
        tri = hull.points[hull.simplices]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                    axis=1)
        scale = np.array([1.0, 1.0, 1.0, 1.0 / max(float(np.ptp(vertices, axis=0).max()), 1e-9)])
        key = np.round(eq * scale * 1e3).astype(np.int64)  # same plane, same key
        _, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.ravel()
        plane_area = np.bincount(inv, weights=area)
        top = np.argsort(-plane_area)[:count]
        normals = np.zeros((len(plane_area), 3))
        np.add.at(normals, inv, eq[:, :3] * area[:, None])
        n = normals[top]
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
        cands.append(n)
    d = np.vstack(cands)
    keep = np.ones(len(d), dtype=bool)
    dots = d @ d.T
    for i in range(1, len(d)):  # (k ≤ 18) drop near-duplicates of earlier candidates
        keep[i] = not np.any(dots[i, :i][keep[:i]] > 0.9995)
    return d[keep]


def score(vertices: np.ndarray, faces: np.ndarray, downs: np.ndarray, *,
          bed_tolerance: float = 0.1, support_angle: float = SUPPORT_ANGLE, hull=None
          ) -> dict[str, np.ndarray]:
    """Cost terms (k,) for each candidate down direction; see the module docstring."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    dbl = np.linalg.norm(cross, axis=1)
    area = dbl / 2
    normal = cross / np.maximum(dbl, 1e-300)[:, None]
    if float(np.einsum("ij,ij->i", tri[:, 0], cross).sum()) < 0:  # inside out
        normal = -normal
    total_area = float(area.sum())
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) or 1.0
    cosd = (normal @ downs.T).astype(np.float32)  # (nf, k): facing the bed
    depth = (v @ downs.T).astype(np.float32)  # (nv, k): along d, the bed at the max
    bed = depth.max(axis=0)
    face_top = np.minimum(np.minimum(depth[f[:, 0]], depth[f[:, 1]]), depth[f[:, 2]])
    on_bed = face_top >= bed - bed_tolerance
    overhang = (cosd > math.cos(math.radians(90.0 - support_angle))) & ~on_bed
    a32 = area.astype(np.float32)[:, None]
    support = (a32 * cosd * overhang).sum(axis=0)
    outside = _on_hull(v, f, hull, diag)[:, None]
    visible = (a32 * (overhang & outside)).sum(axis=0)
    contact = (a32 * (on_bed & (cosd > 0.999))).sum(axis=0)
    height = (bed - depth.min(axis=0)).astype(np.float64)
    base = _base_areas(v, hull, downs, bed_tolerance)
    tipping = np.clip(height / (2 * np.sqrt(base / math.pi) + 1e-9) - 2.0, 0.0, 8.0) / 8.0
    cost = (support + VISIBLE_WEIGHT * visible + HEIGHT_WEIGHT * total_area * height / diag
            - CONTACT_WEIGHT * contact + TIPPING_WEIGHT * total_area * tipping)
    return {"cost": cost.astype(np.float64), "support_mm2": support.astype(np.float64),
            "visible_mm2": visible.astype(np.float64), "contact_mm2": contact.astype(np.float64),
            "height_mm": height, "base_mm2": base, "tipping": tipping}


def _base_areas(v: np.ndarray, hull, downs: np.ndarray, tolerance: float) -> np.ndarray:
    """Area (mm²) of the convex hull of the points resting on the bed, per candidate."""
    from scipy.spatial import ConvexHull, QhullError

    pts = hull.points[hull.vertices] if hull is not None else v
    depth = pts @ downs.T
    out = np.zeros(len(downs))
    for k, d in enumerate(downs):  # a few candidates, each vectorised over points
        on = pts[depth[:, k] >= depth[:, k].max() - tolerance]
        u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        flat = np.stack([on @ u, on @ np.cross(d, u)], axis=1)
        try:
            out[k] = ConvexHull(flat).volume if len(flat) >= 3 else 0.0
        except (QhullError, ValueError):
            out[k] = 0.0  # points on a line: no base to stand on
    return out


def _sphere_directions(count: int = 256) -> np.ndarray:
    """``count`` unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    r = np.sqrt(1.0 - z * z)
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _on_hull(v: np.ndarray, f: np.ndarray, hull, diag: float) -> np.ndarray:
    """Faces whose corners all lie on the convex hull's surface (within 1 % of the diagonal).

    The distance from a point c inside a convex body to its surface is the least, over unit
    directions n, of h(n) − c·n, with h the body's support function; it is taken over 128
    directions, so its cost does not grow with the hull's facet count."""
    if hull is None:
        return np.ones(len(f), dtype=bool)
    dirs = _sphere_directions(128).astype(np.float32)
    support = (hull.points[hull.vertices].astype(np.float32) @ dirs.T).max(axis=0)  # h(n)
    pts = v.astype(np.float32)
    gap = np.empty(len(v), dtype=np.float32)
    step = 32768
    for i in range(0, len(v), step):  # chunks of vertices, every direction at once
        gap[i:i + step] = (support[None] - pts[i:i + step] @ dirs.T).min(axis=1)
    return gap[f].max(axis=1) <= 0.01 * diag


def choose_orientation(vertices: np.ndarray, faces: np.ndarray, mode: str = "auto", *,
                       bed_tolerance: float = 0.1) -> Orientation:
    """Score the candidates and pick one per ``mode`` (keep / auto / if-needed)."""
    if mode not in MODES:
        raise ValueError(f"orient must be one of {', '.join(MODES)}, got {mode!r}")
    v = np.asarray(vertices, dtype=np.float64)
    hull = _hull(v)
    downs = candidate_downs(v, hull) if mode != "keep" else np.array([[0.0, 0.0, -1.0]])
    terms = score(v, faces, downs, bed_tolerance=bed_tolerance, hull=hull)
    pick = 0
    if mode == "auto":
        best = int(np.argmin(terms["cost"]))
        # turn only for a real gain: more than 1 % of the cost as saved (and 1 mm²)
        if terms["cost"][best] < terms["cost"][0] - max(0.01 * abs(terms["cost"][0]), 1.0):
            pick = best
    elif mode == "if-needed" and terms["support_mm2"][0] >= NO_SUPPORT_MM2:
        free = np.flatnonzero(terms["support_mm2"] < NO_SUPPORT_MM2)
        if len(free):
            pick = int(free[np.argmin(terms["cost"][free])])

    def at(i: int) -> dict[str, float]:
        return {k: float(a[i]) for k, a in terms.items()}

    return Orientation(mode, rotation_to_bed(downs[pick]), downs[pick], at(pick), at(0),
                       len(downs))
