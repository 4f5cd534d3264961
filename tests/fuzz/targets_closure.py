"""Fuzz targets of shell closure, crack stitching and scan cleanup on random input.

- ``lid``: random loops (planar polygons in a random plane, convex or not, even
  self-crossing; or random 3-D loops) through :func:`repair.closure.loop_lid`: every lid
  is k-2 triangles on the loop's own vertices (or a fan with one new vertex), and a lid
  called planar has every triangle turning the loop's way.
- ``stitch``: two jittered grid patches with a random gap through
  :func:`repair.stitch.stitch_cracks`: no vertex moves, no face loses a corner, no edge of
  more than two faces or misoriented edge is made.
- ``scan``: small random indexed meshes through :func:`repair.scan.clean_scan`: faces
  stay valid, none with a repeated corner.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from harness import Target
from hypothesis import strategies as st

from repair.closure import loop_lid, loop_planarity
from repair.scan import clean_scan
from repair.stitch import stitch_cracks
from repair.topology import edge_stats

_seed = st.integers(0, 2**32 - 1)


def _loop(value: tuple[int, int, bool]) -> Any:
    seed, k, planar = value
    rng = np.random.default_rng(seed)
    if planar:
        angle = np.sort(rng.uniform(0, 2 * np.pi, k)) if rng.random() < 0.7 else rng.uniform(
            0, 2 * np.pi, k)  # sometimes self-crossing
        r = rng.uniform(0.2, 1.0, k)
        flat = np.c_[r * np.cos(angle), r * np.sin(angle), np.zeros(k)]
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        v = flat @ q.T * rng.uniform(0.1, 100) + rng.normal(size=3) * 50
    else:
        v = rng.normal(size=(k, 3))
    lid = loop_lid(v, np.arange(k), k)
    if len(lid.new_vertices):
        assert len(lid.triangles) == k and np.all(lid.triangles[:, 2] == k)
    else:
        assert len(lid.triangles) == k - 2 and lid.triangles.max() < k
        assert len(np.unique(lid.triangles)) == k
    if lid.planar:
        _, normal, planar_loop = loop_planarity(v)
        p = v[lid.triangles]
        turn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) @ normal
        assert planar_loop and np.all(turn > 0), "a planar lid folds over"
    return lid


def _grid(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.linspace(0, 10, n), np.linspace(0, 10, n))
    v = np.c_[x.ravel(), y.ravel(), 0.02 * rng.normal(size=n * n)]
    i = np.arange((n - 1) * (n - 1))
    a = (i // (n - 1)) * n + i % (n - 1)
    f = np.r_[np.c_[a, a + 1, a + n + 1], np.c_[a, a + n + 1, a + n]]
    return v, f


def _stitch(value: tuple[int, int, int, float]) -> Any:
    seed, n1, n2, gap = value
    rng = np.random.default_rng(seed)
    va, fa = _grid(n1, rng)
    vb, fb = _grid(n2, rng)
    vb = vb * [1, 1, 1] + [0, 10 + gap, 0]  # side by side with a gap along y = 10
    if rng.random() < 0.5:
        fb = fb[:, ::-1]  # facing the other way: not a crack to close
    v = np.vstack([va, vb])
    f = np.vstack([fa, fb + len(va)])
    _, nm0, mis0, _, _ = edge_stats(f)
    out, done = stitch_cracks(v, f, 0.1)
    assert out.min() >= 0 and out.max() < len(v)
    assert np.all((out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 2] != out[:, 0]))
    _, nm1, mis1, _, _ = edge_stats(out)
    assert nm1 <= nm0 and mis1 <= mis0
    return done


def _scan(value: tuple[int, int, int]) -> Any:
    seed, k, n = value
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(k, 3)) * rng.uniform(0.1, 10)
    f = rng.integers(0, k, size=(n, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    out_v, out_f, _ = clean_scan(v, f, 0.4)
    assert len(out_v) == len(v)
    if len(out_f):
        assert out_f.min() >= 0 and out_f.max() < len(v)
        assert np.all((out_f[:, 0] != out_f[:, 1]) & (out_f[:, 1] != out_f[:, 2])
                      & (out_f[:, 2] != out_f[:, 0]))  # fmt: skip
    return out_f


TARGETS: list[Target] = [
    Target("lid", st.tuples(_seed, st.integers(3, 40), st.booleans()), _loop, (),
           ("repair.closure",)),  # fmt: skip
    Target("stitch", st.tuples(_seed, st.integers(2, 12), st.integers(2, 12),
                               st.floats(0.0, 0.3)), _stitch, (), ("repair.stitch",)),  # fmt: skip
    Target("scan", st.tuples(_seed, st.integers(3, 40), st.integers(1, 120)), _scan, (),
           ("repair.scan",)),  # fmt: skip
]
