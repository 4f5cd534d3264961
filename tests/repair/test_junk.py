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
