"""Attene's deviation D (repair.deviation): the local distance tree answers exactly as
the whole mesh would; faces that are input faces rounded to float32 are bounded by how
far rounding moved their corners."""

from __future__ import annotations

import numpy as np
import trimesh


def test_local_distance_tree_gives_the_same_distances_as_the_whole_mesh():
    import igl

    from repair.deviation import _point_mesh_d2

    m = trimesh.creation.icosphere(subdivisions=6, radius=20.0)  # 81920 triangles
    v, f = np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
    rng = np.random.default_rng(5)
    # Points near a small patch (the local tree answers), plus far ones (it must not).
    near = v[f[:300]].mean(axis=1) + rng.normal(scale=0.05, size=(300, 3))
    far = rng.normal(size=(20, 3)) * 3.0
    pts = np.vstack([near, far])
    want = igl.point_mesh_squared_distance(pts, v, f)[0]
    assert np.array_equal(_point_mesh_d2(pts, v, f), want)


def test_a_few_points_measured_on_the_faces_within_their_corner_reach_only():
    """A few sample points on a large mesh (counter's 60 on 84k faces): the tree is built
    on the faces within reach of their nearest corners, with the whole mesh's distances."""
    import igl

    from repair.deviation import _faces_within_vertex_reach, _point_mesh_d2

    m = trimesh.creation.icosphere(subdivisions=6, radius=20.0)  # 81920 triangles
    v, f = np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
    rng = np.random.default_rng(6)
    on = v[f[:30]].mean(axis=1) + rng.normal(scale=0.05, size=(30, 3))
    corner = v[f[40:45, 0]]  # exactly at a corner: reach 0 for these
    pts = np.vstack([on, corner, [[0.0, 0.0, 21.0], [3.0, -2.0, 18.5]]])
    near = _faces_within_vertex_reach(pts, v, f)
    assert near is not None and 0 < len(near) < len(f) // 10
    want = igl.point_mesh_squared_distance(pts, v, f)[0]
    assert np.array_equal(_point_mesh_d2(pts, v, f), want)


def test_faces_rounded_to_float32_are_bounded_by_their_corner_displacement():
    from repair.deviation import _point_mesh_d2, _surface_samples, max_deviation

    m = trimesh.creation.icosphere(subdivisions=4, radius=20.0)
    v, f = np.asarray(m.vertices) + 0.1, np.asarray(m.faces, dtype=np.int64)
    out = v.astype(np.float32).astype(np.float64)
    shift = np.linalg.norm(out - v, axis=1)
    assert shift.max() > 0
    d = max_deviation(out, f, v, f, max_points=0)
    assert d == shift.max()  # the bound, without sampling
    # Sampled distances of the rounded surface to the input stay within it.
    pts = _surface_samples(out, f, 8 * len(f))
    assert np.sqrt(_point_mesh_d2(pts, v, f).max()) <= d
    # A face that is not a rounded input face is still measured.
    moved = out.copy()
    moved[0] += 0.5 * (v[0] - 0.1) / 20.0  # out along the normal
    assert 0.45 <= max_deviation(moved, f, v, f) <= 0.5 + 1e-6


def _pieces(lift: float):
    """One input triangle (10 mm) and its four midpoint pieces lifted by ``lift`` mm."""
    v = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0]])
    f = np.array([[0, 1, 2]])
    m = np.array([[5.0, 0, 0], [5, 5, 0], [0, 5, 0]])
    ov = np.vstack([v, m]) + [0, 0, lift]
    of = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])
    return ov, of, v, f


def test_a_hint_bounds_pieces_of_input_faces_and_never_changes_the_answer():
    from repair.deviation import max_deviation

    # A lift at rounding scale: the hint bounds each piece by its corners' distance.
    for lift in (1e-6, 1e-3):  # below / above the hint's float32-rounding tolerance
        ov, of, v, f = _pieces(lift)
        plain = max_deviation(ov, of, v, f, max_points=0)
        right = max_deviation(ov, of, v, f, max_points=0, hint=np.zeros(4, dtype=np.int64))
        wrong = max_deviation(ov, of, v, f, max_points=0, hint=np.full(4, 7))  # no such face
        assert plain == right == wrong
        assert abs(right - lift) < 1e-12
    # A hint that points at the right face of a piece not lying on it is not trusted.
    ov, of, v, f = _pieces(0.0)
    ov[4, 2] = 0.25  # the middle corner lifted: pieces reach 0.25 mm off the input
    hinted = max_deviation(ov, of, v, f, max_points=0, hint=np.zeros(4, dtype=np.int64))
    assert hinted == max_deviation(ov, of, v, f, max_points=0) == 0.25


def test_point_triangle_distance_matches_libigl():
    import igl

    from repair.deviation import point_triangle_d2

    rng = np.random.default_rng(3)
    tri = rng.normal(size=(500, 3, 3))
    q = rng.normal(size=(500, 3)) * 2.0
    got = point_triangle_d2(q, tri[:, 0], tri[:, 1], tri[:, 2])
    for i in range(0, 500, 25):  # each point against its own triangle
        want = igl.point_mesh_squared_distance(q[i : i + 1], tri[i], np.array([[0, 1, 2]]))[0]
        assert abs(got[i] - want[0]) <= 1e-12 * max(1.0, want[0])


def test_exact_path_sources_are_pieces_of_their_input_faces_and_d_stays_bounded():
    """The exact path's per-face sources (the first outer hull's birth faces, carried to
    the faces the finish kept) name input faces the written faces lie on, so D bounds
    them without samples and stays between what the deterministic samples of every
    written face measure and the fully sampled D (up to float32 rounding)."""
    import igl
    from test_pipeline import klein_bottle  # self-crossing, one-sided: the exact path

    from repair.check import round_to_float32
    from repair.deviation import _within_input_faces, max_deviation
    from repair.finish import finish
    from repair.hull_and_thicken import hull_and_thicken
    from repair.provenance import hull_face_sources
    from repair.report import RepairTally

    v, f = klein_bottle()
    v = round_to_float32(v)
    tally = RepairTally()
    hv, hf, first_hull, birth, _ = hull_and_thicken(v, f, 0.4, tally)
    ov, of, verdict = finish(hv, hf, 0.4, tally)
    assert verdict.ok
    hint = hull_face_sources(v, f, v, f, first_hull, birth, ov, of)
    hinted = np.flatnonzero(hint >= 0)
    assert len(hinted) > 0.5 * len(of)
    on_source, _ = _within_input_faces(ov, of[hinted], v, f[hint[hinted]])
    assert on_source.all()
    plain = max_deviation(ov, of, v, f)
    with_hint = max_deviation(ov, of, v, f, hint=hint)
    p = ov[of]
    pts = np.vstack([ov, p.mean(axis=1), 0.5 * (p + p[:, [1, 2, 0]]).reshape(-1, 3)])
    sampled = float(np.sqrt(igl.point_mesh_squared_distance(pts, v, f)[0].max()))
    tol = 2.0**-21 * float(np.abs(ov).max())
    assert sampled <= with_hint <= max(plain, tol)


def test_samples_left_out_by_their_bounds_never_change_d():
    """D measures only the samples whose corner bounds reach the largest distance found
    (repair.deviation._max_sample_distance): on a thickened sheet -- the input's faces
    offset 0.2 mm, a few corners pushed farther -- and on a noisy copy it is exactly the
    largest distance of all the samples, measured one by one."""
    import igl

    from repair.deviation import _surface_samples, max_deviation

    m = trimesh.creation.icosphere(subdivisions=4, radius=20.0)  # 5120 triangles
    v, f = np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
    offset = v * (20.2 / 20.0)
    offset[[7, 300, 1500]] *= 1.05  # bumps: D is found near them, 1.2 mm out
    rng = np.random.default_rng(8)
    noisy = v + rng.normal(scale=0.05, size=v.shape)
    for out in (offset, noisy):
        for max_points in (0, 400_000):
            pts = _surface_samples(out, f, max_points)
            every = float(np.sqrt(igl.point_mesh_squared_distance(pts, v, f)[0].max()))
            assert max_deviation(out, f, v, f, max_points=max_points) == every
