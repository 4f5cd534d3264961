"""Closed bodies that cross one another are united by manifold3d before the exact
arrangement (repair.body_union); the result must be the one the exact arrangement of
everything gives."""

from __future__ import annotations

import numpy as np

import repair.body_union as body_union
from repair.check import check_printable, round_to_float32
from repair.hairline import hairline_failures
from repair.intersections import intersecting_face_pairs
from repair.junk import probe_distance
from repair.pipeline import repair_mesh
from tests.repair.broken_models import torus
from tests.repair.mesh_helpers import box, concat, signed_volume, sphere


def _bodies_and_a_sheet():
    """Four overlapping spheres, a spindle torus (closed, crossing itself) through two
    of them, and one open triangle through another; float32 values, as the repair
    hands them on."""
    spheres = [sphere(2, 5.0, c) for c in ((0, 0, 0), (6, 0, 0), (3, 5, 0), (3, 2, 4))]
    tv, tf = torus(3.0, 3.5, 24, 12)  # minor > major: the tube crosses itself
    sheet = (np.array([[-9.0, -1.0, 0.3], [-2.0, 1.5, 0.2], [-2.5, -2.0, 1.1]]),
             np.array([[0, 1, 2]]))  # fmt: skip
    v, f = concat(*spheres, (tv + [3.0, 1.0, 0.0], tf), sheet)
    return round_to_float32(v), f


def test_union_keeps_the_rest_and_leaves_crossings_only_with_it(monkeypatch):
    monkeypatch.setattr(body_union, "MIN_BODY_PAIRS", 1)
    v, f = _bodies_and_a_sheet()
    pairs = intersecting_face_pairs(v, f)
    torus_faces = np.arange(4 * 320, len(f) - 1)
    assert np.isin(pairs, torus_faces).all(axis=1).any()  # the torus crosses itself
    united = body_union.unite_closed_bodies(v, f, pairs)
    assert united is not None
    assert united.bodies == 5  # four spheres and the torus's outer hull
    assert len(united.birth) == len(united.faces)
    assert united.birth.min() >= 0 and united.birth.max() < len(f)
    sheet = len(f) - 1
    rows = np.flatnonzero(united.birth == sheet)
    assert len(rows) == 1 and np.array_equal(united.vertices[united.faces[rows[0]]], v[f[sheet]])
    # The union's own faces cross none of one another: every crossing left is the sheet's.
    assert len(united.pairs) and np.all((united.pairs == rows[0]).any(axis=1))
    assert np.array_equal(united.pairs, intersecting_face_pairs(united.vertices, united.faces))
    # Rounded to float32 (what is written) before the arrangement: finish rounds no more.
    assert np.array_equal(round_to_float32(united.vertices), united.vertices)
    assert not np.array_equal(np.unique(united.vertices, axis=0), np.unique(v, axis=0))


def test_repair_with_and_without_the_union_agree(monkeypatch):
    v, f = _bodies_and_a_sheet()
    monkeypatch.setattr(body_union, "MIN_BODY_PAIRS", 10**9)
    exact = repair_mesh(v, f, 0.4)
    monkeypatch.setattr(body_union, "MIN_BODY_PAIRS", 1)
    out = repair_mesh(v, f, 0.4)
    verdict = check_printable(out.vertices.astype(np.float32), out.faces)
    assert verdict.ok, verdict.failures()
    assert out.report["path"] == "exact"
    vol, ref = signed_volume(out.vertices, out.faces), signed_volume(exact.vertices, exact.faces)
    assert abs(vol - ref) <= 1e-5 * ref
    assert out.report["deviation"] <= 0.6 * 0.4


def _stacked_boxes():
    """Two boxes stacked on the plane z = 0.7, the upper one's bottom corners standing
    one or two float32 ulps above or below it (as exported points do), and a sphere
    through both; float32 values."""
    lower, upper = box((0.0, 0.0, 0.0), (1.0, 1.0, 0.7)), box((0.0, 0.0, 0.7), (1.0, 1.0, 1.3))
    uv = round_to_float32(upper[0])
    ulp = float(np.spacing(np.float32(0.7)))
    bottom = np.flatnonzero(uv[:, 2] == uv[:, 2].min())
    uv[bottom, 2] += ulp * np.array([1.0, -2.0, 2.0, -1.0])[: len(bottom)]
    v, f = concat(lower, (uv, upper[1]), sphere(2, 0.4, (0.5, 0.5, 0.7)))
    return round_to_float32(v), f


def test_snapping_moves_points_a_few_ulps_off_a_plane_onto_it():
    v, f = _stacked_boxes()
    reach = body_union.SNAP_REACH * probe_distance(v)
    snapped = body_union.snapped_coordinates(v, reach)
    on_plane = np.abs(v[:, 2] - 0.7) < 1e-6
    assert len(np.unique(v[on_plane, 2])) > 1
    assert np.all(snapped[on_plane, 2] == np.float64(np.float32(0.7)))
    assert np.abs(snapped - v).max() <= reach
    # The sphere's points, whose coordinates lie far apart, stay where they are.
    sphere_points = np.arange(16, len(v))
    assert np.array_equal(snapped[sphere_points][~on_plane[sphere_points]],
                          v[sphere_points][~on_plane[sphere_points]])  # fmt: skip


def test_bodies_stacked_a_few_ulps_apart_fuse_without_a_slit(monkeypatch):
    monkeypatch.setattr(body_union, "MIN_BODY_PAIRS", 1)
    v, f = _stacked_boxes()
    pairs = intersecting_face_pairs(v, f)
    failing = {}
    for reach in (0.0, body_union.SNAP_REACH):
        monkeypatch.setattr(body_union, "SNAP_REACH", reach)
        united = body_union.unite_closed_bodies(v, f, pairs)
        assert united is not None and len(united.pairs) == 0
        assert check_printable(united.vertices, united.faces).ok
        failing[reach] = len(hairline_failures(united.vertices, united.faces))
    assert failing[0.0] > 0  # unsnapped, the union keeps the slit between the boxes
    assert failing[body_union.SNAP_REACH] == 0
