"""manifold_union of many solids unites them in shares side by side on the CPUs
(repair.union._sum_in_shares): the same solid as one batch, cavities kept inside the
shells that hold them, and the same output whatever the number of CPUs."""

from __future__ import annotations

import numpy as np
import pytest

import repair.workers as workers
from repair.check import check_printable
from repair.meshes import shell_volumes
from repair.topology import edge_components
from repair.union import SHARED_MIN_SOLIDS, manifold_union
from tests.repair.mesh_helpers import box


def _hollow_box_of_strips(x0: float, strips: int = 6) -> list[tuple[np.ndarray, np.ndarray]]:
    """A 10 mm cube with 1 mm walls (an 8 mm cavity) at x = x0, each wall a heap of
    ``strips`` overlapping boxes."""
    parts = []
    for axis in range(3):
        for lo in (0.0, 9.0):
            for k in range(strips):
                a, b = np.zeros(3), np.full(3, 10.0)
                a[axis], b[axis] = lo, lo + 1.0
                other = (axis + 1) % 3  # strips across the wall, each overlapping the next
                a[other], b[other] = k * 10.0 / strips, min((k + 1.5) * 10.0 / strips, 10.0)
                a[0] += x0
                b[0] += x0
                parts.append(box(tuple(a), tuple(b)))
    return parts


def _shells(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    labels = edge_components(f)
    return np.sort(shell_volumes(v, f, labels, int(labels.max()) + 1))


def test_many_solids_united_in_shares_keep_their_cavities(monkeypatch):
    parts = _hollow_box_of_strips(0.0) + _hollow_box_of_strips(20.0)
    assert len(parts) >= SHARED_MIN_SOLIDS
    out = manifold_union(parts)
    assert out is not None
    assert check_printable(*out).ok
    # Two shells of 1000 mm³ around two cavities of 512 mm³ (each share holds one box).
    assert _shells(*out) == pytest.approx([-512.0, -512.0, 1000.0, 1000.0], rel=1e-6)
    monkeypatch.setattr(workers, "cpu_workers", lambda: 1)
    again = manifold_union(parts)
    assert again is not None
    assert np.array_equal(again[0], out[0]) and np.array_equal(again[1], out[1])
