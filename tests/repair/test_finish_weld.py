"""rounded_verdict after a weld: pairs carried over from before the weld, re-tested only
near merged vertices, give the same verdict and pairs as a whole check of the result."""

from __future__ import annotations

import numpy as np

from repair.check import check_printable_pairs
from repair.finish import rounded_verdict


def _tetra(apex: np.ndarray, base: float, shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[0, 0, 0], [base, 0, 0], [0, base, 0], apex], dtype=np.float64) + shift
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]], dtype=np.int64)
    return v, f


def test_pairs_after_a_weld_match_a_whole_check() -> None:
    parts = [
        # Two tetrahedra meeting apex to corner: 1e-12 apart in float64, one point in
        # float32 -- the weld merges two vertices, and the faces on them are re-tested.
        _tetra(np.array([1.0, 1.0, 1.0]), 1.0, np.zeros(3)),
        _tetra(np.array([0.5, 0.5, 2.0]), 1.0, np.array([1.0 + 1e-12, 1.0, 1.0])),
        # Two that cross elsewhere, untouched by the weld.
        _tetra(np.array([0.3, 0.3, 1.0]), 1.0, np.array([5.0, 0.0, 0.0])),
        _tetra(np.array([0.3, 0.3, 1.0]), 1.0, np.array([5.2, 0.2, 0.1])),
    ]
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    v, f = np.vstack(vs), np.vstack(fs)
    v32, f32, verdict, pairs = rounded_verdict(v, f)
    assert len(v32) < len(v)  # the weld merged the touching corners
    whole, whole_pairs = check_printable_pairs(v32, f32)
    assert verdict.failures() == whole.failures()
    assert verdict.intersecting_pairs == whole.intersecting_pairs > 0
    got = {tuple(p) for p in np.sort(pairs, axis=1).tolist()}
    assert got == {tuple(p) for p in np.sort(whole_pairs, axis=1).tolist()}
    # Only the crossing tetrahedra (faces 8..15) are paired, not those meeting at a point.
    assert min(min(p) for p in got) >= 8
