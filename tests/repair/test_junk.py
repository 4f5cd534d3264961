"""Internal junk: cavity shells thinner than a hair (near-zero volume, back-to-back
faces) are found by the winding number on both sides of their faces and removed; a real
cavity stays. Checked on the written float32 STL."""

from __future__ import annotations

import numpy as np
from mesh_helpers import box, concat, signed_volume

from repair.check import check_printable
from repair.io import load_mesh, write_stl
from repair.junk import face_winding_sides, failing_faces
from repair.pipeline import repair_file


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
