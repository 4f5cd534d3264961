"""Hairline slits (thinner than the two-sided winding probe) between walls of one shell
are found and filled: the output passes the winding test on every face, stays printable,
and moves by no more than the fill's reach."""

from __future__ import annotations

import numpy as np

from repair.check import check_printable
from repair.deviation import max_deviation
from repair.hairline import (
    FILL_REACH,
    MAX_ZIP_FACES,
    cut_and_lid,
    fold_suspects,
    hairline_failures,
    hairline_suspects,
    without_hairline_gaps,
)
from repair.holes import HolesClosed
from repair.junk import face_winding_sides, failing_faces, probe_distance
from repair.pipeline import repair_mesh
from repair.report import RepairOutcome, RepairTally
from repair.topology import weld_exact

#: Slot width: a float32 ulp or two at x = 5, under the probe distance of a 10 mm part.
GAP = 2.0**-20


def _solid(manifold) -> tuple[np.ndarray, np.ndarray]:
    mesh = manifold.to_mesh()
    v = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    return weld_exact(v, np.asarray(mesh.tri_verts, dtype=np.int64))


def _slotted_box():
    """A 10 mm cube with a slot GAP wide cut 8 mm deep from its side: one shell."""
    import manifold3d as m3d

    box = m3d.Manifold.cube([10, 10, 10])
    return box - m3d.Manifold.cube([GAP, 12, 8]).translate([5, -1, 3])


def _failing(v: np.ndarray, f: np.ndarray) -> int:
    outside, inside = face_winding_sides(v, f)
    return int(failing_faces(outside, inside).sum())


def test_slotted_box_fails_the_winding_test_and_the_suspects_find_every_failure():
    v, f = _solid(_slotted_box())
    assert check_printable(v, f).ok
    assert GAP < probe_distance(v)
    outside, inside = face_winding_sides(v, f)
    every = np.flatnonzero(failing_faces(outside, inside))
    assert len(every) > 0
    assert np.array_equal(np.sort(hairline_failures(v, f)), every)


def test_suspects_among_a_few_faces_are_those_of_the_whole_search():
    """Asked about a few faces of a large mesh, the search builds its tree on the faces
    near them only: the answer is the whole search's, restricted to them."""
    import manifold3d as m3d

    ball = m3d.Manifold.sphere(3.0, 256).translate([5.0, 5.0, 16.0])
    v, f = _solid(_slotted_box() + ball)
    every = hairline_suspects(v, f)
    assert len(every) > 0
    rng = np.random.default_rng(7)
    which = np.unique(np.r_[every[::2], rng.choice(len(f), len(f) // 10, replace=False)])
    assert 4 * len(which) <= len(f)  # the restricted search
    found = hairline_suspects(v, f, which)
    assert np.array_equal(np.sort(found), np.intersect1d(every, which))
    assert len(found) > 0


def test_filling_closes_the_slot_and_moves_the_surface_by_at_most_the_reach():
    v, f = _solid(_slotted_box())
    out = RepairOutcome(v, f, check_printable(v, f), "exact", 0.0, RepairTally(), HolesClosed())
    out = without_hairline_gaps(out, 0.4)
    assert out.verdict.ok
    assert check_printable(out.vertices, out.faces).ok
    assert _failing(out.vertices, out.faces) == 0
    section = out.sections["hairline_gaps"]
    assert section["faces_found"] > 0 and section["faces_left"] == 0
    reach = FILL_REACH * probe_distance(v)
    # Attene's D (output -> input): the fill lies within its reach of the walls.
    assert max_deviation(out.vertices, out.faces, v, f, np.zeros((0, 2, 3))) <= reach * 1.01


def test_repair_of_overlapping_shells_with_a_hairline_slot_passes_the_winding_test():
    import manifold3d as m3d

    sv, sf = _solid(_slotted_box())
    cv, cf = _solid(m3d.Manifold.cube([4, 4, 4]).translate([8, 8, 8]))
    v = np.vstack([sv, cv])
    f = np.vstack([sf, cf + len(sv)])
    result = repair_mesh(v, f, 0.4)
    rv, rf = result.vertices, result.faces
    assert check_printable(rv, rf).ok
    assert _failing(rv, rf) == 0
    assert result.report["hairline_gaps"]["faces_left"] == 0
    assert result.report["deviation"] <= FILL_REACH * probe_distance(rv) * 1.01


def test_fold_suspects_hold_every_failing_face_of_the_slotted_box():
    v, f = _solid(_slotted_box())
    outside, inside = face_winding_sides(v, f)
    every = np.flatnonzero(failing_faces(outside, inside))
    suspects = fold_suspects(v, f)
    assert len(suspects) < len(f)
    assert np.isin(every, suspects).all()


def test_cutting_out_the_slot_walls_and_lidding_the_holes_leaves_a_solid_that_passes():
    v, f = _solid(_slotted_box())
    cut = cut_and_lid(v, f, hairline_failures(v, f), 1)
    assert cut is not None
    cv, cf, gone = cut
    assert len(gone) > 0
    verdict = check_printable(cv, cf)
    assert verdict.ok, verdict.failures()
    assert _failing(cv, cf) == 0
    # The lids close the slot's mouth: the solid is the box less at most the slot.
    assert 1000.0 - 10 * 8 * GAP - 1e-9 <= verdict.volume <= 1000.0 + 1e-9


def _suspects_by_tree(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The definition, by one libigl distance query of every probe against every face."""
    import igl

    d = probe_distance(v)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    c = p.mean(axis=1)
    sq, nearest, _ = igl.point_mesh_squared_distance(np.vstack([c + d * n, c - d * n]), v, f)
    m = len(f)
    other = (nearest.reshape(2, m) != np.arange(m)) & (sq.reshape(2, m) < (0.999 * d) ** 2)
    return np.flatnonzero(other.any(axis=0) | (length[:, 0] == 0))


def test_flat_faces_searched_plane_by_plane_give_the_trees_suspects(monkeypatch):
    """A CAD-like model whose faces mostly lie in a few shared planes (the slotted box,
    its triangles split finer) and a ball above it (each face a plane of its own): the
    planes are searched plane by plane, the ball by the grid, and the suspects are
    exactly those of the whole tree -- the probes searched among disjoint slabs,
    compared with each plane, or sorted along each direction when its planes are
    many."""
    import manifold3d as m3d

    import repair.hairline as hairline
    import repair.probe_grid as probe_grid
    from repair.hairline import PLANE_MIN_MESH, _shared_planes, _unit_normals

    bv, bf = _solid(_slotted_box().refine(8))
    sv, sf = _solid(m3d.Manifold.sphere(2.0, 48).translate([2.5, 5.0, 12.5]))
    v, f = np.vstack([bv, sv]), np.vstack([bf, sf + len(bv)])
    assert len(f) >= PLANE_MIN_MESH
    plane = _shared_planes(v, f, *_unit_normals(v[f]))
    assert len(f) // 4 <= np.count_nonzero(plane >= 0) < len(f)  # both searches take part
    every = hairline_suspects(v, f)
    assert len(every) > 0
    assert np.array_equal(every, _suspects_by_tree(v, f))
    monkeypatch.setattr(probe_grid, "in_disjoint_slabs", lambda *a: None)  # each, then sorted
    assert np.array_equal(hairline_suspects(v, f), every)
    monkeypatch.setattr(hairline, "PLANE_SLAB_TESTS", 0)
    assert np.array_equal(hairline_suspects(v, f), every)


def test_a_large_mesh_is_cut_in_rounds_checked_near_the_cuts_and_then_passes():
    """Over MAX_ZIP_FACES faces the slot is looked for near thin folds only and cut out
    and lidded in rounds checked near the cuts (one local finish at the end): the
    result is printable, no face fails the winding test, and the solid gained at most
    the slot (the lids close its mouth)."""
    import manifold3d as m3d

    ball = m3d.Manifold.sphere(3.0, 384).translate([5.0, 5.0, 16.0])
    v, f = _solid(_slotted_box() + ball)
    assert len(f) > MAX_ZIP_FACES
    before = check_printable(v, f)
    found = _failing(v, f)
    assert found > 0
    out = RepairOutcome(v, f, before, "exact", 0.0, RepairTally(), HolesClosed())
    out = without_hairline_gaps(out, 0.4)
    verdict = check_printable(out.vertices, out.faces)
    assert verdict.ok, verdict.failures()
    assert _failing(out.vertices, out.faces) == 0
    section = out.sections["hairline_gaps"]
    assert section["faces_found"] == found and section["faces_left"] == 0
    assert set(section["rounds"]) == {"cut"}
    assert before.volume - 1e-9 <= verdict.volume <= before.volume + 10 * 8 * GAP + 1e-9


def _slotted_ball():
    """A ball (each face a plane of its own) with a slot GAP wide cut into it: walls of
    one shell a hair apart, curved where they meet the ball."""
    import manifold3d as m3d

    ball = m3d.Manifold.sphere(5.0, 96).translate([5.0, 5.0, 5.0])
    return _solid(ball - m3d.Manifold.cube([GAP, 12, 6]).translate([5, -1, 2]))


def test_the_grid_search_finds_the_trees_suspects_on_a_curved_mesh(monkeypatch):
    """Faces in no shared plane are searched in a grid of cells (probes against the faces
    listed in their cell, box, plane, then exact distance): the suspects are exactly
    those of one libigl distance query of every probe against every face; and the same
    when the grid gives way to the tree."""
    import repair.hairline as hairline
    import repair.probe_grid as probe_grid

    v, f = _slotted_ball()
    assert check_printable(v, f).ok
    d = probe_distance(v)
    p = v[f]
    n, length = hairline._unit_normals(p)
    assert np.all(hairline._shared_planes(v, f, n, length) < 0)
    idx = np.arange(len(f))
    c = p.mean(axis=1)
    q = np.vstack([c + d * n, c - d * n])
    assert probe_grid.probes_near_faces(v, f, idx, q, c, n, idx, d) is not None  # it ran
    every = hairline_suspects(v, f)
    assert len(every) > 0
    assert np.array_equal(every, _suspects_by_tree(v, f))
    monkeypatch.setattr(probe_grid, "GRID_PAIRS_PER_FACE", 0)
    assert probe_grid.probes_near_faces(v, f, idx, q, c, n, idx, d) is None
    assert np.array_equal(hairline_suspects(v, f), every)


def test_the_grid_searches_a_cylinder_of_long_slivers_in_cells_as_long_as_they_are():
    """A cylinder's sides are slivers as long as the part (Ghostkeeper_extra_surface's
    35 mm ones): cubic cells as large as the median face would hold all of them each, so
    the cells are as long as the faces along their axis and thin across. The grid then
    runs on them, and a slot cut along the cylinder is found exactly as by the tree."""
    import manifold3d as m3d

    import repair.probe_grid as probe_grid

    tube = m3d.Manifold.cylinder(35.0, 3.0, 3.0, 640)
    v, f = _solid(tube - m3d.Manifold.cube([GAP, 4, 30]).translate([-GAP / 2, 0, 2.5]))
    d = probe_distance(v)
    p = v[f]
    n, _ = probe_grid.unit_normals(p)
    sides = np.flatnonzero(np.abs(n[:, 2]) < 0.5)
    ext = np.ptp(p[sides], axis=1)
    assert np.median(ext[:, 2]) > 100 * np.median(ext[:, :2].max(axis=1))  # slivers
    idx = np.arange(len(f))
    c = p.mean(axis=1)
    q = np.vstack([c + d * n, c - d * n])
    assert probe_grid.probes_near_faces(v, f, sides, q, c, n, idx, d) is not None
    every = hairline_suspects(v, f)
    assert len(every) > 0
    assert np.array_equal(every, _suspects_by_tree(v, f))


def test_slivers_probed_clear_are_never_failing_and_the_rest_of_the_suspects_fail():
    """The winding test probes a sliver a tenth of its height off it: where no other face
    comes that near its probes it cannot fail, and is not tested. On slotted solids (the
    slot's floor and ends are slivers GAP wide; the ball's cuts leave slivers along the
    slot's mouth) some suspects are cleared, none of them failing, and the failures are
    those of the winding test of every face."""
    from repair.probe_grid import slivers_probed_clear

    for v, f in (_solid(_slotted_box()), _slotted_ball()):
        outside, inside = face_winding_sides(v, f)
        every = np.flatnonzero(failing_faces(outside, inside))
        suspects = hairline_suspects(v, f)
        clear = slivers_probed_clear(v, f, suspects, probe_distance(v))
        assert clear.any() and len(every) > 0
        assert not np.isin(suspects[clear], every).any()
        assert np.array_equal(np.sort(hairline_failures(v, f)), every)


def test_probes_in_disjoint_slabs_are_those_of_the_test_against_each_slab():
    """The plane search finds, per direction, the probes inside each plane's open slab:
    where the slabs are disjoint by one binary search per probe, the same pairs as the
    test of every probe against every slab; overlapping slabs are left to that test."""
    from repair.probe_grid import in_disjoint_slabs

    rng = np.random.default_rng(3)
    x = np.r_[rng.uniform(-1, 11, 5000), 0.5, 2.0, 2.5, 9.0]  # and on slab bounds
    lo = np.array([8.0, 0.5, 2.5, 4.0])
    hi = np.array([9.0, 2.0, 3.0, 7.5])
    i, j = in_disjoint_slabs(x, lo, hi)
    row, col = np.nonzero((x[None] > lo[:, None]) & (x[None] < hi[:, None]))
    assert len(i) > 100
    got = np.lexsort((j, i))
    want = np.lexsort((row, col))
    assert np.array_equal(i[got], col[want]) and np.array_equal(j[got], row[want])
    assert in_disjoint_slabs(x, np.r_[lo, 6.0], np.r_[hi, 8.5]) is None
