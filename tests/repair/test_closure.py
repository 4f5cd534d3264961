"""Shell closure (Bøhn & Wozny) on written float32 files: planar holes get exact lids,
non-planar ones minimal-area lids, open surfaces stay sheets."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_helpers import box, signed_volume

from repair.check import check_printable
from repair.closure import loop_lid
from repair.files import repair_file
from repair.holes import boundary_loops, close_small_holes
from repair.io import load_mesh, write_stl

EPS = 0.4


def _written(tmp_path, v, f, name="in.stl"):
    path = tmp_path / name
    write_stl(path, v, f)
    return path


@pytest.mark.parametrize("missing", [0, 5, 11])
def test_cube_missing_a_facet_comes_back_as_the_exact_cube(tmp_path, missing):
    v, f = box((0, 0, 0), (100, 100, 100))
    src = _written(tmp_path, v, np.delete(f, missing, axis=0))
    out = tmp_path / "out.stl"
    report = repair_file(src, out, epsilon=EPS)
    written = load_mesh(out)
    verdict = check_printable(written.vertices, written.faces)
    assert verdict.ok, verdict.failures()
    assert len(written.faces) == 12
    assert verdict.volume == 1e6
    # The same twelve triangles (as vertex sets) as the cube's.
    got = {frozenset(map(tuple, t)) for t in written.vertices[written.faces].tolist()}
    want = {frozenset(map(tuple, t)) for t in v[f].tolist()}
    assert got == want
    assert report["deviation"] == 0.0
    assert report["after"]["sheet_triangles_thickened"] == 0
    (lid,) = report["holes_closed"]["lids"]
    assert lid["planar"] and lid["planarity"] == 0.0
    assert lid["area"] == pytest.approx(5000.0)
    assert lid["perimeter"] == pytest.approx(200 + 100 * np.sqrt(2))


def test_planar_lid_of_a_concave_hole_is_a_valid_triangulation():
    # An L-shaped hole in the plane z = 0 (concave), in lid order (counter-clockwise).
    ring = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], float)
    v = np.c_[ring, np.zeros(len(ring))]
    lid = loop_lid(v, np.arange(len(ring)), len(v))
    assert lid.planar and len(lid.new_vertices) == 0 and len(lid.triangles) == 4
    p = v[lid.triangles]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(normals[:, 2] > 0)  # all turn the loop's way: none folds over
    assert lid.area == pytest.approx(4 * 1 + 2 * 1)  # exactly the L's area


def test_a_non_planar_hole_gets_a_minimal_area_lid():
    # A saddle-shaped loop: no triangulation of its vertices has less area, e.g. none of
    # the fans from one of its vertices.
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    v = np.c_[np.cos(t), np.sin(t), 0.3 * np.cos(2 * t)]
    lid = loop_lid(v, np.arange(12), 12)
    assert not lid.planar and len(lid.triangles) == 10 and len(lid.new_vertices) == 0
    fans = []
    for apex in range(12):
        p = np.roll(v, -apex, axis=0)
        fans.append(0.5 * np.linalg.norm(np.cross(p[1:-1] - p[0], p[2:] - p[0]), axis=1).sum())
    assert lid.area <= min(fans) + 1e-12 and lid.area < max(fans)


def test_a_flat_sheet_is_not_lidded_onto_itself():
    # A flat square sheet: its rim is planar and its faces lie in that plane, but facing
    # the other way from the lid (which would close it into a zero-volume pillow).
    v = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    _, out_f, holes = close_small_holes(v, f)
    assert holes.count == 0 and np.array_equal(out_f, f)


def test_box_with_a_missing_quad_in_a_wall_is_closed_exactly():
    # A finer box: each side split into a 4x4 grid; remove two triangles (one quad) from
    # the middle of a side: a planar square hole within the facet.
    import trimesh

    m = trimesh.creation.box(extents=(20, 20, 20))
    m = m.subdivide().subdivide()
    v, f = np.asarray(m.vertices), np.asarray(m.faces, np.int64)
    c = v[f].mean(axis=1)
    hole = np.flatnonzero((c[:, 2] > 9.99) & (np.abs(c[:, 0]) < 5) & (np.abs(c[:, 1]) < 5))
    open_f = np.delete(f, hole, axis=0)
    loops, _ = boundary_loops(open_f)
    assert len(loops) == 1
    out_v, out_f, holes = close_small_holes(v, open_f)
    assert holes.count == 1 and holes.facet_lids == 1 and len(out_v) == len(v)
    assert signed_volume(out_v, out_f) == pytest.approx(8000.0)
    assert check_printable(out_v, out_f).ok


def test_two_holes_touching_at_a_vertex_are_two_jordan_curves(tmp_path):
    # Two triangles of one vertex's fan removed, not sharing an edge: four boundary edges
    # meet at that vertex. Paired by turning round it, they are two triangular holes.
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    v, f = np.asarray(s.vertices), np.asarray(s.faces, np.int64)
    fan = np.flatnonzero((f == 0).any(axis=1))
    # Two faces of the fan with no edge in common (only vertex 0).
    a = fan[0]
    b = next(g for g in fan[1:] if len(set(f[a]) & set(f[g])) == 1)
    open_f = np.delete(f, [a, b], axis=0)
    loops, _ = boundary_loops(open_f)
    assert sorted(len(lp) for lp in loops) == [3, 3]
    assert all(0 in lp for lp in loops)
    src, out = tmp_path / "pinched.stl", tmp_path / "out.stl"
    write_stl(src, v, open_f)
    report = repair_file(src, out, epsilon=EPS)
    written = load_mesh(out)
    verdict = check_printable(written.vertices, written.faces)
    assert verdict.ok, verdict.failures()
    assert report["holes_closed"]["count"] == 2
    assert report["after"]["sheet_triangles_thickened"] == 0
    # The lids are the two missing triangles: the sphere comes back whole.
    assert len(written.faces) == len(f)
    assert verdict.volume == pytest.approx(signed_volume(v, f), rel=1e-6)


def _per_gap_measures(p: np.ndarray, normal: np.ndarray | None):
    """The triangles of each gap measured on their own, one numpy pass per gap."""
    from repair.closure import _tri_measures

    k = len(p)
    for gap in range(2, k):
        i = np.arange(k - gap)
        m = i[:, None] + np.arange(1, gap)[None, :]
        yield (gap, *_tri_measures(p[i][:, None], p[m], p[i + gap][:, None], normal))


@pytest.mark.parametrize("k", [5, 38, 160])
@pytest.mark.parametrize("planar", [True, False])
def test_gap_measures_taken_together_equal_those_taken_gap_by_gap(k, planar):
    """The lid's dynamic programme measures many gaps' triangles in one pass (in blocks,
    k = 160 spans several); every number must be the one a pass per gap gives."""
    from repair.closure import _gap_measures

    rng = np.random.default_rng(k)
    t = np.sort(rng.uniform(0.0, 2.0 * np.pi, k))
    radius = rng.uniform(5.0, 10.0, k)
    z = np.zeros(k) if planar else rng.normal(scale=2.0, size=k)
    p = np.c_[radius * np.cos(t), radius * np.sin(t), z] + 100.0
    normal = np.array([0.0, 0.0, 1.0]) if planar else None
    together = list(_gap_measures(p, normal))
    alone = list(_per_gap_measures(p, normal))
    assert [g for g, *_ in together] == [g for g, *_ in alone] == list(range(2, k))
    for (_, a1, q1), (_, a2, q2) in zip(together, alone, strict=True):
        assert a1.shape == a2.shape
        assert np.array_equal(a1, a2) and np.array_equal(q1, q2)
