"""The time-budget fallback (issue 18): past its budget the exact repair gives way to a
stated approximation that keeps the exact shells exact, and the report says so."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from repair.budget import run_within_budget
from repair.check import check_printable
from repair.errors import RepairError
from repair.fallback import split_exact_shells
from repair.files import repair_file
from repair.io import load_mesh, write_stl
from repair.meshes import surface_area
from repair.pipeline import repair_mesh
from repair.topology import edge_components
from tests.repair.broken_models import overlapping_shells, triangle_soup
from tests.repair.mesh_helpers import box, concat
from tests.repair.sheet_measures import covered_fraction

CORPUS = Path("/work/shared/corpus")
#: Too short for any repair: the fallback always runs.
NO_TIME = 1e-6
EPS = 0.4


def _soup_and_cube() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Twelve crossing sheet triangles beside (not touching) an exact closed 10 mm cube;
    the cube's corners as a (12, 3, 3) array of its triangles."""
    sv, sf = triangle_soup(12, seed=3)
    cv, cf = box((60.0, 0.0, 0.0), (70.0, 10.0, 10.0))
    v, f = concat((sv, sf), (cv, cf))
    return v, f, cv[cf]


def _sorted_triangles(tris: np.ndarray) -> set[bytes]:
    """Each triangle's three corners as a byte key, whatever their order."""
    t = np.asarray(tris, dtype=np.float32)
    order = np.lexsort(t.transpose(2, 0, 1)[::-1], axis=1)
    return {row.tobytes() for row in np.take_along_axis(t, order[:, :, None], axis=1)}


def _written_check(v: np.ndarray, f: np.ndarray, tmp_path: Path):
    path = tmp_path / "written.stl"
    write_stl(path, v, f)
    mesh = load_mesh(path)
    return check_printable(mesh.vertices, mesh.faces, as_float32=True)


def test_past_the_budget_the_fallback_keeps_the_cube_exact(tmp_path):
    v, f, cube = _soup_and_cube()
    result = repair_mesh(v, f, EPS, time_budget=NO_TIME)
    r = result.report
    assert r["path"] == "fallback"
    assert r["fallback"]["reason"] == f"exact repair exceeded {NO_TIME:g} s"
    assert r["fallback"]["exact_shells"] == 1
    assert r["fallback"]["approximated_triangles"] == 12
    assert r["time_budget"]["exceeded"]
    assert r["summary"].startswith(f"fallback: exact repair exceeded {NO_TIME:g} s; "
                                   "approximation: ")
    assert f"D = {r['deviation']:.3g} mm" in r["summary"]
    assert _written_check(result.vertices, result.faces, tmp_path).ok
    # The cube is in the output triangle for triangle, on its very corners.
    out = _sorted_triangles(result.vertices[result.faces])
    assert _sorted_triangles(cube) <= out
    # The sheets moved by about eps/2 (the slabs' miter limit bounds it by 0.55 eps).
    assert 0.45 * EPS <= r["deviation"] <= 0.55 * EPS + 1e-6
    # No sheet area is lost: the soup lies inside its thickened output.
    assert covered_fraction(v[:36], f[:12], result.vertices, result.faces) >= 0.99


def test_a_repair_within_its_budget_is_unchanged(tmp_path):
    v, f = triangle_soup(6, seed=1)
    plain = repair_mesh(v, f, EPS)
    budgeted = repair_mesh(v, f, EPS, time_budget=600.0)
    assert budgeted.report["path"] == plain.report["path"] == "exact"
    assert "time_budget" not in budgeted.report and "fallback" not in budgeted.report
    a, b = tmp_path / "a.stl", tmp_path / "b.stl"
    write_stl(a, plain.vertices, plain.faces)
    write_stl(b, budgeted.vertices, budgeted.faces)
    assert a.read_bytes() == b.read_bytes()
    same = {k for k in plain.report if k not in ("stages", "seconds")}
    assert {k: plain.report[k] for k in same} == {k: budgeted.report[k] for k in same}


@pytest.mark.skipif(not (CORPUS / "mikedh_soup.stl").exists(), reason="corpus not present")
def test_corpus_soup_falls_back_to_a_printable_file(tmp_path):
    out = tmp_path / "soup.stl"
    report = repair_file(CORPUS / "mikedh_soup.stl", out, epsilon=EPS, time_budget=NO_TIME)
    assert report["path"] == "fallback"
    assert report["fallback"]["approximated_triangles"] == report["before"]["triangles"]
    mesh = load_mesh(out)
    assert check_printable(mesh.vertices, mesh.faces, as_float32=True).ok
    # Slabs and blocks: D <= 0.55 eps; a sheet thickened by its level set, as on the exact
    # path: up to eps / sqrt(2) (sheet_level_set).
    assert 0 < report["deviation"] <= EPS / np.sqrt(2)
    src = load_mesh(CORPUS / "mikedh_soup.stl")
    assert covered_fraction(src.vertices, src.faces, mesh.vertices, mesh.faces) >= 0.99


def test_cli_time_budget(tmp_path):
    v, f, _ = _soup_and_cube()
    src, out = tmp_path / "in.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    done = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(src), "-o", str(out),
         "--time-budget", str(NO_TIME), "--json"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["path"] == "fallback"
    mesh = load_mesh(out)
    assert check_printable(mesh.vertices, mesh.faces, as_float32=True).ok
    bad = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(src), "-o", str(out),
         "--time-budget", "-1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert bad.returncode != 0 and "--time-budget" in bad.stderr


# --- the budget itself, on plain callables in a real forked child ----------------------

def _meshed(tag: float):
    return np.full((1, 3), tag), np.zeros((1, 3), dtype=np.int64), {"summary": f"got {tag}"}


def _slow_exact():
    time.sleep(1.0)
    return _meshed(1.0)


def _no_fallback(reason: str):
    raise RepairError(f"{reason}, and the fallback failed: test")


def test_a_failed_fallback_lets_the_exact_repair_finish():
    v, _, report = run_within_budget(_slow_exact, 0.05, _no_fallback)
    assert v[0, 0] == 1.0
    assert report["time_budget"]["fallback_failed"].startswith("exact repair exceeded 0.05 s")
    assert report["summary"].endswith("got 1.0")


def test_errors_of_the_exact_repair_come_back_as_they_were():
    def refuse():
        raise RepairError("nothing printable: test")

    with pytest.raises(RepairError, match="nothing printable: test"):
        run_within_budget(refuse, 60.0, lambda reason: _meshed(2.0))


def _crash():
    os.kill(os.getpid(), signal.SIGKILL)  # as a native crash or the OOM killer would


def test_a_crashed_exact_repair_falls_back():
    v, _, report = run_within_budget(_crash, 60.0, lambda reason: (*_meshed(2.0)[:2],
                                                                   {"summary": reason}))
    assert v[0, 0] == 2.0
    assert report["summary"] == "exact repair crashed with SIGKILL"


def test_shell_split_keeps_solids_turned_outward_and_leaves_sheets():
    cv, cf = box()
    sv, sf = triangle_soup(2, seed=4)
    v, f = concat((cv, cf[:, ::-1]), (sv, sf))  # an inside-out cube and two sheets
    split = split_exact_shells(v, f)
    assert (split.exact_shells, split.offending_shells, split.crossing_solids) == (1, 2, 0)
    assert np.array_equal(split.exact_faces, cf)
    assert np.array_equal(split.offending, [12, 13])
    # A closed shell that crosses itself is kept (its surface's slab would be hollow),
    # its crossing faces named as knots, for eps-blocks to cover.
    crossing = split_exact_shells(cv, cf, np.array([[0, 6]]))
    assert (crossing.exact_shells, crossing.crossing_solids) == (1, 1)
    assert np.array_equal(crossing.knots, [0, 6]) and len(crossing.offending) == 0


def test_overlapping_shells_with_holes_fall_back_to_their_exact_union(tmp_path):
    # The most common breakage, small: closed shells crossing one another, with
    # single triangles missing. Lids close the holes; the shells are then kept exactly
    # and united by manifold3d, without the exact arrangement.
    model = overlapping_shells(6000, 8, seed=2, shells=3)
    result = repair_mesh(model.vertices, model.faces, EPS, time_budget=NO_TIME)
    r = result.report
    assert r["path"] == "fallback"
    assert (r["fallback"]["exact_shells"], r["fallback"]["approximated_triangles"]) == (3, 0)
    assert r["holes_closed"]["count"] == model.holes
    assert _written_check(result.vertices, result.faces, tmp_path).ok
    # Only the lids (each a missing triangle) stray from the input: D stays far below eps.
    assert r["deviation"] < 0.25 * EPS
    assert covered_fraction(model.vertices, model.faces, result.vertices, result.faces) >= 0.99


def _crossed_prism() -> tuple[np.ndarray, np.ndarray]:
    """A closed 5 mm prism over the self-crossing quadrilateral (0,0) (10,10) (10,0)
    (0,6): one shell, every edge used twice, crossing itself along its walls and caps;
    its two lobes wind opposite ways, the larger (31.25 mm^2) around (7.9, 4.6)."""
    quad = np.array([[0.0, 0.0], [10.0, 10.0], [10.0, 0.0], [0.0, 6.0]])
    v = np.vstack([np.c_[quad, np.zeros(4)], np.c_[quad, np.full(4, 5.0)]])
    walls = [[i, (i + 1) % 4, 4 + (i + 1) % 4] for i in range(4)]
    walls += [[i, 4 + (i + 1) % 4, 4 + i] for i in range(4)]
    return v, np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], *walls])


def test_a_self_crossing_closed_shell_falls_back_to_a_filled_printable_solid(tmp_path):
    from repair.winding import winding_numbers

    v, f = _crossed_prism()
    result = repair_mesh(v, f, EPS, time_budget=NO_TIME)
    r = result.report
    assert r["path"] == "fallback", r["summary"]
    assert r["fallback"]["self_crossing_shells"] == 1
    assert r["fallback"]["knot_triangles"] > 0
    # Its crossings are resolved exactly, not covered by blocks: the two lobes meet along
    # an edge, which each gets its own copy of (a few ulps apart). Below the crossing the
    # two cap triangles overlap with opposite turns, top and bottom: folds that bound no
    # solid, thickened as sheets.
    assert not r["fallback"]["knots_blocked"]
    assert r["fallback"]["knot_fold_triangles"] > 0
    assert _written_check(result.vertices, result.faces, tmp_path).ok
    # Nothing strays beyond the eps/2 (miter-limited) of the folds' slabs.
    assert 0 < r["deviation"] <= 0.55 * EPS + 1e-6
    # Every input face is inside the output, and both lobes are solid -- the smaller
    # one, turned inside out by the crossing, too -- not a hollow skin.
    assert covered_fraction(v, f, result.vertices, result.faces) >= 0.99
    lobes = np.array([[7.9, 4.6, 2.5], [1.25, 3.25, 2.5]])
    assert np.allclose(winding_numbers(result.vertices, result.faces, lobes), 1.0)
    # Their volume: the quadrilateral's two triangles either side of the crossing at
    # (3.75, 3.75), 31.25 + 11.25 mm^2, times 5 mm; plus the folds' two slabs (eps thick,
    # 1.1 eps at most) over the 18.75 mm^2 triangle (0, 0) (3.75, 3.75) (10, 0).
    p = np.asarray(result.vertices, dtype=np.float64)[result.faces]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    assert 212.5 + 2 * 18.75 * EPS - 1e-2 < volume <= 212.5 + 2 * 18.75 * 1.1 * EPS


def _volume(v: np.ndarray, f: np.ndarray) -> float:
    p = np.asarray(v, dtype=np.float64)[np.asarray(f, dtype=np.int64)]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6)


@pytest.mark.parametrize("name", ["admesh_basic.stl", "admesh_remove-unconnected-bad.stl"])
def test_corpus_admesh_self_crossing_solid_keeps_its_material(name, tmp_path):
    # A 1000 x 1500 x 400 mm solid whose x = -500 wall is triangulated twice over (its
    # triangles overlap, 96 crossing pairs) and that has 34 degenerate faces. Handed to
    # manifold3d as it was, its constructor re-meshed the knotted wall and cut 0.77M mm³
    # out of the solid, up to 40 mm deep (D was 40.3 mm); mended first, it keeps it all.
    import igl

    if not (CORPUS / name).exists():
        pytest.skip("corpus not present")
    out = tmp_path / "out.stl"
    report = repair_file(CORPUS / name, out, epsilon=EPS, time_budget=NO_TIME)
    assert report["path"] == "fallback", report["summary"]
    assert report["fallback"]["self_crossing_shells"] == 1
    assert not report["fallback"]["knots_blocked"]
    mesh = load_mesh(out)
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, np.int64)
    assert check_printable(v, f, as_float32=True).ok
    # The degenerate faces' segments get eps-prisms, the folds eps-slabs: D ~ eps/2.
    assert report["deviation"] <= 0.55 * EPS + 1e-6
    src = load_mesh(CORPUS / name)
    sv, sf = np.asarray(src.vertices, dtype=np.float64), np.asarray(src.faces, np.int64)
    assert covered_fraction(sv, sf, v, f) >= 0.99
    # Every point of the input solid more than eps inside it is inside the output
    # (sampled in the box of its largest part: remove-unconnected has a far-off speck).
    shell = edge_components(sf)
    main = sf[shell == np.argmax(np.bincount(shell))]
    box_v = sv[main].reshape(-1, 3)
    q = np.random.default_rng(0).uniform(box_v.min(axis=0), box_v.max(axis=0), (50_000, 3))
    deep = np.asarray(igl.fast_winding_number(sv, sf, q)) > 0.5
    deep &= np.asarray(igl.point_mesh_squared_distance(q, sv, sf)[0]) > EPS**2
    assert np.count_nonzero(deep) > 10_000
    assert np.all(np.asarray(igl.fast_winding_number(v, f, q[deep])) > 0.5)
    # So the volume is the solid's, plus at most eps/2 (miter-limited) over its area.
    assert _volume(sv, main) * (1 - 1e-6) <= _volume(v, f)
    assert _volume(v, f) <= _volume(sv, main) + 0.55 * EPS * surface_area(sv, sf)


@pytest.mark.slow
@pytest.mark.skipif(not (CORPUS / "mikedh_target.obj").exists(), reason="corpus not present")
# Its union's float32 rounding collapses 2,055 faces onto edges shared by four faces;
# separating those edges once sorted the faces by NaN angles (mend.py, "invalid value").
@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_corpus_target_whose_slab_folds_falls_back_to_a_printable_file(tmp_path):
    out = tmp_path / "target.stl"
    report = repair_file(CORPUS / "mikedh_target.obj", out, epsilon=EPS, time_budget=NO_TIME)
    assert report["path"] == "fallback", report["summary"]
    mesh = load_mesh(out)
    assert check_printable(mesh.vertices, mesh.faces, as_float32=True).ok
    # Slabs and blocks: D <= 0.55 eps; a sheet thickened by its level set, as on the exact
    # path: up to eps / sqrt(2) (sheet_level_set).
    assert 0 < report["deviation"] <= EPS / np.sqrt(2)
    src = load_mesh(CORPUS / "mikedh_target.obj")
    assert covered_fraction(src.vertices, src.faces, mesh.vertices, mesh.faces) >= 0.99


def test_corpus_flipped_faces_are_turned_not_thickened(tmp_path):
    # A closed 12-triangle box, some of whose faces are listed the wrong way round
    # (every edge used twice, some twice in the same direction). Orientation is exact:
    # the fallback turns them consistent and keeps the box as it is, D at float32
    # rounding scale -- it once replaced the box by its eps-slab (48 triangles, D =
    # eps/2).
    name = "admesh_normal-directions-bad.stl"
    if not (CORPUS / name).exists():
        pytest.skip("corpus not present")
    src = load_mesh(CORPUS / name)
    sv, sf = np.asarray(src.vertices, dtype=np.float64), np.asarray(src.faces, np.int64)
    out = tmp_path / "out.stl"
    report = repair_file(CORPUS / name, out, epsilon=EPS, time_budget=NO_TIME)
    assert report["path"] == "fallback", report["summary"]
    assert report["fallback"]["approximated_triangles"] == 0
    assert report["fallback"]["exact_shells"] == 1
    assert report["deviation"] < 1e-6
    mesh = load_mesh(out)
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, np.int64)
    assert check_printable(v, f, as_float32=True).ok
    # The input's triangles, each on its own corners, now all facing outward.
    assert _sorted_triangles(v[f]) == _sorted_triangles(sv[sf])
    assert _volume(v, f) > 0


@pytest.mark.slow
@pytest.mark.skipif(not (CORPUS / "mikedh_cycloidal.ply").exists(), reason="corpus not present")
def test_corpus_cycloidal_kept_shells_unite_nearly_without_crossing_themselves():
    # A gear exported as 117 closed shells that overlap (54,780 crossing pairs), some
    # sharing an edge with another. The fallback keeps them exact and unites them with
    # manifold3d, one solid per shell: handed over as edge-connected pieces, the shells
    # sharing an edge made one non-manifold piece, whose union crossed itself (7,955
    # pairs) and cost the finish ~3k faces of CGAL arrangement.
    from repair.clean import clean_checked
    from repair.fallback import _shell_labels
    from repair.intersections import intersecting_face_pairs
    from repair.rounding import round_input
    from repair.topology import undirected_edges
    from repair.union import manifold_union

    src = load_mesh(CORPUS / "mikedh_cycloidal.ply")
    r = round_input(np.asarray(src.vertices, np.float64), np.asarray(src.faces, np.int64))
    c = clean_checked(r.vertices, r.faces, r.verdict)
    split = split_exact_shells(c.vertices, c.faces)
    assert split.exact_shells >= 100
    _, uses = undirected_edges(split.exact_faces)
    assert np.count_nonzero(uses > 2) > 0  # shells that share an edge
    shells = _shell_labels(split.exact_faces)
    united = manifold_union([(c.vertices, split.exact_faces)], collapse=False, shells=shells)
    assert united is not None
    uv, uf = united
    # 117 solids are united in two halves, then the halves (manifold_union's shares):
    # where the halves meet along shared edges a few crossings remain for the finish.
    assert len(intersecting_face_pairs(uv, uf)) < 50
