"""Stages 2-3 of the repair (repair.hull): re-meshing only the faces that intersect gives
the same polyhedron as re-meshing the whole mesh; nesting components by parts gives the
same outer hull as one libigl call."""

from __future__ import annotations

import numpy as np
from mesh_helpers import box, concat, sphere

import repair.hull as hull
from repair.hull import LOCAL_REMESH_MIN_FACES, _remesh
from repair.intersections import intersecting_face_pairs
from repair.topology import weld_exact


def _triangles(v: np.ndarray, f: np.ndarray, birth: np.ndarray) -> list:
    """Each face as (birth face, its corner coordinates in a canonical order)."""
    return sorted((int(b), tuple(sorted(map(tuple, v[t])))) for b, t in zip(birth, f, strict=True))


def test_local_arrangement_is_the_whole_mesh_arrangement():
    v, f = concat(sphere(3, 10.0), sphere(3, 7.0, (9.3, 1.7, -2.1)))
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
    v, f = sphere(4, 10.0)
    rv, rf, birth, n = _remesh(v, f)
    assert n == 0
    assert np.array_equal(rv, v) and np.array_equal(rf, f)
    assert np.array_equal(birth, np.arange(len(f)))


def _single_call(v, f, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(hull, "_outside_sides_by_parts", lambda *a: None)
        return hull.outer_hull_split(v, f)


def test_components_nest_as_one_libigl_call_nests_them(monkeypatch):
    big = sphere(4, 10.0)  # 5120 faces: its cells are extracted on their own
    inner = box((-1, -1, -1), (1, 1, 1))  # inside the sphere: internal
    outer = box((20, 0, 0), (22, 2, 2))  # beside it: kept
    sheet = (np.array([[30.0, 0, 0], [32, 0, 0], [30, 2, 0]]), np.array([[0, 1, 2]]))
    v, f = concat(big, inner, outer, sheet)
    split = hull.outer_hull_split(v, f)
    assert np.array_equal(np.sort(split.solid_index), np.r_[0:5120, 5132:5144])
    assert np.array_equal(split.sheet_index, [5144])
    assert split.internal == 12
    ref = _single_call(v, f, monkeypatch)
    for a, b in zip(
        (split.solid_faces, split.sheet_faces, split.solid_index, split.sheet_index),
        (ref.solid_faces, ref.sheet_faces, ref.solid_index, ref.sheet_index),
        strict=True,
    ):
        assert np.array_equal(a, b)


def test_the_largest_component_inside_a_coarse_box_is_internal(monkeypatch):
    big = sphere(4, 10.0)
    around = box((-20, -20, -20), (20, 20, 20))  # 12 faces around 5120
    v, f = concat(big, around)
    split = hull.outer_hull_split(v, f)
    assert np.array_equal(np.sort(split.solid_index), np.arange(5120, 5132))
    assert split.internal == 5120 and len(split.sheet_index) == 0
    ref = _single_call(v, f, monkeypatch)
    assert np.array_equal(np.sort(ref.solid_index), np.sort(split.solid_index))


def test_components_arranged_apart_give_the_same_polyhedron_on_any_number_of_cpus(
    monkeypatch,
):
    import igl.copyleft.cgal as cgal

    import repair.workers as workers

    # Three separate pairs of crossing spheres: three independent groups of crossings.
    parts = []
    for k in range(3):
        parts += [sphere(3, 5.0, (30.0 * k, 0, 0)), sphere(3, 4.0, (30.0 * k + 4.1, 0.7, 0))]
    v, f = concat(*parts)
    runs = []
    for n in (1, 3):
        monkeypatch.setattr(workers, "cpu_workers", lambda n=n: n)
        runs.append(_remesh(v, f))
    for a, b in zip(runs[0], runs[1], strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    lv, lf, lb, n_pairs = runs[0]
    wv, wf, _, wb, im = cgal.remesh_self_intersections(v, f, stitch_all=True, cutoff=2**31 - 1)
    wf = np.asarray(im)[wf]
    assert n_pairs == len(intersecting_face_pairs(v, f))
    lv, lf = weld_exact(lv, lf)
    wv, wf = weld_exact(np.asarray(wv), wf)
    assert _triangles(lv, lf, lb) == _triangles(wv, wf, np.asarray(wb))


def test_a_worker_that_dies_has_its_jobs_run_again():
    import os
    import signal

    from repair.workers import map_forked

    parent = os.getpid()

    def square(x):
        if os.getpid() != parent and x == 3:
            os.kill(os.getpid(), signal.SIGKILL)
        return (np.array([x * x]),)

    got = map_forked(square, [1, 2, 3, 4, 5], [[0, 4], [1, 2], [3]])
    assert [int(r[0][0]) for r in got] == [1, 4, 9, 16, 25]


def test_later_resolve_rounds_test_only_near_the_new_faces_and_find_the_same():
    # Ghostkeeper's extra surface re-creates crossings on rounding for several rounds:
    # the rounds after the first test near the faces the pass made; the result must be
    # what a whole test every round gives (this reference loop).
    from pathlib import Path

    import pytest

    from repair.clean import clean_soup, degenerate_mask, drop_unreferenced
    from repair.io import load_mesh
    from repair.topology import unique_faces

    path = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"
    path = path / "Ghostkeeper_extra_surface.stl"
    if not path.exists():
        pytest.skip("corpus not present")
    m = load_mesh(path)
    c = clean_soup(m.vertices, m.faces)
    v, f = c.vertices, c.faces
    assert len(f) >= LOCAL_REMESH_MIN_FACES
    got = hull.resolve(v, f)
    rv, rf, birth, rounds = v, f, np.arange(len(f)), 0
    for _ in range(4):
        rv, rf, b, n_pairs = _remesh(rv, rf)
        birth, rounds = birth[b], rounds + 1
        rv, rf = weld_exact(rv, rf)
        deg = degenerate_mask(rv, rf)
        keep = np.flatnonzero(~deg)
        keep = keep[unique_faces(rf[keep])]
        changed = len(keep) != len(rf)
        rf, birth = rf[keep], birth[keep]
        rv, rf = drop_unreferenced(rv, rf)
        if not changed and (n_pairs == 0 or not np.any(deg)):
            break
    assert rounds > 1
    assert _triangles(*got[:3]) == _triangles(rv, rf, birth)


def test_hull_taken_again_with_known_pairs_is_the_hull_taken_from_scratch():
    # finish's whole-mesh rerun hands the rounded mesh's crossing pairs on (hull_again):
    # the hull must be the one found without them, and the pairs it hands to the next
    # check must be all the crossings of the mesh it took the hull of.
    from repair.check import round_to_float32
    from repair.clean import clean_soup
    from repair.hull_and_thicken import hull_again, hull_and_thicken
    from repair.report import RepairTally

    v, f = concat(sphere(3, 10.0), sphere(3, 7.0, (9.3, 1.7, -2.1)))
    v32 = round_to_float32(v)
    pairs = intersecting_face_pairs(v32, f)
    assert len(pairs) > 0 and len(f) >= LOCAL_REMESH_MIN_FACES
    got_v, got_f, before = hull_again(v32, f, pairs, [], 0.4, RepairTally())
    c = clean_soup(v32, f, solid=True)
    ref_v, ref_f, _, _, _ = hull_and_thicken(c.vertices, c.faces, 0.4, RepairTally(), solid=True)
    assert np.array_equal(got_v, ref_v) and np.array_equal(got_f, ref_f)
    assert len(got_f) < len(f)  # the union dropped the faces inside the other sphere
    bv, bf, bp = before
    assert np.array_equal(bp, intersecting_face_pairs(bv, bf))
    assert hull_again(v32, f, None, [], 0.4, RepairTally())[2] is None


def test_arrangement_of_float32_input_scaled_to_integers_has_the_same_points():
    # CGAL's exact arithmetic is cheaper on integers: float32 coordinates are scaled by
    # a power of two that makes them integers, and the points scaled back are the very
    # doubles an unscaled arrangement gives; only each face's triangulation may differ.
    import igl.copyleft.cgal as cgal

    from repair.hull import _integer_scale, _remesh_all

    def face_areas(v, f):
        p = v[f]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    rng = np.random.default_rng(7)
    v = rng.uniform(0.0, 10.0, (90, 3)).astype(np.float32).astype(np.float64)
    f = np.arange(90).reshape(-1, 3)
    assert _integer_scale(v) > 0
    assert _integer_scale(v + 0.1) == 0  # 53 significant bits: no integer fits
    vv, ff, birth, n = _remesh_all(v, f)
    wv, wf, pairs, wb, im = cgal.remesh_self_intersections(v, f, stitch_all=True, cutoff=2**31 - 1)
    wf = np.asarray(im)[np.asarray(wf)]
    assert n == len(pairs) > 10
    assert np.array_equal(np.unique(vv, axis=0), np.unique(np.asarray(wv), axis=0))
    area = np.bincount(birth, face_areas(vv, ff), minlength=len(f))
    direct = np.bincount(np.asarray(wb), face_areas(np.asarray(wv), wf), minlength=len(f))
    assert np.allclose(area, direct, rtol=1e-12, atol=0)


def test_a_crossing_group_arranged_in_pieces_is_arranged_as_a_whole(monkeypatch):
    """A large group of crossing faces is arranged in pieces (halves of halves, each with
    the faces it crosses, keeping its own faces' pieces; side by side on the CPUs): the
    same faces, in the same order, on the same points as one call on the group -- on
    coordinates of few bits too, which libigl gets scaled to integers by the group's
    scale, not each piece's own."""
    a = sphere(3, 10.0)
    b = sphere(3, 7.0, (9.3, 1.7, -2.1))
    v, f = concat(a, b)
    v = np.round(v * 2.0**12) / 2.0**12  # few bits: an integer scale applies
    pairs = intersecting_face_pairs(v, f)
    group = np.unique(pairs)
    assert hull._integer_scale(v[np.unique(f[group])]) > 0
    monkeypatch.setattr(hull, "PIECE_FACES", 24)
    jobs = hull._pieces(v, f, group, pairs)
    assert len(jobs) >= 4
    kept = np.concatenate([given[keep] for given, keep, _ in jobs])
    assert np.array_equal(np.sort(kept), group)  # each face kept by one piece
    pv, pf, pb, n = _remesh(v, f)
    monkeypatch.setattr(hull, "PIECE_FACES", 10**9)
    assert len(hull._pieces(v, f, group, pairs)) == 1
    wv, wf, wb, wn = _remesh(v, f)
    assert n == wn and np.array_equal(pb, wb)
    pv, pf = weld_exact(pv, pf)
    wv, wf = weld_exact(wv, wf)
    assert np.array_equal(pv, wv) and np.array_equal(pf, wf)
