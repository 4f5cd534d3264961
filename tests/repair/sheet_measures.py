"""Measures of thickened sheets for the repair tests: area coverage (sample points on
the input triangles inside or on the output solid) and wall thickness (along the sheet's
normal through the output, both ways). Units mm; vectorised numpy + libigl."""

from __future__ import annotations

import numpy as np


def surface_samples(v: np.ndarray, f: np.ndarray, count: int, seed: int = 0):
    """``count`` points uniformly by area on the triangles, and each one's unit normal."""
    rng = np.random.default_rng(seed)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = np.linalg.norm(n, axis=1)
    t = rng.choice(len(f), count, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    q = ((1 - r1)[:, None] * p[t, 0] + (r1 * (1 - r2))[:, None] * p[t, 1]
         + (r1 * r2)[:, None] * p[t, 2])  # fmt: skip
    return q, n[t] / area[t, None]


def covered_fraction(v_in, f_in, v_out, f_out, count: int = 20_000, tol: float = 1e-4) -> float:
    """Share of the input's area (sampled) that lies inside the output solid (winding
    number > 1/2) or on its surface (within ``tol`` mm: float32 rounding)."""
    import igl

    q, _ = surface_samples(np.asarray(v_in, float), np.asarray(f_in, np.int64), count)
    vo, fo = np.asarray(v_out, float), np.asarray(f_out, np.int64)
    w = np.asarray(igl.fast_winding_number(vo, fo, q))
    d2 = np.asarray(igl.point_mesh_squared_distance(q, vo, fo)[0])
    return float(np.mean((w > 0.5) | (d2 <= tol * tol)))


def _first_hit(origins: np.ndarray, dirs: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance along each ray to the nearest triangle it crosses (inf if none):
    Moller-Trumbore, rays x triangles at once."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.full(len(origins), np.inf)
    for s in range(0, len(origins), 64):
        o, d = origins[s : s + 64, None], dirs[s : s + 64, None]
        h = np.cross(d, e2[None])
        a = np.einsum("rfk,fk->rf", h, e1)
        inv = np.divide(1.0, a, out=np.zeros_like(a), where=np.abs(a) > 1e-300)
        sv = o - tri[None, :, 0]
        u = inv * np.einsum("rfk,rfk->rf", sv, h)
        qv = np.cross(sv, e1[None])
        w = inv * np.einsum("rfk,rfk->rf", qv, d)
        t = inv * np.einsum("fk,rfk->rf", e2, qv)
        tol = 1e-9  # a ray through an edge or corner hits either face there
        ok = (a != 0) & (u >= -tol) & (w >= -tol) & (u + w <= 1 + tol) & (t > 0)
        out[s : s + 64] = np.where(ok, t, np.inf).min(axis=1)
    return out


def _distance_to_rim(q: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point to the nearest boundary edge (used by one face)."""
    from repair.topology import undirected_edges

    edges, uses = undirected_edges(f)
    rim = edges[uses == 1]
    if len(rim) == 0:
        return np.full(len(q), np.inf)
    a, b = v[rim[:, 0]], v[rim[:, 1]]
    ab = b - a
    t = np.einsum("pek,ek->pe", q[:, None] - a[None], ab) / np.einsum("ek,ek->e", ab, ab)
    c = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]
    return np.linalg.norm(q[:, None] - c, axis=2).min(axis=1)


def wall_thickness(
    v_in, f_in, v_out, f_out, count: int = 400, seed: int = 1, rim_margin: float = 0.0
) -> np.ndarray:
    """Thickness (mm) of the output's wall through sample points of the input sheet:
    the distance along the sheet's normal to the output surface one way plus the other
    way (the sheet lies inside its slab). Points within ``rim_margin`` mm of the sheet's
    open rim are left out: at the rim the wall ends, so "through" is not defined."""
    v, f = np.asarray(v_in, float), np.asarray(f_in, np.int64)
    q, n = surface_samples(v, f, count, seed)
    keep = _distance_to_rim(q, v, f) >= rim_margin
    q, n = q[keep], n[keep]
    tri = np.asarray(v_out, float)[np.asarray(f_out, np.int64)]
    return _first_hit(q, n, tri) + _first_hit(q, -n, tri)
