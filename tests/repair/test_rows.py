"""repair.rows.unique_rows must agree with np.unique(axis=0) in every output."""

from __future__ import annotations

import numpy as np
import pytest

from repair.rows import unique_rows


@pytest.mark.parametrize("shape", [(1000, 2), (3000, 3), (1, 3), (0, 2)])
@pytest.mark.parametrize("flags", [(False, False, False), (True, True, True), (False, True, True),
                                   (True, False, False)])  # fmt: skip
def test_unique_rows_matches_numpy(shape, flags):
    a = np.random.default_rng(len(shape) + shape[0]).integers(-5, 40, size=shape)
    want = np.unique(a, axis=0, return_index=flags[0], return_inverse=flags[1],
                     return_counts=flags[2])  # fmt: skip
    got = unique_rows(a, *flags)
    _assert_same_outputs(want, got)
    assert np.asarray(got if not isinstance(got, tuple) else got[0]).shape == (
        np.asarray(want if not isinstance(want, tuple) else want[0]).shape
    )


def _assert_same_outputs(want, got) -> None:
    """The same arrays (flattened) in the same order, as np.unique returns them."""
    want = want if isinstance(want, tuple) else (want,)
    got = got if isinstance(got, tuple) else (got,)
    assert len(got) == len(want)
    for w, g in zip(want, got, strict=True):
        assert np.array_equal(np.asarray(w).reshape(-1), np.asarray(g).reshape(-1))


def test_unique_rows_of_huge_indices_falls_back_to_numpy():
    a = np.array([[2**40, 2**40, 2**40], [0, 0, 0], [2**40, 2**40, 2**40]], dtype=np.int64)
    rows, inv = unique_rows(a, return_inverse=True)
    assert rows.tolist() == [[0, 0, 0], [2**40] * 3]
    assert inv.tolist() == [1, 0, 1]


@pytest.mark.parametrize("n,lo,hi", [(5000, -50, 300), (1, 0, 5), (0, 0, 1), (2000, -2**40, 2**40),
                                     (3000, 0, 2**61)])  # fmt: skip
@pytest.mark.parametrize("flags", [(False, False, False), (True, True, True), (False, True, False)])
def test_unique_ints_matches_numpy(n, lo, hi, flags):
    from repair.rows import unique_ints

    a = np.random.default_rng(n).integers(lo, hi, size=n)
    a = np.r_[a, a[: n // 3]]  # repeats, first occurrences to find
    want = np.unique(a, return_index=flags[0], return_inverse=flags[1], return_counts=flags[2])
    got = unique_ints(a, *flags)
    _assert_same_outputs(want, got)
    first = got if not isinstance(got, tuple) else got[0]
    assert first.dtype == (want if not isinstance(want, tuple) else want[0]).dtype


def test_ranges_gathers_runs_in_order():
    from repair.rows import ranges

    assert ranges(np.array([5, 0, 9]), np.array([2, 0, 3])).tolist() == [5, 6, 9, 10, 11]
    assert ranges(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)).tolist() == []
