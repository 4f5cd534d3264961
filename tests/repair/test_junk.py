"""Internal junk: cavity shells thinner than a hair (near-zero volume, back-to-back
faces) are found by the winding number on both sides of their faces and removed; a real
cavity stays. Checked on the written float32 STL."""

from __future__ import annotations

import numpy as np
from mesh_helpers import box, concat, signed_volume

from repair.check import check_printable
from repair.files import repair_file
from repair.io import load_mesh, write_stl
from repair.junk import face_winding_sides, failing_faces


def _inverted(v, f):
    return v, f[:, ::-1]


def _sliver_cavity():
    """An inverted flat box 2 x 2 mm and 1e-6 mm thick inside a 10 mm cube: a legal
    cavity of near-zero volume (about -4e-6 mm³)."""
    return _inverted(*box((4.0, 4.0, 5.0), (6.0, 6.0, 5.000001)))


def test_a_hair_thin_cavity_fails_the_two_sided_winding_test():
    v, f = concat(box((0, 0, 0), (10, 10, 10)), _sliver_cavity())
    assert check_printable(v, f).ok  # legal for the exact check...
    out, inside = face_winding_sides(v, f)
    bad = failing_faces(out, inside)
    assert not bad[:12].any()  # ...the cube's faces are fine
    # The sliver's broad faces see solid on both sides (its 1e-6 mm rims do not).
    p = v[f[12:]]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    assert area[bad[12:]].sum() > 0.99 * area.sum()


def test_the_repair_removes_thin_cavities_and_keeps_real_ones(tmp_path):
    real = _inverted(*box((2, 2, 2), (4, 4, 4)))
    v, f = concat(box((0, 0, 0), (10, 10, 10)), real, _sliver_cavity())
    src, dst = tmp_path / "in.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, dst, epsilon=0.4)
    w = load_mesh(dst)
    verdict = check_printable(w.vertices, w.faces)
    assert verdict.ok, verdict.failures()
    assert report["after"]["internal_junk_shells_removed"] == 1
    assert len(w.faces) == 24  # the cube and the real cavity
    assert np.isclose(signed_volume(w.vertices, w.faces), 1000.0 - 8.0)
    out, inside = face_winding_sides(w.vertices, w.faces)
    assert not failing_faces(out, inside).any()


def test_winding_sides_of_a_few_faces_of_a_large_mesh_see_a_slit_thinner_than_the_probe():
    """On a mesh of more than SPLIT_MIN_FACES faces, a few faces' winding sides are
    summed exactly over the faces near their probes and approximately over the rest:
    still right to the unit a hair off a face -- the walls of a slit 2^-20 mm wide see
    solid on both sides (1|1), every other face 0|1."""
    import manifold3d as m3d

    from repair.junk import SPLIT_MIN_FACES
    from repair.topology import weld_exact

    gap = 2.0**-20
    slotted = m3d.Manifold.cube([10, 10, 10]) - m3d.Manifold.cube([gap, 12, 8]).translate(
        [5, -1, 3]
    )
    ball = m3d.Manifold.sphere(3.0, 384).translate([5.0, 5.0, 16.0])
    mesh = (slotted + ball).to_mesh()
    v, f = weld_exact(np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3],
                      np.asarray(mesh.tri_verts, dtype=np.int64))  # fmt: skip
    assert len(f) >= SPLIT_MIN_FACES
    p = v[f]
    on_box = np.flatnonzero(p[:, :, 2].max(axis=1) <= 10.0)
    rng = np.random.default_rng(3)
    on_ball = rng.choice(np.flatnonzero(p[:, :, 2].min(axis=1) > 10.0), 100, replace=False)
    which = np.r_[on_box, on_ball]
    outside, inside = face_winding_sides(v, f, which)
    q = p[which]
    wall = ((np.abs(q[:, :, 0] - 5.0) <= gap).all(axis=1)
            & (np.ptp(q[:, :, 2], axis=1) > 1.0))  # fmt: skip
    assert wall.sum() >= 2
    assert np.array_equal(np.rint(outside), np.where(wall, 1.0, 0.0))
    assert np.all(np.rint(inside) == 1.0)
    assert np.array_equal(failing_faces(outside, inside), wall)


def _slit_box_on_the_bed(seed: int):
    """A 10 mm cube with a slot 0.4 probe distances wide cut 8 mm deep from its side,
    and a ball above it (2k faces: the fast winding path), turned at random and placed
    100-250 mm off the origin, as a part lies on a printer's bed (float32 ulps there are
    ~6 probe distances). Returns the mesh and which faces are the slot's two walls."""
    import manifold3d as m3d

    from repair.junk import probe_distance
    from repair.topology import weld_exact

    slot = m3d.Manifold.cube([1.0, 12.0, 8.0]).translate([5.0, -1.0, 3.0])
    ball = m3d.Manifold.sphere(3.0, 64).translate([5.0, 5.0, 16.0])
    mesh = (m3d.Manifold.cube([10.0, 10.0, 10.0]) - slot + ball).to_mesh()
    v, f = weld_exact(np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3],
                      np.asarray(mesh.tri_verts, dtype=np.int64))  # fmt: skip
    # Narrow the 1 mm slot in float64 (manifold3d's float32 could not hold it).
    gap = 0.4 * probe_distance(v)
    v[:, 0] = np.where(v[:, 0] >= 6.0, v[:, 0] - 1.0 + gap, v[:, 0])
    p = v[f]
    wall = (np.abs(p[:, :, 0] - 5.0) <= 2 * gap).all(axis=1) & (np.ptp(p[:, :, 2], axis=1) > 1.0)
    rng = np.random.default_rng(seed)
    turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return v @ turn.T + rng.uniform(100.0, 250.0, 3), f, wall


def test_a_slit_wall_fails_even_where_the_float32_sums_read_the_expected_value():
    """libigl's fast winding number sums in float32: off a part on the bed, a probe a hair
    past a slit's far wall can read 0 (it "did not cross" it) -- exactly the value a
    good face has. The two-sided test sums every probe some other face comes near
    exactly, so it finds all four wall faces; keeping the fast value wherever it read
    the expected one found 2 of them on these placements."""
    import igl

    from repair.junk import probe_distance

    fooled = 0
    for seed in (2, 3, 4):
        v, f, wall = _slit_box_on_the_bed(seed)
        assert check_printable(v, f).ok
        assert wall.sum() == 4
        outside, inside = face_winding_sides(v, f)
        assert np.array_equal(failing_faces(outside, inside), wall)
        # The trap: the float32 sums read 0|1 at some of the walls' failing probes.
        d = probe_distance(v)
        p = v[f[wall]]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        c = p.mean(axis=1)
        q = np.vstack([c + d * n, c - d * n])
        fast = igl.fast_winding_number(v, f, q)
        exact = np.r_[outside[wall], inside[wall]]
        expected = np.r_[np.zeros(4), np.ones(4)]
        fooled += int(np.sum((np.abs(fast - expected) <= 0.05) & (np.rint(exact) != expected)))
    assert fooled > 0


def test_only_probes_another_face_comes_near_can_read_other_than_0_and_1():
    """What the fast path rests on: on a printable mesh a probe's winding number (exact,
    libigl's float64 winding_number) differs from 0 outside / 1 inside only where some
    other face comes nearer to it than its own (repair.junk._crowded)."""
    import igl

    from repair.junk import _crowded, probe_distance

    v, f, wall = _slit_box_on_the_bed(3)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1)
    longest = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2).max(axis=1)
    d = np.minimum(probe_distance(v), 0.1 * length / longest)
    n /= length[:, None]
    c = p.mean(axis=1)
    q = np.vstack([c + d[:, None] * n, c - d[:, None] * n])
    owner = np.r_[np.arange(len(f)), np.arange(len(f))]
    crowded = _crowded(v, f, q, owner, np.r_[d, d])
    off = np.rint(igl.winding_number(v, f, q)) != np.r_[np.zeros(len(f)), np.ones(len(f))]
    assert off.any() and crowded.sum() < len(f) // 10
    assert not (off & ~crowded).any()
    assert wall[owner[off]].all()
