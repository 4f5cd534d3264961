"""repair.provenance.starts_with_faces: the same rows on the same points, however the
arrays are shared, copied or renumbered; a moved point or a changed row says no."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from repair.io import load_mesh
from repair.provenance import same_faces, starts_with_faces

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"


def _rabbit() -> tuple[np.ndarray, np.ndarray]:
    path = CORPUS / "mikedh_rabbit.obj"
    if not path.exists():
        pytest.skip(f"corpus file missing: {path}")
    m = load_mesh(path)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def test_the_very_arrays_copies_and_appended_lids_start_with_the_faces():
    v, f = _rabbit()
    assert starts_with_faces(v, f, v, f)
    lid = np.array([[0, 1, 2]])
    assert starts_with_faces(v, f, v.copy(), np.vstack([f, lid]))
    extra = np.vstack([v, [[1e3, 2e3, 3e3]]])  # a vertex appended for a lid
    assert starts_with_faces(v, f, extra, np.vstack([f, [[0, 1, len(v)]]]))
    match = same_faces(v, f, v, f)
    np.testing.assert_array_equal(match, np.arange(len(f)))


def test_renumbered_vertices_on_the_same_points_start_with_the_faces():
    v, f = _rabbit()
    perm = np.random.default_rng(4).permutation(len(v))
    inverse = np.argsort(perm)
    assert starts_with_faces(v, f, v[perm], inverse[f])


def test_a_moved_point_or_a_changed_row_does_not():
    v, f = _rabbit()
    moved = v.copy()
    moved[f[len(f) // 2, 1]] += 2.0**-20
    assert not starts_with_faces(v, f, moved, f)
    rows = f.copy()
    rows[7] = rows[7, [0, 2, 1]]  # the same points, another row: compared as rows
    assert not starts_with_faces(v, f, v, rows)
    assert not starts_with_faces(v, f, v, f[:-1])
