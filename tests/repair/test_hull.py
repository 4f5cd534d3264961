"""Stage 2 of the repair (repair.hull): the exact arrangement. Re-meshing only the faces
that intersect gives the same polyhedron as re-meshing the whole mesh."""

from __future__ import annotations

import numpy as np
import trimesh

from repair.check import intersecting_face_pairs, weld_exact
from repair.hull import LOCAL_REMESH_MIN_FACES, _remesh


def _triangles(v: np.ndarray, f: np.ndarray, birth: np.ndarray) -> list:
    """Each face as (birth face, its corner coordinates in a canonical order)."""
    return sorted((int(b), tuple(sorted(map(tuple, v[t])))) for b, t in zip(birth, f, strict=True))


def test_local_arrangement_is_the_whole_mesh_arrangement():
    a = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    b = trimesh.creation.icosphere(subdivisions=3, radius=7.0)
    v = np.vstack([a.vertices, b.vertices + (9.3, 1.7, -2.1)])
    f = np.vstack([a.faces, b.faces + len(a.vertices)]).astype(np.int64)
    assert len(f) >= LOCAL_REMESH_MIN_FACES
    pairs = intersecting_face_pairs(v, f)
    assert 0 < len(np.unique(pairs)) < len(f) // 4  # a local pass, not the whole mesh

    lv, lf, lb, n = _remesh(v, f)
    assert n == len(pairs)
    assert len(lf) > len(f)  # the crossing faces were split
    untouched = np.setdiff1d(np.arange(len(f)), pairs)
    assert np.isin(untouched, lb).all()

    import igl.copyleft.cgal as cgal

    wv, wf, _, wb, im = cgal.remesh_self_intersections(v, f, stitch_all=True, cutoff=2**31 - 1)
    wf = np.asarray(im)[wf]
    lv, lf = weld_exact(lv, lf)
    wv, wf = weld_exact(np.asarray(wv), wf)
    assert len(lv) == len(wv)
    assert _triangles(lv, lf, lb) == _triangles(wv, wf, np.asarray(wb))


def test_arrangement_of_a_mesh_without_crossings_is_the_mesh():
    s = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    v, f = np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)
    rv, rf, birth, n = _remesh(v, f)
    assert n == 0
    assert np.array_equal(rv, v) and np.array_equal(rf, f)
    assert np.array_equal(birth, np.arange(len(f)))
