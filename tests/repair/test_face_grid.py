"""FaceGrid on a real mesh with long faces: a gear whose flanks are long thin triangles
among many small ones. Its queries are the faces whose (grown) box meets an asked
face's -- never fewer (the exact tests of a changed region rely on it), and not the
whole model where the asked faces are few."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from repair.face_grid import FaceGrid
from repair.io import load_mesh

GEAR = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus" / "mikedh_cycloidal.ply"


@pytest.fixture(scope="module")
def gear() -> tuple[np.ndarray, np.ndarray]:
    if not GEAR.is_file():
        pytest.skip("corpus not available")
    m = load_mesh(GEAR)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def _meeting(grid: FaceGrid, which: np.ndarray) -> np.ndarray:
    """Brute force: the faces whose grown box meets that of a face of ``which``."""
    lo, hi = grid.lo, grid.hi
    out = np.zeros(len(lo), dtype=bool)
    for s in range(0, len(which), 128):
        w = which[s : s + 128]
        out |= ((lo[None] <= hi[w, None]) & (hi[None] >= lo[w, None])).all(axis=2).any(axis=0)
    return np.flatnonzero(out)


def test_the_gear_has_long_faces_among_small_ones(gear):
    v, f = gear
    p = v[f]
    ext = (p.max(axis=1) - p.min(axis=1)).max(axis=1)
    assert np.quantile(ext, 0.99) > 8 * np.median(ext)


def test_near_is_exactly_the_faces_whose_box_meets_a_few_asked_ones(gear):
    v, f = gear
    grid = FaceGrid(v, f)
    rng = np.random.default_rng(3)
    for k in (1, 10, 100):
        which = np.unique(rng.integers(0, len(f), k))
        near = grid.near(which)
        assert np.array_equal(near, _meeting(grid, which))


def test_near_a_few_neighbouring_faces_is_a_small_region(gear):
    # A patch of faces around one vertex (a mend's changed faces are clustered).
    v, f = gear
    grid = FaceGrid(v, f)
    rng = np.random.default_rng(4)
    for seed in rng.integers(0, len(f), 5):
        centre = v[f[seed, 0]]
        d = np.linalg.norm(v[f].mean(axis=1) - centre, axis=1)
        which = np.argsort(d)[:50]
        near = grid.near(which)
        truth = _meeting(grid, which)
        assert np.isin(truth, near).all()
        assert len(near) <= max(2 * len(truth), len(f) // 20)


def test_near_many_asked_faces_is_a_superset(gear):
    v, f = gear
    grid = FaceGrid(v, f)
    which = np.unique(np.random.default_rng(5).integers(0, len(f), 400))
    near = grid.near(which)
    assert np.isin(_meeting(grid, which), near).all()
    assert np.isin(which, near).all()
