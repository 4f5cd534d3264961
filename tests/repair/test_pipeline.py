"""Known-answer cases for the as-exact-as-possible repair (repair.pipeline)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mesh_helpers import box, concat, signed_volume

from repair.check import check_printable
from repair.pipeline import RepairError, repair_mesh

EPS = 0.4


def assert_printable(res):
    pr = check_printable(res.vertices.astype(np.float32), res.faces)
    assert pr.ok, pr.failures()
    assert res.report["printable"]["ok"]
    json.dumps(res.report)  # serialisable


def test_already_printable_is_unchanged():
    v, f = box()
    res = repair_mesh(v, f, EPS)
    assert res.report["path"] == "unchanged"
    assert np.array_equal(res.faces, f)
    assert np.array_equal(res.vertices[res.faces], v[f])
    assert res.report["deviation"] == 0.0


def test_float64_input_is_repaired_on_its_float32_rounding_and_d_counts_it():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    v, f = np.asarray(s.vertices) + 0.1, np.asarray(s.faces, dtype=np.int64)
    shift = np.linalg.norm(v.astype(np.float32).astype(np.float64) - v, axis=1).max()
    assert shift > 0
    res = repair_mesh(v, f, EPS)  # printable as it is: unchanged, but rounded
    assert res.report["path"] == "unchanged"
    assert np.array_equal(res.vertices, v.astype(np.float32).astype(np.float64))
    assert res.report["deviation"] == shift
    # Two overlapping copies: the union, with D the rounding (the union's surface lies on
    # the rounded input).
    v2, f2 = concat((v, f), (v + (7.3, 0.0, 0.0), f))
    res = repair_mesh(v2, f2, EPS)
    assert res.report["path"] == "union"
    assert_printable(res)
    shift2 = np.linalg.norm(v2.astype(np.float32).astype(np.float64) - v2, axis=1).max()
    assert shift2 <= res.report["deviation"] <= shift2 + 1e-5


def test_overlapping_closed_parts_give_the_exact_union():
    import manifold3d as m3d

    a = box((0, 0, 0), (2, 2, 2))
    b = box((1, 1, 1), (3, 3.5, 3))
    v, f = concat(a, b)
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    want = m3d.Manifold.batch_boolean(
        [m3d.Manifold.cube((2, 2, 2)), m3d.Manifold.cube((2, 2.5, 2)).translate((1, 1, 1))],
        m3d.OpType.Add,
    ).volume()
    assert res.report["volume"] == pytest.approx(want, rel=1e-9)
    # The union keeps the input's triangles, cut where the shells cross; where a cut
    # meets a triangle's diagonal (z = 1.8) the new corner is rounded to float32.
    assert res.report["deviation"] < 1e-7
    assert res.report["after"]["components"] == 1
    # Every written face is a piece of one input triangle: none spans two.
    p = res.vertices[res.faces]
    t = v[f]
    from repair.deviation import point_triangle_d2

    for face in p:
        d2 = np.max([point_triangle_d2(np.repeat(face[k][None], len(t), 0), t[:, 0], t[:, 1],
                                        t[:, 2]) for k in range(3)], axis=0)  # fmt: skip
        assert d2.min() < 1e-14


def test_nested_shells_keep_the_outer_one_only():
    v, f = concat(box((0, 0, 0), (4, 4, 4)), box((1, 1, 1), (2, 2, 2)))
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    assert res.report["volume"] == pytest.approx(64.0)
    assert len(res.faces) == 12
    assert res.report["after"]["components_dropped_internal"] == 1


def test_all_faces_flipped_are_fixed():
    v, f = box((0, 0, 0), (3, 2, 1))
    res = repair_mesh(v, f[:, ::-1], EPS)
    assert_printable(res)
    assert res.report["volume"] == pytest.approx(6.0)
    assert len(res.faces) == 12
    assert res.report["deviation"] < 1e-9


def test_flattened_cube_becomes_a_slab_of_thickness_epsilon():
    v, f = box((0, 0, 0), (10, 10, 10))
    v = v.copy()
    v[:, 2] = 0.0
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    z = res.vertices[:, 2]
    assert z.max() - z.min() == pytest.approx(EPS, rel=1e-6)
    assert res.report["volume"] == pytest.approx(100.0 * EPS, rel=1e-3)
    assert res.report["deviation"] <= 0.6 * EPS


def test_open_surface_is_thickened():
    v, f = box((0, 0, 0), (5, 5, 5))
    top = v[f][:, :, 2].min(axis=1) == 5.0
    res = repair_mesh(v, f[~top], EPS)  # an open-topped box: all sheet
    assert_printable(res)
    assert res.report["after"]["sheet_triangles_thickened"] == 10
    assert 0.0 < res.report["volume"] < 125.0
    assert res.report["deviation"] <= 0.6 * EPS


def sphere_with_holes(n_holes: int) -> tuple[np.ndarray, np.ndarray, float]:
    """An icosphere of radius 10 mm (5120 triangles) with the one-ring of ``n_holes``
    well separated vertices removed (hexagonal holes, perimeter ~3 mm each), and the
    volume of the closed sphere."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)
    closed_volume = signed_volume(v, f)
    targets = [np.argmax(v @ d) for d in np.eye(3)[:n_holes]]
    keep = ~np.isin(f, targets).any(axis=1)
    return v, f[keep], closed_volume


def test_sphere_with_small_holes_is_closed_not_thickened():
    v, f, closed_volume = sphere_with_holes(3)
    assert len(f) == 5120 - 3 * 6
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    after = res.report["after"]
    assert res.report["holes_closed"]["count"] == 3
    assert after["sheet_triangles_thickened"] == 0
    assert after["wires_inflated"] == 0 and after["singular_edges_thickened"] == 0
    assert after["components"] == 1
    assert res.report["volume"] == pytest.approx(closed_volume, rel=0.01)
    # The rest of the sphere is kept exactly: every input triangle is in the output.
    out = {tuple(sorted(map(tuple, t))) for t in res.vertices[res.faces].tolist()}
    inp = v[f].astype(np.float32).astype(np.float64)
    assert all(tuple(sorted(map(tuple, t))) in out for t in inp.tolist())
    assert res.report["deviation"] <= res.report["holes_closed"]["max_lid_radius"] + 1e-6
    assert "3 small hole(s) closed" in res.report["summary"]


def test_flap_beside_a_hole_of_a_scan_is_removed_and_the_hole_closed():
    v, f, closed_volume = sphere_with_holes(2)
    # A triangle dangling off an edge of the shell (the edge now has 3 faces) at the rim
    # of a hole, as scanners leave them.
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, cnt = np.unique(e, axis=0, return_counts=True)
    rim = np.unique(edges[cnt == 1])
    a, b = next(
        (p, q) for p, q in edges[cnt == 2] if (p in rim) != (q in rim)
    )  # an inner edge from the rim of a hole into the shell
    apex = 0.5 * (v[a] + v[b]) * 1.02
    v2 = np.vstack([v, apex])
    f2 = np.vstack([f, [[a, b, len(v)]]])
    res = repair_mesh(v2, f2, EPS)
    assert_printable(res)
    holes = res.report["holes_closed"]
    assert holes["flaps_removed"] == 1 and holes["count"] == 2
    assert res.report["after"]["sheet_triangles_thickened"] == 0
    assert res.report["volume"] == pytest.approx(closed_volume, rel=0.01)


def test_lone_segment_becomes_an_epsilon_cylinder():
    v = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 10.0], [0.0, 0.0, 4.0]])
    res = repair_mesh(v, np.array([[0, 1, 2]]), EPS)  # collinear: a wire
    assert_printable(res)
    assert res.report["after"]["wires_inflated"] == 1
    lo, hi = res.vertices.min(axis=0), res.vertices.max(axis=0)
    assert hi[2] - lo[2] == pytest.approx(10.0, rel=1e-6)
    assert max(hi[0] - lo[0], hi[1] - lo[1]) == pytest.approx(EPS, rel=1e-3)
    r = np.hypot(res.vertices[:, 0], res.vertices[:, 1])
    assert r.max() == pytest.approx(EPS / 2, rel=1e-5)
    assert res.report["deviation"] == pytest.approx(EPS / 2, rel=1e-3)


def test_cube_with_zero_thickness_fin_keeps_the_cube_exact():
    cube = box((0, 0, 0), (10, 10, 10))
    fin = (np.array([[10.0, 5.0, 2.0], [15.0, 5.0, 2.0], [10.0, 5.0, 8.0]]), np.array([[0, 1, 2]]))
    v, f = concat(cube, fin)
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    assert res.report["after"]["sheet_triangles_thickened"] >= 1
    assert res.report["volume"] > 1000.0
    assert res.report["deviation"] <= 0.6 * EPS
    # Every cube corner is still a vertex; the cube's faces away from the fin are exact.
    out = {tuple(p) for p in res.vertices}
    for p in cube[0]:
        assert tuple(p) in out
    far = res.vertices[:, 0] < 9.0
    assert np.all(
        np.isclose(res.vertices[far], 0.0) | np.isclose(res.vertices[far], 10.0)
        | (res.vertices[far] > 0) & (res.vertices[far] < 10.0)
    )  # fmt: skip
    assert res.vertices[:, 0].max() <= 15.0 + 0.6 * EPS


def klein_bottle(n: int = 40, m: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """The figure-8 immersion of the Klein bottle (self-intersecting, non-orientable)."""
    r = 3.0
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    w = np.linspace(0, 2 * np.pi, m, endpoint=False)
    uu, ww = np.meshgrid(u, w, indexing="ij")
    a = r + np.cos(uu / 2) * np.sin(ww) - np.sin(uu / 2) * np.sin(2 * ww)
    v = np.stack([a * np.cos(uu), a * np.sin(uu),
                  np.sin(uu / 2) * np.sin(ww) + np.cos(uu / 2) * np.sin(2 * ww)], -1)  # fmt: skip
    v = v.reshape(-1, 3) * 10.0
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1 = (i + 1) % n
    # Crossing u = 2 pi maps w to -w.
    j_next = np.where(i1 == 0, (-j) % m, j)
    j1_next = np.where(i1 == 0, (-(j + 1)) % m, (j + 1) % m)
    a0, a1 = i * m + j, i * m + (j + 1) % m
    b0, b1 = i1 * m + j_next, i1 * m + j1_next
    f = np.concatenate([np.stack([a0, b0, b1], 1), np.stack([a0, b1, a1], 1)])
    return v, f


@pytest.mark.slow
def test_klein_bottle_becomes_its_outer_hull():
    import igl.copyleft.cgal as cgal

    from repair.finish import SINGULAR_EDGE_DIAMETER

    v, f = klein_bottle()
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    hv, hf, _, _ = cgal.outer_hull(v, f)
    assert res.report["volume"] > 0
    # The outer hull is closed and lies on the input surface; where it touches itself
    # along an edge, each side gets its own copy of the edge a few ulps apart (or, if
    # that does not hold, the edge is fused by a prism of SINGULAR_EDGE_DIAMETER * eps).
    reach = 0.6 * SINGULAR_EDGE_DIAMETER * EPS
    assert res.report["deviation"] <= reach
    assert res.vertices.max(axis=0) == pytest.approx(hv.max(axis=0), abs=reach)
    assert res.vertices.min(axis=0) == pytest.approx(hv.min(axis=0), abs=reach)
    assert res.report["after"]["sheet_triangles_thickened"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5, 7])
def test_random_triangles_become_a_printable_solid(seed):
    rng = np.random.default_rng(seed)
    tri = rng.uniform(0, 20, size=(40, 3, 3))
    res = repair_mesh(tri.reshape(-1, 3), np.arange(120).reshape(-1, 3), EPS)
    assert_printable(res)
    # At least every triangle's slab: each is eps thick over its own area.
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert res.report["volume"] > EPS * area.max()
    assert res.report["deviation"] <= 0.6 * EPS


def test_repair_is_deterministic():
    # libigl's arrangement runs in threads; its output is put in one canonical order, so
    # the same input always gives the same result (and the same verdict).
    rng = np.random.default_rng(2)
    tri = rng.uniform(0, 20, size=(40, 3, 3)).reshape(-1, 3)
    f = np.arange(120).reshape(-1, 3)
    a, b = repair_mesh(tri, f, EPS), repair_mesh(tri, f, EPS)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


def test_face_partly_solid_partly_sheet_gets_a_ledge_and_keeps_the_solid_exact():
    # A 10 mm cube whose top is one 16 mm wide square: 3 mm of it overhang on either
    # side as zero-thickness ledges. The two top triangles are solid hull over the cube
    # and sheet beyond it.
    v, f = box((0, 0, 0), (10, 10, 10))
    top = np.isclose(v[f][:, :, 2], 10.0).all(axis=1)
    lid = np.array([[-3.0, 0, 10], [13.0, 0, 10], [13.0, 10, 10], [-3.0, 10, 10]])
    v, f = concat((v, f[~top]), (lid, np.array([[0, 1, 2], [0, 2, 3]])))
    res = repair_mesh(v, f, EPS)
    assert_printable(res)
    assert res.report["after"]["sheet_triangles_thickened"] >= 2
    # The cube plus two 3 x 10 mm ledges eps thick (their rims grown by eps / 100).
    assert res.report["volume"] == pytest.approx(1000.0 + 2 * 3 * 10 * EPS, abs=0.2)
    assert res.report["deviation"] <= 0.6 * EPS
    lo, hi = res.vertices.min(axis=0), res.vertices.max(axis=0)
    assert lo[2] == 0.0 and hi[2] == pytest.approx(10.0 + EPS / 2, abs=1e-5)
    assert lo[0] == pytest.approx(-3.0, abs=0.01) and hi[0] == pytest.approx(13.0, abs=0.01)
    # The cube's bottom corners are kept exactly, and its top stays flat at z = 10
    # away from the ledges.
    out = {tuple(p) for p in res.vertices}
    for p in [(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 10.0, 0.0), (10.0, 10.0, 0.0)]:
        assert p in out
    mid = (res.vertices[:, 0] > 0.1) & (res.vertices[:, 0] < 9.9)
    assert np.all(np.isin(res.vertices[mid, 2], [0.0, 10.0]))


def test_everything_collapsed_to_a_point_is_an_error():
    v = np.zeros((3, 3)) + 5.0
    with pytest.raises(RepairError, match="nothing printable"):
        repair_mesh(v, np.array([[0, 1, 2], [2, 1, 0]]), EPS)


def test_bad_epsilon_is_an_error():
    v, f = box()
    with pytest.raises(RepairError, match="epsilon"):
        repair_mesh(v, f, 0.0)


def test_progress_is_reported():
    seen = []
    v, f = concat(box((0, 0, 0), (2, 2, 2)), box((1, 1, 1), (3, 3, 3)))
    repair_mesh(v, f, EPS, progress=lambda s, x: seen.append((s, x)))
    assert seen and seen[-1][1] == 1.0
    assert all(0.0 <= x <= 1.0 for _, x in seen)


def _write_ascii_stl(path, v, f):
    lines = ["solid t"]
    for tri in v[f]:
        lines += ["facet normal 0 0 0", "outer loop"]
        lines += [f"vertex {float(p[0])} {float(p[1])} {float(p[2])}" for p in tri]
        lines += ["endloop", "endfacet"]
    lines.append("endsolid t")
    path.write_text("\n".join(lines) + "\n")


def test_cli_repairs_a_file_and_writes_a_report(tmp_path):
    from repair.io import load_mesh

    src = tmp_path / "two.stl"
    _write_ascii_stl(src, *concat(box((0, 0, 0), (2, 2, 2)), box((1, 1, 1), (3, 3, 3))))
    out, rep = tmp_path / "out.stl", tmp_path / "r.json"
    proc = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(src), "-o", str(out),
         "--epsilon", "0.5", "--report", str(rep)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    report = json.loads(rep.read_text())
    assert report["epsilon"] == 0.5 and report["printable"]["ok"]
    assert report["volume"] == pytest.approx(15.0)
    m = load_mesh(out)
    assert check_printable(m.vertices, m.faces).ok


def test_cli_fails_with_one_line_for_nothing_printable(tmp_path):
    src = tmp_path / "dot.stl"
    _write_ascii_stl(src, np.ones((3, 3)), np.array([[0, 1, 2]]))
    proc = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(src), "-o", str(tmp_path / "o.stl")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("preflight: ")
    assert not (tmp_path / "o.stl").exists()


CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"


@pytest.mark.skipif(not (CORPUS / "DragonAceNL_1004825.stl").is_file(), reason="no corpus")
def test_a_failing_local_mend_falls_back_to_the_whole_outer_hull(monkeypatch):
    """Ten overlapping Thingiverse shells: their union's float32 rounding needs mending.
    If the local mend is refused (libigl raises), the whole outer hull is taken instead."""
    import repair.finish as finish
    from repair.io import load_mesh

    calls = []

    def refuse(*args, **kwargs):
        calls.append(1)
        raise RuntimeError("CGAL refused the subset")

    monkeypatch.setattr(finish, "mend_intersections", refuse)
    m = load_mesh(CORPUS / "DragonAceNL_1004825.stl")
    res = repair_mesh(m.vertices, m.faces, EPS)
    assert calls, "the mend was not reached: the case no longer tests the fallback"
    assert_printable(res)
    assert res.report["volume"] > 0


def test_input_pairs_carried_past_cleaning_and_lids_are_those_a_whole_test_finds():
    import trimesh

    from repair.check import check_printable_pairs
    from repair.clean import clean_soup
    from repair.holes import close_small_holes
    from repair.intersections import intersecting_face_pairs
    from repair.provenance import carry_input_pairs

    a = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    b = trimesh.creation.icosphere(subdivisions=3, radius=8.0)
    v = np.vstack([a.vertices, b.vertices + (9.3, 1.7, -2.1)]).astype(np.float32)
    f = np.vstack([a.faces, b.faces + len(a.vertices)]).astype(np.int64)
    f = np.vstack([np.delete(f, [5, 900, 1700], axis=0), f[:3]])  # holes and duplicates
    v = v.astype(np.float64)
    _, pairs_in = check_printable_pairs(v, f, as_float32=True)
    c = clean_soup(v, f)
    cv, cf, holes = close_small_holes(c.vertices, c.faces)
    assert holes.count == 3 and c.duplicates_removed == 3
    carried = carry_input_pairs(v, f, pairs_in, cv, cf)
    assert len(carried) > 0
    assert np.array_equal(carried, intersecting_face_pairs(cv, cf))


def test_the_repair_runs_blas_on_one_thread_and_gives_the_threads_back():
    """Inside repair_mesh (seen from its progress callback) BLAS has one thread; after it,
    as many as before (two here, whatever the machine)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    inside: list[list[int]] = []
    v, f = concat(box(), box((0.5, 0.3, 0.2), (1.5, 1.3, 1.2)))
    repair_mesh(v, f, EPS)  # a first repair loads SciPy's BLAS: counted before, too
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        out = repair_mesh(v, f, EPS, progress=lambda stage, x: inside.append(blas_threads()))
        after = blas_threads()
    assert before and all(t == 2 for t in before)
    assert check_printable(out.vertices, out.faces, as_float32=True).ok
    assert inside and all(t == [1] * len(before) for t in inside)
    assert after == before


def test_a_fresh_process_limits_scipys_blas_without_importing_scipy_linalg():
    """A command-line repair does not pay for importing scipy.linalg (~0.3 s of CPU):
    SciPy's own OpenBLAS is loaded as a library before the BLAS search, and when SciPy
    then imports it, it is that same library, limited to one thread inside a repair."""
    code = """if True:
        import sys
        from mesh_helpers import box, concat
        from threadpoolctl import threadpool_info
        from repair.pipeline import repair_mesh
        from repair.workers import blas_controller
        v, f = concat(box(), box((0.5, 0.3, 0.2), (1.5, 1.3, 1.2)))
        repair_mesh(v, f, 0.4)
        print("linalg" if "scipy.linalg" in sys.modules else "no linalg")
        with blas_controller().limit(limits=1, user_api="blas"):
            import scipy.linalg
            scipy.linalg.solve([[2.0, 1.0], [1.0, 3.0]], [1.0, 2.0])
            print(sorted((i["prefix"], i["num_threads"]) for i in threadpool_info()
                         if i["user_api"] == "blas"))
    """
    tests = Path(__file__).resolve().parent
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=tests, check=True).stdout.splitlines()  # fmt: skip
    assert out[0] == "no linalg"
    libs = eval(out[1])  # noqa: S307 -- our own subprocess's printed list
    assert len(libs) >= 2  # NumPy's OpenBLAS and SciPy's, each once
    assert all(n == 1 for _, n in libs)
