"""repair.intersections: the pairs of a few changed faces, tested against the faces
around them only, are exactly those a test of the whole region finds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from repair.clean import degenerate_mask
from repair.intersections import intersecting_face_pairs, intersecting_pairs_with
from repair.io import load_mesh

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"


def _real_crossing_mesh() -> tuple[np.ndarray, np.ndarray]:
    path = CORPUS / "mikedh_soup.stl"
    if not path.exists():
        pytest.skip(f"corpus file missing: {path}")
    m = load_mesh(path)
    v, f = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    return v, f[~degenerate_mask(v, f)]


def _region_test(v: np.ndarray, f: np.ndarray, which: np.ndarray) -> np.ndarray:
    """The reference: every pair of the whole mesh, kept where it holds a face of which."""
    found = intersecting_face_pairs(v, f)
    return found[np.isin(found, which).any(axis=1)]


@pytest.mark.parametrize("count", [1, 7, 60])
def test_pairs_of_changed_faces_are_those_of_a_whole_test(count: int):
    v, f = _real_crossing_mesh()
    reference = intersecting_face_pairs(v, f)
    assert len(reference) > 100  # a real soup of crossing parts
    rng = np.random.default_rng(count)
    # Changed faces picked among crossing ones and among the rest.
    which = np.unique(np.r_[rng.choice(np.unique(reference), count), rng.choice(len(f), count)])
    others = np.setdiff1d(np.arange(len(f)), which)
    got = intersecting_pairs_with(v, f, which, others)
    expected = _region_test(v, f, which)
    assert len(expected) > 0
    np.testing.assert_array_equal(got, expected)


def test_corners_at_one_point_under_two_indices_read_as_shared():
    # Each face gets its own copies of its corners: adjacency is by position only, as
    # libigl's self test reads it, so neighbours that only share an edge do not pair.
    v, f = _real_crossing_mesh()
    v_split, f_split = v[f.reshape(-1)], np.arange(3 * len(f)).reshape(-1, 3)
    which = np.arange(0, len(f), 97)
    others = np.setdiff1d(np.arange(len(f)), which)
    got = intersecting_pairs_with(v_split, f_split, which, others)
    np.testing.assert_array_equal(got, _region_test(v_split, f_split, which))
    np.testing.assert_array_equal(got, _region_test(v, f, which))


@pytest.mark.parametrize("k", [2, 3])
def test_slabs_of_a_large_mesh_cut_on_a_sample_hold_every_face_and_balance(k):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from mesh_helpers import concat, sphere

    from repair.intersections import _CUT_SAMPLE, face_slabs

    # Two overlapping balls, faces of very different sizes: more faces than the sample.
    v, f = concat(sphere(7, 10.0), sphere(3, 8.0, centre=(6.0, 1.0, 0.5)))
    assert len(f) > 2 * _CUT_SAMPLE
    slabs = face_slabs(v, f, k)
    covered = np.zeros(len(f), dtype=bool)
    for s in slabs:
        covered[s] = True
    assert covered.all()  # every face is tested somewhere
    counts = [len(s) for s in slabs]
    assert max(counts) - min(counts) <= 0.02 * max(counts)



@pytest.mark.parametrize("split_from", [3_000, 10**9])
def test_a_region_of_thousands_tested_in_two_forked_slabs_finds_the_same_pairs(
    split_from, monkeypatch
):
    # mikedh_box's ten crossing shells, the first 3,500 faces changed: 3,843 faces near
    # them, tested in two slabs (one in a forked child) beside the faces apart -- or,
    # split_from 10**9, in one test here: the pairs a test of the whole mesh finds.
    import repair.intersections as inter

    path = CORPUS / "mikedh_box.STL"
    if not path.exists():
        pytest.skip(f"corpus file missing: {path}")
    monkeypatch.setattr(inter, "SPLIT_MIN_FACES", split_from)
    m = load_mesh(path)
    v, f = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    which, others = np.arange(3_500), np.arange(3_500, len(f))
    got = intersecting_pairs_with(v, f, which, others)
    expected = _region_test(v, f, which)
    assert len(expected) > 1_000
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("beside_from", [1_000, 10**9])
def test_faces_apart_tested_in_a_child_beside_a_slabbed_region_find_the_same_pairs(
    beside_from, monkeypatch
):
    # mikedh_box, the first 3,500 faces changed: the 3,843 faces near them are slabbed
    # (PARALLEL_MIN_FACES lowered to 3,000) and the faces apart tested in a forked child
    # beside them -- or, beside_from 10**9, after them: the pairs of a whole test.
    import repair.intersections as inter
    import repair.workers as workers

    path = CORPUS / "mikedh_box.STL"
    if not path.exists():
        pytest.skip(f"corpus file missing: {path}")
    monkeypatch.setattr(inter, "PARALLEL_MIN_FACES", 3_000)
    monkeypatch.setattr(inter, "BESIDE_MIN_FACES", beside_from)
    monkeypatch.setattr(workers, "cpu_workers", lambda: 2)
    m = load_mesh(path)
    v, f = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    which, others = np.arange(3_500), np.arange(3_500, len(f))
    got = intersecting_pairs_with(v, f, which, others)
    monkeypatch.setattr(inter, "PARALLEL_MIN_FACES", 10**9)
    expected = _region_test(v, f, which)
    assert len(expected) > 1_000
    np.testing.assert_array_equal(got, expected)


def test_used_vertices_are_numpys_unique_with_inverse():
    from repair.intersections import _used_vertices

    rng = np.random.default_rng(5)
    corners = rng.integers(0, 1_000, 3_000) * 3  # gaps: unused vertices
    used, inverse = _used_vertices(corners, 3_000)
    want_used, want_inverse = np.unique(corners, return_inverse=True)
    np.testing.assert_array_equal(used, want_used)
    np.testing.assert_array_equal(inverse, want_inverse)
    np.testing.assert_array_equal(used[inverse], corners)
