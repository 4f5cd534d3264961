"""A seeded generator of broken models: overlapping closed shells (UV spheres, tori,
cylinders, plates) with scattered single triangles deleted -- the most common real
breakage (overlapping parts plus small holes) -- and random-triangle soups (crossing
zero-thickness sheets). Used by the repair tests and by ``bench/bench_repair.py``.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3), all vectorised numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BrokenModel", "broken_family", "overlapping_shells", "triangle_soup"]


def _grid_faces(rows: int, cols: int, wrap_cols: bool) -> np.ndarray:
    """Two triangles per cell of a (rows + 1) x cols vertex grid (columns wrap when
    ``wrap_cols``), oriented counter-clockwise in (row, col) order."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols if wrap_cols else cols - 1), indexing="ij")
    width = cols
    a = r * width + c
    b = r * width + (c + 1) % width
    d = (r + 1) * width + c
    e = (r + 1) * width + (c + 1) % width
    return np.concatenate(
        [np.stack([a, d, b], -1).reshape(-1, 3), np.stack([b, d, e], -1).reshape(-1, 3)]
    ).astype(np.int64)


def uv_sphere(radius: float, rings: int, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed outward UV sphere: 2 * segments * (rings - 1) triangles."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.vstack([ring, [[0, 0, 1]], [[0, 0, -1]]]) * radius
    f = _grid_faces(rings - 2, segments, True)
    top, bottom = len(ring), len(ring) + 1
    j = np.arange(segments)
    last = (rings - 2) * segments
    caps = np.vstack([
        np.stack([np.full(segments, top), j, (j + 1) % segments], -1),
        np.stack([np.full(segments, bottom), last + (j + 1) % segments, last + j], -1),
    ])  # fmt: skip
    return _outward(v, np.vstack([f, caps]))


def torus(major: float, minor: float, n_major: int, n_minor: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed outward torus about z: 2 * n_major * n_minor triangles."""
    u = np.linspace(0.0, 2 * np.pi, n_major, endpoint=False)
    w = np.linspace(0.0, 2 * np.pi, n_minor, endpoint=False)
    uu, ww = np.meshgrid(u, w, indexing="ij")
    rad = major + minor * np.cos(ww)
    v = np.stack([rad * np.cos(uu), rad * np.sin(uu), minor * np.sin(ww)], -1).reshape(-1, 3)
    f = _grid_faces(n_major, n_minor, True) % len(v)
    return _outward(v, f)


def cylinder(radius: float, height: float, rings: int, segments: int):
    """Closed outward cylinder along z, centred at 0: 2 * segments * (rings + 1) triangles."""
    z = np.linspace(-height / 2, height / 2, rings + 1)
    p = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    zz, pp = np.meshgrid(z, p, indexing="ij")
    side = np.stack([radius * np.cos(pp), radius * np.sin(pp), zz], -1).reshape(-1, 3)
    v = np.vstack([side, [[0, 0, -height / 2]], [[0, 0, height / 2]]])
    f = _grid_faces(rings, segments, True)
    j = np.arange(segments)
    lo, hi, last = len(side), len(side) + 1, rings * segments
    caps = np.vstack([
        np.stack([np.full(segments, lo), j, (j + 1) % segments], -1),
        np.stack([np.full(segments, hi), last + (j + 1) % segments, last + j], -1),
    ])  # fmt: skip
    return _outward(v, np.vstack([f, caps]))


def plate(size: tuple[float, float, float], cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed outward box centred at 0, each face a ``cells`` x ``cells`` grid
    (12 * cells**2 triangles)."""
    g = np.linspace(-0.5, 0.5, cells + 1)
    a, b = np.meshgrid(g, g, indexing="ij")
    a, b = a.reshape(-1), b.reshape(-1)
    quad = _grid_faces(cells, cells + 1, False)
    vs, fs = [], []
    for axis in range(3):
        for side in (-0.5, 0.5):
            pts = np.zeros((len(a), 3))
            pts[:, axis] = side
            pts[:, (axis + 1) % 3], pts[:, (axis + 2) % 3] = a, b
            ff = quad if side > 0 else quad[:, ::-1]
            fs.append(ff + sum(len(x) for x in vs))
            vs.append(pts)
    v, f = np.vstack(vs) * np.asarray(size, float), np.vstack(fs)
    # Weld the shared edges of the six grids exactly (they sit on identical points).
    _, first, inv = np.unique(v.round(9), axis=0, return_index=True, return_inverse=True)
    return _outward(v[first], inv.reshape(-1)[f])


def _outward(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    if np.einsum("ij,ij->", a, np.cross(b, c)) < 0:
        f = f[:, ::-1]
    return v.astype(np.float64), np.ascontiguousarray(f, dtype=np.int64)


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@dataclass(frozen=True)
class BrokenModel:
    """A generated broken model: ``vertices``, ``faces``, its ``name`` (seed and sizes)
    and how many triangles were deleted (``holes``)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    holes: int


def overlapping_shells(
    triangles: int = 190_000, holes: int = 100, seed: int = 0, shells: int = 5
) -> BrokenModel:
    """``shells`` overlapping closed shells (cycling through UV sphere, UV sphere, torus,
    cylinder, plate), about ``triangles`` in all, randomly turned and placed so that
    each crosses the others, with ``holes`` scattered single triangles deleted."""
    rng = np.random.default_rng(seed)
    kinds = ("sphere", "sphere", "torus", "cylinder", "plate")
    per = max(triangles // shells, 200)
    parts = []
    for i in range(shells):
        kind = kinds[i % len(kinds)]
        size = rng.uniform(18.0, 26.0)
        if kind == "sphere":
            n = max(int(np.sqrt(per / 2)), 6)
            v, f = uv_sphere(size, n, n)
        elif kind == "torus":
            n = max(int(np.sqrt(per / 2 / 3)), 4)
            v, f = torus(size, size * rng.uniform(0.25, 0.4), 3 * n, n)
        elif kind == "cylinder":
            n = max(int(np.sqrt(per / 2)), 6)
            v, f = cylinder(size * 0.5, size * 2.0, n - 1, n)
        else:
            n = max(int(np.sqrt(per / 12)), 1)
            v, f = plate((size * 3.0, size * 2.0, size * 0.2), n)
        v = v @ _rotation(rng).T + rng.uniform(-12.0, 12.0, size=3)
        parts.append((v, f))
    off = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    v = np.vstack([p[0] for p in parts])
    f = np.vstack([p[1] + o for p, o in zip(parts, off, strict=True)])
    # Scattered single triangles, drawn at random: two may share a vertex or an edge
    # (then their holes touch), as in real exports.
    picked = rng.choice(len(f), size=min(holes, len(f) // 200), replace=False)
    keep = np.ones(len(f), dtype=bool)
    keep[picked] = False
    name = f"shells{shells}_{len(f) // 1000}k_h{len(picked)}_s{seed}"
    return BrokenModel(name, v, f[keep], len(picked))


def broken_family(count: int = 50, low: int = 10_000, high: int = 200_000, seed: int = 0):
    """``count`` seeded broken models, triangle counts log-spaced from ``low`` to
    ``high``, 2-6 shells each, 5-150 holes."""
    rng = np.random.default_rng(seed)
    sizes = np.geomspace(low, high, count).astype(int)
    out = []
    for i, n in enumerate(sizes):
        out.append(overlapping_shells(int(n), int(rng.integers(5, 151)), seed * 1000 + i,
                                      int(rng.integers(2, 7))))  # fmt: skip
    return out


def triangle_soup(count: int = 20, seed: int = 0, low: float = 8.0, high: float = 28.0):
    """``count`` random triangles with edges ``low``-``high`` mm, crossing one another in
    a box about 30 mm wide: each a two-sided visible sheet."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        centre = rng.uniform(-8.0, 8.0, size=3)
        pts = centre + rng.normal(size=(3, 3)) * (high / 2.5)
        edges = np.linalg.norm(pts - np.roll(pts, 1, axis=0), axis=1)
        if edges.min() >= low and edges.max() <= high:
            out.append(pts)
    v = np.asarray(out).reshape(-1, 3)
    return v, np.arange(len(v), dtype=np.int64).reshape(-1, 3)
