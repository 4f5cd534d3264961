"""Local mending of closed surfaces (repair.mend): exact arrangement of the crossing faces
only, winding-number choice of the pieces, float32 rounding that avoids new crossings."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_helpers import box, concat, signed_volume, sphere

from repair.check import check_printable
from repair.clean import clean_soup, degenerate_mask, net_faces
from repair.face_grid import FaceGrid
from repair.intersections import intersecting_face_pairs
from repair.mend import mend_intersections, separate_singular_edges, side_windings
from repair.rounding import (
    DIRECT_BOX_TESTS,
    _near,
    crossings_after_change,
    round_avoiding_crossings,
    round_finding_crossings,
)
from repair.topology import is_cycle, undirected_edges, weld_exact


def test_overlapping_cubes_become_their_exact_union():
    v, f = concat(box((0, 0, 0), (10, 10, 10)), box((5, 5, 5), (15, 15, 15)))
    assert len(intersecting_face_pairs(v, f)) > 0
    md = mend_intersections(v, f)
    assert md.pairs > 0 and md.pieces_dropped > 0
    assert is_cycle(md.faces)
    assert signed_volume(md.vertices, md.faces) == np.float64(1000 + 1000 - 125)
    out, left = round_avoiding_crossings(md.vertices, md.faces)
    assert left == 0
    verdict = check_printable(*weld_exact(out, md.faces))
    assert verdict.ok, verdict.failures()


def test_three_overlapping_cubes_at_odd_offsets_are_printable_after_rounding():
    # Offsets that are not representable: intersection points must be rounded.
    v, f = concat(
        box((0, 0, 0), (10, 10, 10)),
        box((3.1, 2.7, 4.3), (13.3, 12.9, 14.1)),
        box((-2.2, 6.6, 1.9), (7.7, 16.1, 8.8)),
    )
    v, f = weld_exact(v.astype(np.float32).astype(np.float64), f)
    for _ in range(6):
        md = mend_intersections(v, f)
        out, _ = round_avoiding_crossings(md.vertices, md.faces)
        v, f = weld_exact(out, md.faces)
        verdict = check_printable(v, f)
        if verdict.ok:
            break
    assert verdict.ok, verdict.failures()
    # The union is at least as big as the largest part and at most their sum.
    assert 1000.0 < verdict.volume < 3 * 1000.0
    assert abs(verdict.volume - signed_volume(v, f)) < 1e-9 * verdict.volume


def test_nested_cube_is_dropped_as_internal():
    v, f = concat(box((0, 0, 0), (10, 10, 10)), box((2, 2, 2), (4, 4, 4)))
    front, back = side_windings(v, f, np.arange(len(f)))
    outer, inner = slice(0, 12), slice(12, 24)
    assert np.all(front[outer] == 0) and np.all(back[outer] == 1)
    assert np.all(front[inner] == 1) and np.all(back[inner] == 2)


def test_net_faces_merges_copies_and_cancels_opposites():
    f = np.array([[0, 1, 2], [1, 2, 0], [3, 4, 5], [5, 4, 3], [6, 7, 8]])
    idx, w = net_faces(f)
    assert sorted(map(tuple, np.sort(f[idx], axis=1))) == [(0, 1, 2), (6, 7, 8)]
    assert dict(zip(map(int, idx), map(int, w), strict=True)) == {0: 2, 4: 1}


def test_is_cycle():
    v, f = box((0, 0, 0), (1, 1, 1))
    assert is_cycle(f)
    assert not is_cycle(f[1:])
    two = concat((v, f), (v, f))[1]
    assert is_cycle(two)


def test_rounding_keeps_representable_vertices_and_moves_others_one_ulp_at_most():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(50, 3)) * 10.0
    v[:25] = v[:25].astype(np.float32)
    f = np.array([[0, 1, 2]])
    out, left = round_avoiding_crossings(v, f)
    assert left == 0
    assert np.array_equal(out[:25], v[:25])
    assert np.array_equal(out.astype(np.float32).astype(np.float64), out)
    ulp = np.spacing(np.abs(v).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(out - v) <= ulp)


def _whole_test(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The crossing pairs one test of all the non-degenerate faces finds."""
    ok = np.flatnonzero(~degenerate_mask(v, f))
    return ok[intersecting_face_pairs(v, f[ok])]


def _two_crossing_spheres():
    return concat(sphere(3, 10.0), sphere(2, 6.0, (8.3, 1.7, -2.1)))


def test_rounding_reports_exactly_the_crossings_a_whole_test_finds():
    # Unmended crossings: rounding keeps trying other corners for their moved vertices
    # and re-tests only near them; the pairs it reports must still be all of them.
    v, f = _two_crossing_spheres()
    out, pairs = round_finding_crossings(v, f, max_tries=5)
    assert len(pairs) > 0
    assert np.array_equal(pairs, _whole_test(out, f))


def test_rounding_with_known_pairs_of_untouched_faces_finds_what_a_whole_test_finds():
    # A mesh checked once (float32 corners, all its crossings known), then changed in a
    # few places: only the region near the changed faces is tested again.
    v, f = _two_crossing_spheres()
    out, pairs = round_finding_crossings(v, f, max_tries=5)
    assert len(pairs) > 0
    rng = np.random.default_rng(4)
    moved = np.r_[np.unique(f[pairs[:3]].reshape(-1)), 11]
    v2 = out.copy()
    v2[moved] += rng.normal(scale=0.2, size=(len(moved), 3))  # not float32 values
    same = ~np.isin(f, moved).any(axis=1)
    kept = pairs[same[pairs].all(axis=1)]
    got_v, got = round_finding_crossings(v2, f, max_tries=5, known=(same, kept))
    assert np.array_equal(got_v[~np.isin(np.arange(len(v2)), moved)],
                          out[~np.isin(np.arange(len(v2)), moved)])  # fmt: skip
    assert np.array_equal(got, _whole_test(got_v, f))
    assert len(kept) > 0 and not np.array_equal(got, pairs)


def test_rounding_with_known_pairs_when_most_faces_changed_finds_what_a_whole_test_finds():
    # A union that cut a third or more of the faces (a CAD export's overlapping shells):
    # the untouched faces still keep their pairs, the changed ones are tested against
    # them and among themselves only.
    v, f = _two_crossing_spheres()
    out, pairs = round_finding_crossings(v, f, max_tries=5)
    rng = np.random.default_rng(6)
    moved = np.unique(np.r_[f[pairs].reshape(-1), rng.integers(0, len(v), len(v) // 6)])
    v2 = out.copy()
    v2[moved] += rng.normal(scale=0.05, size=(len(moved), 3))  # not float32 values
    same = ~np.isin(f, moved).any(axis=1)
    assert len(f) // 5 < np.count_nonzero(~same) < len(f) * 3 // 4
    kept = pairs[same[pairs].all(axis=1)]
    got_v, got = round_finding_crossings(v2, f, max_tries=5, known=(same, kept))
    assert np.array_equal(np.delete(got_v, moved, axis=0), np.delete(out, moved, axis=0))
    assert np.array_equal(got, _whole_test(got_v, f))
    assert len(got) > 0


def test_faces_near_a_few_changed_ones_are_exactly_those_whose_box_meets_one():
    # Few changed faces on a large mesh: found box against box, without a grid.
    v, f = concat(sphere(5, 10.0), sphere(4, 6.0, (8.3, 1.7, -2.1)))
    p = v[f]
    lo, hi = p.min(axis=1), p.max(axis=1)
    rng = np.random.default_rng(8)
    for k in (1, 5, 40):
        changed = np.zeros(len(f), dtype=bool)
        changed[rng.integers(0, len(f), k)] = True
        assert np.count_nonzero(changed) * len(f) <= DIRECT_BOX_TESTS
        which = np.flatnonzero(changed)
        near, grid = _near(v, f, changed, None)
        assert grid is None
        meets = (lo[None] <= hi[which, None]) & (hi[None] >= lo[which, None])
        assert np.array_equal(near, np.flatnonzero(meets.all(axis=2).any(axis=0)))
        assert np.isin(near, FaceGrid(v, f).near(which)).all()


def test_faces_near_many_changed_ones_of_a_small_mesh_are_exactly_those_whose_box_meets_one():
    # Many changed faces (a sixteenth or more): the faces touching them are taken without
    # a box test, the others tested box against box; the same faces either way. Over a
    # fifth changed, _near takes all faces (a superset) without testing boxes.
    from repair.rounding import TOUCH_FIRST, _boxes_meeting

    v, f = concat(sphere(3, 10.0), sphere(2, 6.0, (8.3, 1.7, -2.1)))
    p = v[f]
    lo, hi = p.min(axis=1), p.max(axis=1)
    rng = np.random.default_rng(3)
    for k in (len(f) // TOUCH_FIRST, len(f) // 4, len(f)):
        changed = np.zeros(len(f), dtype=bool)
        changed[rng.choice(len(f), k, replace=False)] = True
        which = np.flatnonzero(changed)
        assert TOUCH_FIRST * len(which) >= len(f)
        assert len(which) * len(f) <= DIRECT_BOX_TESTS
        near = _boxes_meeting(v, f, which)
        meets = (lo[None] <= hi[which, None]) & (hi[None] >= lo[which, None])
        assert np.array_equal(near, np.flatnonzero(meets.all(axis=2).any(axis=0)))
        assert len(near) < len(f) or k == len(f)
        got, grid = _near(v, f, changed, None)
        assert grid is None
        everything = len(which) > len(f) // 5
        assert np.array_equal(got, np.arange(len(f)) if everything else near)


def test_crossings_after_a_local_change_are_those_a_whole_test_finds():
    v, f = _two_crossing_spheres()
    before = _whole_test(v, f)
    # Move a few vertices of crossing faces (and one far away) a little, copy one face.
    rng = np.random.default_rng(2)
    moved = np.r_[np.unique(f[before[:5]].reshape(-1)), 7]
    v2 = v.copy()
    v2[moved] += rng.normal(scale=0.3, size=(len(moved), 3))
    f2 = np.vstack([f, f[before[0, 0]]])
    changed = np.isin(f2, moved).any(axis=1)
    changed[-1] = True
    kept = before[~changed[before].any(axis=1)]
    got = crossings_after_change(v2, f2, kept, changed)
    assert np.array_equal(got, _whole_test(v2, f2))
    assert len(got) > 0 and not np.array_equal(got, before)


def test_faces_near_holds_every_face_whose_box_meets_one_of_them():
    v, f = _two_crossing_spheres()
    p = v[f]
    lo, hi = p.min(axis=1), p.max(axis=1)
    rng = np.random.default_rng(5)
    for k in (1, 7, 60):
        which = np.unique(rng.integers(0, len(f), k))
        grid = FaceGrid(v, f)
        near = grid.near(which)
        meets = (lo[None] <= hi[which, None]) & (hi[None] >= lo[which, None])
        truth = np.flatnonzero(meets.all(axis=2).any(axis=0))
        assert np.isin(truth, near).all()
        assert len(near) < len(f)  # a region, not the whole mesh
        # Exactly the faces whose (slightly grown) box meets one of theirs.
        glo, ghi = grid.lo, grid.hi
        meets = (glo[None] <= ghi[which, None]) & (ghi[None] >= glo[which, None])
        assert np.array_equal(near, np.flatnonzero(meets.all(axis=2).any(axis=0)))


def test_faces_near_many_asked_faces_are_exactly_those_whose_box_meets_one():
    # Many asked faces over coarse cells: each asked face's cells are filtered by its own
    # box, not by all of them at once.
    v, f = sphere(5, 10.0)
    which = np.unique(np.random.default_rng(8).integers(0, len(f), 2000))
    grid = FaceGrid(v, f)
    near = grid.near(which)
    glo, ghi = grid.lo, grid.hi
    truth = np.zeros(len(f), dtype=bool)
    for s in range(0, len(which), 200):
        w = which[s : s + 200]
        truth |= ((glo[None] <= ghi[w, None]) & (ghi[None] >= glo[w, None])).all(axis=2).any(axis=0)
    assert np.array_equal(near, np.flatnonzero(truth))
    assert len(near) < len(f)
    assert np.array_equal(grid.near(which, chunk=1000), near)  # box-tested in chunks


def test_faces_near_many_asked_faces_over_coarse_cells_are_a_superset():
    # 2 % long slivers make the cells as large as the model: listing every asked face's
    # cells would list the mesh many times over, so the cells' faces are taken whole.
    v, f = sphere(4, 10.0)
    rng = np.random.default_rng(9)
    ends = rng.normal(size=(110, 2, 3)) * 10.0
    sv = np.concatenate([ends, ends[:, :1] + 0.01], axis=1).reshape(-1, 3)
    v = np.vstack([v, sv])
    f = np.vstack([f, len(v) - len(sv) + np.arange(len(sv)).reshape(-1, 3)])
    grid = FaceGrid(v, f)
    which = np.unique(rng.integers(0, 5120, 900))
    near = grid.near(which)
    glo, ghi = grid.lo, grid.hi
    meets = ((glo[None] <= ghi[which, None]) & (ghi[None] >= glo[which, None])).all(axis=2)
    truth = np.flatnonzero(meets.any(axis=0))
    assert np.isin(truth, near).all()
    assert len(near) > len(truth)  # the superset branch, not the exact one


def test_face_grid_handles_faces_far_larger_than_its_cells():
    v, f = _two_crossing_spheres()
    # Long slivers across the whole model, and one triangle larger than all of it.
    big_v = np.array([[-30.0, -30, -30], [40, -30, -30], [-30, 40, 30],
                      [-12.0, 0, 0], [20, 0.5, 0], [-12, 0.5, 0.1]])  # fmt: skip
    v = np.vstack([v, big_v])
    n = len(v) - 6
    f = np.vstack([f, [[n, n + 1, n + 2], [n + 3, n + 4, n + 5]]])
    p = v[f]
    lo, hi = p.min(axis=1), p.max(axis=1)
    grid = FaceGrid(v, f)
    assert len(grid.big) >= 1  # the triangle larger than 64 cells is tested box to box
    rng = np.random.default_rng(6)
    for which in (np.array([len(f) - 2]), np.array([len(f) - 1, 3]),
                  np.unique(rng.integers(0, len(f) - 2, 40))):  # fmt: skip
        near = grid.near(which)
        meets = (lo[None] <= hi[which, None]) & (hi[None] >= lo[which, None])
        assert np.isin(np.flatnonzero(meets.all(axis=2).any(axis=0)), near).all()
        glo, ghi = grid.lo, grid.hi  # and no more than the grown boxes meet
        meets = (glo[None] <= ghi[which, None]) & (ghi[None] >= glo[which, None])
        assert np.array_equal(near, np.flatnonzero(meets.all(axis=2).any(axis=0)))


def test_pole_triangles_collapsed_onto_an_edge_are_not_wires():
    v, f = box((0, 0, 0), (1, 1, 1))
    a, b = f[0, 0], f[0, 1]
    v2 = np.vstack([v, v[b]])  # a copy of vertex b: the extra face collapses onto edge ab
    f2 = np.vstack([f, [[a, b, len(v)]]])
    c = clean_soup(v2, f2)
    assert c.degenerate_removed == 1
    assert len(c.segments) == 0



def _cubes_touching_along_an_edge():
    # Two unit cubes sharing only the edge x = y = 1, welded: that edge has four faces.
    return weld_exact(*concat(box((0, 0, 0), (1, 1, 1)), box((1, 1, 0), (2, 2, 1))))


def test_cubes_touching_along_an_edge_get_an_edge_each():
    v, f = _cubes_touching_along_an_edge()
    before = check_printable(v, f)
    assert before.nonmanifold_edges == 1
    step = 1e-4
    sv, sf, n = separate_singular_edges(v, f, step)
    assert n == 1
    pr = check_printable(sv, sf, as_float32=True)
    assert pr.ok, pr.failures()
    assert pr.components == 2
    assert pr.volume == pytest.approx(2.0, abs=1e-3)
    # Only the copies of the shared edge's two vertices moved, each by `step` into its
    # own cube; every other corner is exactly where it was.
    moved = np.linalg.norm(sv - np.round(sv), axis=1) > 0
    assert moved.sum() == 4
    assert np.allclose(np.linalg.norm(sv[moved] - np.round(sv[moved]), axis=1), step)
    m = sv[moved]
    assert np.count_nonzero((m[:, 0] < 1) & (m[:, 1] < 1)) == 2  # into the first cube
    assert np.count_nonzero((m[:, 0] > 1) & (m[:, 1] > 1)) == 2  # into the second

def test_faces_around_an_edge_that_do_not_alternate_are_left_alone():
    v, f = _cubes_touching_along_an_edge()
    # Flip one cube: around the shared edge, orientations no longer alternate.
    f = f.copy()
    f[:12] = f[:12, ::-1]
    assert separate_singular_edges(v, f, 1e-4) is None


@pytest.mark.parametrize("first", [True, False])
def test_a_face_collapsed_onto_a_touching_edge_leaves_it_alone(first):
    # Two cubes touching along an edge, plus a face collapsed onto that edge (its third
    # corner is one of the edge's ends: no area, no side of the edge), listed first or
    # last among the faces around the edge. Its angle about the edge is undefined (it
    # was NaN, or 0 from rounding noise): no pairing of wedges can be trusted.
    v, f = _cubes_touching_along_an_edge()
    edges, uses = undirected_edges(f)
    a, b = edges[uses == 4][0]
    collapsed = np.array([[a, b, a]])
    f = np.vstack([collapsed, f]) if first else np.vstack([f, collapsed])
    with np.errstate(all="raise"):
        assert separate_singular_edges(v, f, 1e-4) is None
