"""check_printable on meshes whose verdict is known by construction."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest
import trimesh
from mesh_helpers import concat, sphere

import repair.intersections as intersections_mod
from repair.check import (
    check_printable,
    degenerate_face_mask,
    round_to_float32,
)
from repair.rows import unique_rows
from repair.topology import weld_exact
from repair.winding import winding_numbers


def box(lo=(0.0, 0.0, 0.0), hi=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-oriented axis-aligned box (8 vertices, 12 triangles), mm."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    m = trimesh.creation.box(bounds=np.array([lo, hi]))
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def test_closed_cube_passes():
    v, f = box()
    p = check_printable(v, f)
    assert p.ok, p.failures()
    assert p.failures() == []
    assert p.triangles == 12
    assert p.components == 1
    assert p.volume == pytest.approx(1.0, rel=1e-12)
    d = p.to_dict()
    assert d["ok"] is True and d["intersecting_pairs"] == 0 and d["boundary_edges"] == 0


def test_sphere_and_torus_pass():
    for m in (
        trimesh.creation.icosphere(subdivisions=4, radius=10.0),
        trimesh.creation.torus(20.0, 5.0, major_sections=64, minor_sections=32),
    ):
        p = check_printable(m.vertices, m.faces)
        assert p.ok, p.failures()
        assert p.volume == pytest.approx(m.volume, rel=1e-9)


def test_cube_with_a_face_removed_is_not_closed():
    v, f = box()
    p = check_printable(v, f[1:])
    assert not p.ok
    assert not p.closed
    assert p.boundary_edges == 3
    assert any("not closed" in s for s in p.failures())


def test_one_flipped_face_is_misoriented():
    v, f = box()
    f = f.copy()
    f[4] = f[4][::-1]
    p = check_printable(v, f)
    assert not p.oriented and not p.ok
    assert p.misoriented_edges == 3
    assert p.closed and p.edge_manifold


def test_all_faces_flipped_has_negative_volume():
    v, f = box(hi=(2.0, 3.0, 4.0))
    p = check_printable(v, f[:, ::-1])
    assert p.closed and p.oriented and p.edge_manifold
    assert p.volume == pytest.approx(-24.0)
    assert not p.positive_volume and not p.ok
    assert any("volume" in s for s in p.failures())


def test_interpenetrating_cubes_self_intersect():
    v, f = concat(box(), box((0.5, 0.5, 0.5), (1.5, 1.5, 1.5)))
    p = check_printable(v, f)
    # Each shell is closed and oriented on its own: only the intersection test catches it.
    assert p.closed and p.edge_manifold and p.oriented and p.positive_volume
    assert not p.no_self_intersections and not p.ok
    assert p.intersecting_pairs > 0
    assert p.components == 2


def test_disjoint_and_nested_shells():
    # Two separate cubes: printable, two components.
    v, f = concat(box(), box((3, 0, 0), (4, 1, 1)))
    p = check_printable(v, f)
    assert p.ok and p.components == 2 and p.volume == pytest.approx(2.0)
    assert p.shells_outward is True and p.misnested_shells == 0
    # The shell of each face comes with the verdict (not in its JSON form).
    assert p.shells.tolist() == [0] * 12 + [1] * 12
    assert "shells" not in p.to_dict()
    # A hollow box (inner shell inverted) is a legitimate solid with a cavity.
    vi, fi = box((1, 1, 1), (2, 2, 2))
    v, f = concat(box((0, 0, 0), (3, 3, 3)), (vi, fi[:, ::-1]))
    p = check_printable(v, f)
    assert p.ok, p.failures()
    assert p.volume == pytest.approx(26.0)


def test_shells_must_face_outward_and_not_nest():
    big = box((0, 0, 0), (10, 10, 10))
    vs, fs = box((20, 0, 0), (21, 1, 1))
    # A separate inverted shell: total volume still positive, but it is not a solid.
    p = check_printable(*concat(big, (vs, fs[:, ::-1])))
    assert p.volume == pytest.approx(999.0) and p.positive_volume
    assert p.shells_outward is False and p.misnested_shells == 1 and not p.ok
    assert any("inverted or nested" in s for s in p.failures())
    # An outward shell nested inside a solid (double material): also refused.
    vi, fi = box((2, 2, 2), (3, 3, 3))
    p = check_printable(*concat(big, (vi, fi)))
    assert p.misnested_shells == 1 and not p.ok
    # A solid island inside a cavity inside a solid is fine (winding 0 / 1 / 0).
    vc, fc = box((1, 1, 1), (9, 9, 9))
    p = check_printable(*concat(big, (vc, fc[:, ::-1]), (vi, fi)))
    assert p.ok, p.failures()
    assert p.components == 3 and p.misnested_shells == 0
    # Not assessed when the surface is open: the winding number means nothing there.
    v, f = box()
    p = check_printable(v, f[1:])
    assert p.shells_outward is None and p.misnested_shells is None


def test_touching_unwelded_cubes_count_as_intersecting():
    # Face-to-face contact between separate shells is a self-contact, not a solid.
    v, f = concat(box(), box((1, 0.25, 0.25), (2, 0.75, 0.75)))
    p = check_printable(v, f)
    assert not p.no_self_intersections


def test_fold_across_a_shared_edge_counts_as_intersecting():
    # Two triangles on a shared edge, coplanar and overlapping: a fold.
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0]], float)
    p = check_printable(v, np.array([[0, 1, 2], [1, 0, 3]]))
    assert p.intersecting_pairs == 1
    # The same pair hinged properly along the shared edge does not intersect.
    v[3] = (0.3, -0.3, 0.0)
    assert check_printable(v, np.array([[0, 1, 2], [1, 0, 3]])).intersecting_pairs == 0


def cube_with_sliver():
    """A closed cube whose edge a-b has its midpoint m on one side only, patched by the
    zero-area face (a, b, m): closed, manifold, oriented, but with one degenerate face."""
    v, f = box()
    # find a face (a, b, c) and its neighbour across edge (a, b)
    a, b, c = f[0]
    nb = [i for i in range(1, 12) if {a, b} <= set(f[i])][0]
    m = len(v)
    v = np.vstack([v, 0.5 * (v[a] + v[b])])
    f = np.vstack([np.delete(f, 0, axis=0), [[a, m, c], [m, b, c], [a, b, m]]])
    assert nb >= 1
    return v, f


def test_degenerate_face_fails():
    v, f = cube_with_sliver()
    p = check_printable(v, f)
    assert p.closed and p.edge_manifold and p.oriented and p.positive_volume
    assert p.degenerate_faces == 1 and not p.no_degenerate_faces and not p.ok
    # Without the sliver, m is a T-junction: both halves touch the unsplit neighbour
    # face at m, beyond the vertex they share with it, which is a contact.
    assert p.intersecting_pairs == 2


def test_repeated_index_face_is_degenerate():
    v, f = box()
    p = check_printable(v, np.vstack([f, [[0, 0, 1]]]))
    assert p.degenerate_faces == 1 and not p.ok


def test_degeneracy_is_decided_exactly():
    a = np.array([0.1, 0.2, 0.3])
    # 0, a, 2a, 4a are exactly collinear in doubles (scaling by 2 is exact)...
    v = np.array([a, 2 * a, 4 * a, 4 * a])
    # ... and nudging one coordinate by one ulp makes the triangle proper.
    v[3, 2] = np.nextafter(v[3, 2], 1.0)
    mask = degenerate_face_mask(v, np.array([[0, 1, 2], [0, 1, 3]]))
    assert mask.tolist() == [True, False]
    # Tiny but proper triangles far from the origin are not degenerate.
    big = 1e6
    v = np.array([[big, big, big], [big + 1e-9, big, big], [big, big + 1e-9, big]])
    assert degenerate_face_mask(v, np.array([[0, 1, 2]])).tolist() == [False]


def test_duplicate_faces_fail():
    # Two back-to-back copies of one triangle: closed, oriented, zero volume, and the
    # exact intersection test skips combinatorial duplicates, so it is counted here.
    v, f = box()
    tri = np.array([[0, 1, 2], [0, 2, 1]]) + len(v)
    v2 = np.vstack([v, [[5, 0, 0], [6, 0, 0], [5, 1, 0]]])
    p = check_printable(v2, np.vstack([f, tri]))
    assert p.duplicate_faces == 1 and not p.ok


def test_float32_rounding_can_create_an_intersection():
    # A second box 1e-9 mm away from the first: separate in doubles, but float32 has a
    # spacing of ~1.2e-7 at 1.0, so the written file has the boxes touching.
    v, f = concat(box(), box((1 + 1e-9, 0.25, 0.25), (2, 0.75, 0.75)))
    exact = check_printable(v, f)
    assert exact.ok, exact.failures()
    written = check_printable(v, f, as_float32=True)
    assert written.float32
    assert not written.ok and not written.no_self_intersections
    # the helper gives the same rounded coordinates
    assert round_to_float32(v)[9, 0] == 1.0


def test_float32_weld_merges_collapsed_vertices():
    v = np.array([[1.0, 0, 0], [1.0 + 1e-12, 0, 0], [0, 1.0, 0]])
    uv, uf = weld_exact(round_to_float32(v), np.array([[0, 1, 2]]))
    assert len(uv) == 2
    assert uf[0, 0] == uf[0, 1]
    # -0.0 and +0.0 are the same point
    uv, _ = weld_exact(np.array([[0.0, 0, 0], [-0.0, 0, 0]]), np.array([[0, 1, 1]]))
    assert len(uv) == 1


def test_empty_and_malformed_input():
    p = check_printable(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    assert not p.ok and p.triangles == 0 and p.failures()
    with pytest.raises(ValueError):
        check_printable(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(ValueError):
        check_printable(np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))


def test_large_clean_mesh_passes():
    m = trimesh.creation.torus(10.0, 3.0, major_sections=500, minor_sections=250)
    assert len(m.faces) == 250_000
    p = check_printable(m.vertices, m.faces, as_float32=True)
    assert p.ok, p.failures()
    assert p.components == 1


def _crossing_spheres():
    return concat(sphere(4, 10.0), sphere(3, 6.0, (8.3, 1.7, -2.1)))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="slabs run in forked processes")
def test_slabs_tested_side_by_side_find_the_pairs_one_test_finds():
    v, f = _crossing_spheres()
    one = unique_rows(np.sort(intersections_mod._pairs(v, f), axis=1))
    assert len(one) > 100
    for k in (2, 3, 4):
        slabs = unique_rows(np.sort(intersections_mod._pairs_in_slabs(v, f, k), axis=1))
        assert np.array_equal(slabs, one)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="slabs run in forked processes")
def test_a_slab_whose_worker_dies_is_tested_again_in_the_parent(monkeypatch):
    v, f = _crossing_spheres()
    one = unique_rows(np.sort(intersections_mod._pairs(v, f), axis=1))
    parent = os.getpid()
    real = intersections_mod._pairs

    def dies_in_children(vv, ff):
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)  # the worker dies (no core file)
        return real(vv, ff)

    monkeypatch.setattr(intersections_mod, "_pairs", dies_in_children)
    slabs = unique_rows(np.sort(intersections_mod._pairs_in_slabs(v, f, 3), axis=1))
    assert np.array_equal(slabs, one)


def test_winding_numbers_agree_with_libigl():
    import igl

    v, f = _crossing_spheres()
    rng = np.random.default_rng(4)
    q = rng.normal(scale=9.0, size=(40, 3))
    want = igl.winding_number(v, f, q)
    got = winding_numbers(v, f, q)
    assert np.allclose(got, want, atol=1e-9)
    inside = winding_numbers(v, f[:, ::-1], np.zeros((1, 3)))
    assert np.isclose(inside[0], -1.0)


@pytest.mark.parametrize("n", [60, 2100])  # a box-probe table, then a k-d tree
def test_one_shell_nested_among_many_is_found(n):
    parts = [box((3.0 * i, 3.0 * j, 0.0), (3.0 * i + 2, 3.0 * j + 2, 2.0))
             for i in range(50) for j in range((n + 49) // 50)][:n]  # fmt: skip
    v, f = concat(*parts)
    p = check_printable(v, f)
    assert p.ok and p.components == n
    v2, f2 = concat((v, f), box((3.5, 3.5, 0.5), (4.5, 4.5, 1.5)))  # inside box (1, 1)
    p = check_printable(v2, f2)
    assert not p.ok and p.misnested_shells == 1


@pytest.mark.parametrize("k", [2, 3, 4])
def test_slab_cuts_give_every_slab_about_as_many_faces(k):
    from repair.intersections import _even_cuts

    rng = np.random.default_rng(k)
    lo = rng.normal(size=3000) * 10.0
    hi = lo + np.abs(rng.normal(size=3000)) * rng.uniform(0.0, 4.0, size=3000)  # mixed sizes
    e = np.r_[-np.inf, _even_cuts(lo, hi, k), np.inf]
    inside = [(lo < e[i + 1]) & (hi >= e[i]) for i in range(k)]
    assert np.logical_or.reduce(inside).all()  # every face is tested somewhere
    counts = [int(s.sum()) for s in inside]
    assert max(counts) - min(counts) <= 0.02 * max(counts)


@pytest.mark.parametrize("k", [2, 3])
def test_slab_cuts_leave_the_first_slab_lighter_by_its_process_other_work(k):
    # head: the process testing slab 0 has other work worth 10 % of the faces (the
    # finish's test of the faces apart): slab 0 holds that many fewer, the others
    # about as many each, and every face is still tested somewhere.
    from repair.intersections import _even_cuts

    rng = np.random.default_rng(10 + k)
    lo = rng.normal(size=3000) * 10.0
    hi = lo + np.abs(rng.normal(size=3000)) * rng.uniform(0.0, 4.0, size=3000)
    e = np.r_[-np.inf, _even_cuts(lo, hi, k, 0.1), np.inf]
    inside = [(lo < e[i + 1]) & (hi >= e[i]) for i in range(k)]
    assert np.logical_or.reduce(inside).all()
    counts = [int(s.sum()) for s in inside]
    rest = counts[1:]
    assert max(rest) - min(rest) <= 0.02 * max(rest)
    assert abs(min(rest) - counts[0] - 300) <= 0.02 * max(rest)
