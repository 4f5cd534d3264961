"""The local zip of hairline slits and blades (repair.zip): corners within the reach
merge, back-to-back faces cancel, the surface stays closed and oriented, moves by at
most the reach, and the written mesh passes the two-sided winding test."""

from __future__ import annotations

import numpy as np

from repair.check import check_printable
from repair.deviation import max_deviation
from repair.finish import finish
from repair.hairline import FILL_REACH, hairline_failures, without_hairline_gaps
from repair.holes import HolesClosed
from repair.junk import probe_distance
from repair.report import RepairOutcome, RepairTally
from repair.zip import closest_on_triangles, snap_onto_opposite, zip_hairline
from tests.repair.test_hairline import GAP, _failing, _slotted_box, _solid


def _blade_box():
    """Two 10 mm cubes side by side, GAP apart, joined by a bridge on top: the two facing
    walls are a slit; their corners face each other, their diagonals cross."""
    import manifold3d as m3d

    a = m3d.Manifold.cube([10, 10, 10])
    b = m3d.Manifold.cube([10, 10, 10]).translate([10 + GAP, 0, 0])
    bridge = m3d.Manifold.cube([4, 10, 2]).translate([8, 0, 9])
    return a + b + bridge


def test_merging_the_slit_walls_corners_and_mending_closes_the_slit():
    v, f = _solid(_slotted_box())
    assert check_printable(v, f).ok
    bad = hairline_failures(v, f)
    assert len(bad) > 0 and _failing(v, f) == len(bad)
    reach = FILL_REACH * probe_distance(v)
    zv, zf, shift = zip_hairline(v, f, bad, reach, guarded=False)
    zv, zf, verdict = finish(zv, zf, 0.4, RepairTally(), local_only=True)
    assert 0 < shift <= reach
    verdict = check_printable(zv, zf)
    assert verdict.ok, verdict.failures()
    assert _failing(zv, zf) == 0
    assert abs(verdict.volume - float(check_printable(v, f).volume)) < 1e-3


def test_zip_does_nothing_when_no_corners_are_within_reach():
    v, f = _solid(_slotted_box())
    bad = hairline_failures(v, f)
    assert zip_hairline(v, f, bad, GAP / 4) is None


def test_zip_leaves_walls_triangulated_differently_alone():
    # Merging corners of walls whose diagonals cross would leave edges of 3-4 faces.
    v, f = _solid(_blade_box())
    bad = hairline_failures(v, f)
    assert zip_hairline(v, f, bad, FILL_REACH * probe_distance(v)) is None


def test_hairline_gaps_closes_a_slit_between_walls_triangulated_differently():
    v, f = _solid(_blade_box())
    out = RepairOutcome(v, f, check_printable(v, f), "exact", 0.0, RepairTally(), HolesClosed())
    out = without_hairline_gaps(out, 0.4)
    assert check_printable(out.vertices, out.faces).ok
    assert _failing(out.vertices, out.faces) == 0
    section = out.sections["hairline_gaps"]
    assert section["rounds"] and section["faces_left"] == 0
    reach = FILL_REACH * probe_distance(v)
    assert max_deviation(out.vertices, out.faces, v, f, np.zeros((0, 2, 3))) <= reach * 1.01


def test_closest_point_on_triangles_matches_a_dense_sampling():
    rng = np.random.default_rng(7)
    tri = rng.normal(size=(40, 3, 3))
    q = rng.normal(size=(40, 3)) * 2
    got = closest_on_triangles(q, tri)
    w = rng.dirichlet(np.ones(3), size=20000)
    for i in range(len(q)):
        samples = w @ tri[i]
        best = np.linalg.norm(samples - q[i], axis=1).min()
        dist = np.linalg.norm(got[i] - q[i])
        assert dist <= best + 1e-12
        assert dist >= best - 0.05  # the sampling's resolution


def test_snap_moves_one_wall_onto_the_other_by_at_most_the_reach():
    v, f = _solid(_blade_box())
    bad = hairline_failures(v, f)
    reach = FILL_REACH * probe_distance(v)
    sv, moved = snap_onto_opposite(v, f, bad, reach)
    assert moved.any()
    shift = np.linalg.norm(sv - v, axis=1)
    assert shift.max() <= reach and np.all(shift[~moved] == 0)
    # The moved corners sit on the other wall: x = 10 + GAP or x = 10.
    x = sv[moved, 0]
    assert np.all(np.isclose(x, 10.0, atol=1e-12) | np.isclose(x, 10 + GAP, atol=1e-12))
    assert len(np.unique(np.round(v[moved, 0], 12))) == 1  # one wall moved
