"""repair.pending_pairs: the intersection test started in forked children gives the pairs
of a test in one process; the check calls ``unwanted`` only on a mesh that is not
printable before the test decides, and the repair's surface features found beside the
check are those the surface stage finds afterwards."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plate_model as plate  # noqa: E402
from mesh_helpers import concat, sphere  # noqa: E402

from repair.check import check_printable, check_printable_pairs, round_to_float32  # noqa: E402
from repair.intersections import PARALLEL_MIN_FACES, _pairs, intersecting_face_pairs  # noqa: E402
from repair.pending_pairs import BACKGROUND_MIN_FACES, start_face_pairs  # noqa: E402
from repair.pipeline import repair_mesh  # noqa: E402
from repair.rows import unique_rows  # noqa: E402
from repair.surface.features import refine_surfaces  # noqa: E402
from repair.surface.stage import features_of  # noqa: E402
from repair.workers import cpu_workers  # noqa: E402


def test_pairs_started_in_children_are_those_of_one_whole_test():
    v, f = concat(sphere(6, 10.0), sphere(5, 8.0, centre=(6.0, 1.0, 0.5)))  # crossing
    assert len(f) >= BACKGROUND_MIN_FACES
    pending = start_face_pairs(v, f)
    assert pending.running == (cpu_workers() > 1)
    found = pending.result()
    whole = unique_rows(np.sort(_pairs(v, f), axis=1))  # one libigl test, one process
    assert len(whole) > 100
    assert np.array_equal(found, whole)
    assert np.array_equal(found, intersecting_face_pairs(v, f))
    assert not pending.running and pending.result() is found


def test_a_mid_sized_test_forks_its_other_slabs_at_once_and_tests_slab_0_when_asked():
    v, f = concat(sphere(4, 10.0), sphere(4, 8.0, centre=(6.0, 1.0, 0.5)))  # crossing
    assert PARALLEL_MIN_FACES <= len(f) < BACKGROUND_MIN_FACES
    pending = start_face_pairs(v, f)
    assert pending.running == (cpu_workers() > 1)
    found = pending.result()
    whole = unique_rows(np.sort(_pairs(v, f), axis=1))  # one libigl test, one process
    assert len(whole) > 50
    assert np.array_equal(found, whole)
    assert not pending.running and pending.result() is found
    # Cancelled before it is asked (the check found a copy of a face): nothing is left
    # running, and the check's test without the copy finds the same pairs.
    started = start_face_pairs(v, f)
    started.cancel()
    assert not started.running
    verdict, pairs = check_printable_pairs(v, np.vstack([f, f[:1]]))
    assert verdict.duplicate_faces == 1 and np.array_equal(np.sort(pairs, axis=1), whole)


def test_unwanted_is_called_only_when_the_mesh_is_not_printable_but_for_the_test():
    v, f = sphere(6, 10.0)  # 81920 faces, closed
    assert len(f) >= BACKGROUND_MIN_FACES
    calls: list[int] = []
    verdict, pairs = check_printable_pairs(v, f, unwanted=lambda: calls.append(1))
    assert verdict.ok and len(pairs) == 0 and calls == []
    # Two crossing spheres: printable but for the test; only the verdict says no.
    v2, f2 = concat((v, f), sphere(4, 10.0, centre=(5.0, 0.0, 0.0)))
    verdict, pairs = check_printable_pairs(v2, f2, unwanted=lambda: calls.append(1))
    assert not verdict.ok and verdict.intersecting_pairs == len(pairs) > 0 and calls == []
    # A hole: the edge census already says no.
    verdict, _ = check_printable_pairs(v, f[1:], unwanted=lambda: calls.append(1))
    assert not verdict.closed and calls == [1]
    # A copy of a face: said before the census.
    calls.clear()
    verdict, _ = check_printable_pairs(v, np.vstack([f, f[:1]]), unwanted=lambda: calls.append(1))
    assert verdict.duplicate_faces == 1 and calls == [1]


def test_surface_found_beside_the_check_is_what_the_stage_finds_after_it():
    # A coarse plate with holes beside a fine ball: large enough to be tested in children.
    pv, pf = plate.plate(24)
    v, f = concat((pv, pf), sphere(6, 10.0, centre=pv.max(axis=0) + 20.0))
    assert len(f) >= BACKGROUND_MIN_FACES and check_printable(v, f, as_float32=True).ok
    result = repair_mesh(v, f, 0.4, surface="holes")
    after = refine_surfaces(round_to_float32(v), f, epsilon=0.4, mode="holes")
    assert after.changed and result.report["surface"]["features"]
    assert np.array_equal(result.vertices, round_to_float32(after.vertices))
    assert np.array_equal(result.faces, after.faces)
    assert result.report["surface"] == after.to_dict()
    assert check_printable(result.vertices, result.faces, as_float32=True).ok


def test_a_test_started_on_faces_the_check_must_not_test_starts_again_without_them():
    v, f = concat(sphere(6, 10.0), sphere(5, 8.0, centre=(6.0, 1.0, 0.5)))
    proper = intersecting_face_pairs(v, f)
    # A copy of face 0 and a face with a repeated corner: the test must not see them.
    with_bad = np.vstack([f, f[:1], [[f[1, 0], f[1, 0], f[1, 1]]]])
    verdict, pairs = check_printable_pairs(v, with_bad)
    assert verdict.duplicate_faces == 1 and verdict.degenerate_faces == 1
    assert np.array_equal(np.sort(pairs, axis=1), proper) and len(proper) > 100


def test_features_found_ahead_stop_on_an_open_mesh_and_are_the_search_on_a_closed_one():
    v, f = plate.plate(12)
    v32 = round_to_float32(v)
    ahead = features_of(v32, f, 0.4, "holes", closed_only=True)
    search = features_of(v32, f, 0.4, "holes")
    assert ahead and [(s.kind, g.tolist()) for s, g in ahead] == [
        (s.kind, g.tolist()) for s, g in search
    ]
    # One face less: an edge used once, never printable, so never unchanged: nothing found.
    assert features_of(v32, f[1:], 0.4, "holes", closed_only=True) is None
    assert features_of(v32, f[1:], 0.4, "holes")  # without the flag the search runs
