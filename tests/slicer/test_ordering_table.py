"""The nearest-neighbour ordering's distance table (used for groups of few points per path)
must choose exactly what the step-by-step search chooses: same order, same orientations."""

import numpy as np
import pytest

from slicer import ordering
from slicer.planner import Path


def _group(seed: int) -> list[Path]:
    rng = np.random.default_rng(seed)
    paths = []
    for _ in range(50):  # infill-like lines, some on a shared grid so that distances tie
        a = np.round(rng.uniform(0, 40, 2), 1)
        paths.append(Path(np.array([a, a + np.round(rng.uniform(-5, 5, 2), 1)]), False, 0.45,
                          "sparse_infill"))
    for _ in range(2):  # a few short loops and polylines
        c = rng.uniform(0, 40, 2)
        t = np.linspace(0, 2 * np.pi, 4, endpoint=False)
        paths.append(Path(c + np.c_[np.cos(t), np.sin(t)], True, 0.45, "sparse_infill"))
        paths.append(Path(c + rng.uniform(-3, 3, (4, 2)), False, 0.45, "sparse_infill"))
    return paths


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("rear_seam", [False, True])
def test_table_orders_as_the_stepwise_search(monkeypatch, seed, rear_seam):
    paths = _group(seed)
    start = np.array([20.0, 20.0])
    n_points = sum(len(p.points) if p.closed or len(p.points) == 2 else 2 for p in paths)
    assert ordering._gap_table(*np.zeros((2, n_points)), len(paths)) is not None  # in use
    with_table, end_t = ordering._nearest_neighbour(paths, start, rear_seam)
    monkeypatch.setattr(ordering, "_gap_table", lambda *args: None)
    stepwise, end_s = ordering._nearest_neighbour(paths, start, rear_seam)
    assert [id(p) for _, p in with_table] == [id(p) for _, p in stepwise]
    for (a, _), (b, _) in zip(with_table, stepwise, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(end_t, end_s)
