"""Scan cleanup (RameshCleaner) on written float32 files: a noisy scanned-like sphere
(spikes, specks, ragged holes) comes out closed, spike-free and near the sphere."""

from __future__ import annotations

import numpy as np
import pytest
from scan_models import noisy_scan

from repair.check import check_printable
from repair.files import repair_file
from repair.io import load_mesh, write_stl
from repair.scan import SCAN_MIN_FACES, clean_scan, looks_like_scan
from repair.topology import edge_stats

EPS = 0.4
RADIUS = 20.0


@pytest.mark.parametrize(("seed", "clean"), [(0, "scan"), (1, "auto"), (2, "scan")])
def test_noisy_scan_comes_out_closed_without_spikes(tmp_path, seed, clean):
    v, f = noisy_scan(5, RADIUS, seed=seed)
    boundary, _, _, shells, _ = edge_stats(f)
    assert boundary > 100 and shells > 10  # ragged holes and specks
    assert np.linalg.norm(v, axis=1).max() > 1.15 * RADIUS  # spikes
    src, out = tmp_path / "scan.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, out, epsilon=EPS, clean=clean)
    written = load_mesh(out)
    verdict = check_printable(written.vertices, written.faces)
    assert verdict.ok, verdict.failures()
    assert verdict.components == 1  # specks gone, holes closed
    assert report["after"]["sheet_triangles_thickened"] == 0
    scan = report["scan_cleanup"]
    assert scan["why"].startswith("asked" if clean == "scan" else "looks like a scan")
    assert scan["relaxed_vertices"] > 0 and scan["components_removed"] > 0
    assert "cleaned as a scan" in report["summary"]
    # No spike: every written point within 0.25 mm outside the sphere (the spikes stood
    # 4 mm out); lids sag inwards by their sagitta only.
    r = np.linalg.norm(written.vertices, axis=1)
    assert r.max() <= RADIUS * 1.002 + 0.25
    assert r.min() >= RADIUS - 1.0
    assert verdict.volume == pytest.approx(4 / 3 * np.pi * RADIUS**3, rel=0.01)
    # D: lids reach into the holes; elsewhere the surface stays on the input.
    assert report["deviation"] <= report["holes_closed"]["max_lid_radius"] + 0.05
    assert report["deviation"] <= 2.5


def test_clean_none_leaves_a_scan_to_the_exact_repair(tmp_path):
    v, f = noisy_scan(5, RADIUS, seed=0, holes=0, specks=0)
    src, out = tmp_path / "scan.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, out, epsilon=EPS, clean="none")
    assert "scan_cleanup" not in report
    # The spikes are kept, exactly (the input is a closed sphere with spikes).
    assert report["path"] == "unchanged"
    assert np.linalg.norm(load_mesh(out).vertices, axis=1).max() > 1.15 * RADIUS


def test_clean_scan_flattens_the_spikes_of_a_closed_scan(tmp_path):
    # Closed and printable as it is: only an explicit "scan" touches it.
    v, f = noisy_scan(5, RADIUS, seed=6, holes=0, specks=0)
    src, out = tmp_path / "scan.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, out, epsilon=EPS, clean="scan")
    written = load_mesh(out)
    assert check_printable(written.vertices, written.faces).ok
    assert report["scan_cleanup"]["relaxed_vertices"] > 0
    assert np.linalg.norm(written.vertices, axis=1).max() <= RADIUS * 1.002 + 0.25
    # Where a spike stood, the surface now spans its base: D is within about an edge.
    edge = np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)
    assert report["deviation"] <= 1.5 * np.median(edge)


def test_only_dense_ragged_smooth_meshes_look_like_scans():
    v, f = noisy_scan(5, RADIUS, seed=3)
    assert len(f) >= SCAN_MIN_FACES and looks_like_scan(v, f, EPS)
    # The same sphere without holes or specks: nothing ragged about it.
    v, f = noisy_scan(5, RADIUS, seed=3, holes=0, specks=0)
    assert looks_like_scan(v, f, EPS) == ""
    # A small ragged mesh is not dense enough.
    v, f = noisy_scan(3, RADIUS, seed=3)
    assert looks_like_scan(v, f, EPS) == ""


def _bad_boundary_vertices(f: np.ndarray) -> int:
    """Boundary vertices in one face only (ears) or on more than two boundary edges."""
    from repair.topology import undirected_edges

    edges, cnt = undirected_edges(f)
    b = edges[cnt == 1]
    on = np.unique(b)
    n_bnd = np.bincount(b.reshape(-1))[on]
    faces_at = np.bincount(f.reshape(-1))[on]
    return int(np.count_nonzero((n_bnd > 2) | (faces_at == 1)))


def test_clean_scan_removes_ears_and_dangling_faces():
    from repair.holes import boundary_loops

    v, f = noisy_scan(4, RADIUS, seed=4, spikes=0, holes=3, specks=0)
    assert _bad_boundary_vertices(f) > 0  # the jittered holes are ragged
    _, out_f, done = clean_scan(v, f, EPS)
    assert done.boundary_faces_removed > 0
    assert _bad_boundary_vertices(out_f) == 0
    # Every boundary edge is now on a simple loop, which shell closure can lid.
    loops, _ = boundary_loops(out_f)
    assert sum(len(lp) for lp in loops) == edge_stats(out_f)[0]


def test_a_holed_cad_tessellation_is_not_taken_for_a_scan():
    """Overlapping UV spheres, a torus, a cylinder and a plate with 40 small holes are
    dense, ragged and smooth like a scan, but their flat (planar-quad) edges show they are
    a tessellation: auto cleanup must leave them exact (it once relaxed 1,321 vertices)."""
    from broken_models import overlapping_shells

    model = overlapping_shells(40_000, 40, seed=3)
    assert len(model.faces) >= SCAN_MIN_FACES
    assert looks_like_scan(model.vertices, model.faces, EPS) == ""


def _with_short_edges(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A noisy scan (holes, specks, spikes) with ``count`` edges shrunk to 2% of their
    length (one end moved next to the other), at faces far apart."""
    v, f = noisy_scan(5, RADIUS, seed=seed)
    v = v.copy()
    picked = f[np.random.default_rng(seed).choice(len(f) // 2, size=count, replace=False) * 2]
    v[picked[:, 1]] = v[picked[:, 0]] + 0.02 * (v[picked[:, 1]] - v[picked[:, 0]])
    return v, f


def test_edges_kept_up_to_date_through_a_collapse_match_a_fresh_sort():
    """The cleanup renumbers only the edges at merged vertices and re-takes normals only
    where corners moved: the result must be what sorting the collapsed faces gives."""
    from repair.scan import _collapse, _normals, _Surface
    from repair.scan_edges import ScanEdges

    v, f = _with_short_edges(40, seed=7)
    e = ScanEdges.of(f)
    surface = _Surface(v, f, e, *_normals(v, f))
    a, b = _collapse(surface.v, surface.e, surface.area)
    assert len(a) >= 30  # most planted short edges collapse
    surface.merge(a, b)
    fresh = ScanEdges.of(surface.f)
    for name in ("eid", "ends", "h1", "h2"):
        assert np.array_equal(getattr(surface.e, name), getattr(fresh, name)), name
    normals, area = _normals(surface.v, surface.f)
    assert np.array_equal(surface.normals, normals) and np.array_equal(surface.area, area)


def test_the_cleaned_scan_hands_on_the_topology_of_its_faces():
    from repair.topology import edge_topology

    v, f = _with_short_edges(40, seed=8)
    out_v, out_f, done = clean_scan(v, f, EPS)
    assert done.collapsed_edges > 0 and done.components_removed > 0
    given, fresh = done.topology, edge_topology(out_f)
    assert given is not None and given.of(out_f)
    for name in ("eid", "counts", "shells"):
        assert np.array_equal(getattr(given, name), getattr(fresh, name)), name
    assert (given.boundary, given.nonmanifold, given.misoriented) == (
        fresh.boundary, fresh.nonmanifold, fresh.misoriented)
    assert given.boundary > 0  # the holes are still open: shell closure lids them next


def _lid_points(v: np.ndarray, lid_f: np.ndarray) -> np.ndarray:
    """Points spread over the lid triangles (seeded barycentric samples), mm."""
    w = np.random.default_rng(0).dirichlet([1.0, 1.0, 1.0], size=30)
    return np.einsum("sk,tkd->tsd", w, v[lid_f]).reshape(-1, 3)


def test_a_scan_hole_on_the_curved_side_gets_a_fair_patch_on_the_sphere():
    """Liepa's refined and faired patch follows the sphere across the hole; the
    minimal-area lid of the same rim cuts a chord under it (much further off)."""
    from repair.check import check_printable
    from repair.holes import boundary_loops, close_small_holes

    v, f = noisy_scan(5, RADIUS, seed=5, spikes=0, holes=4, specks=0)
    cv, cf, _ = clean_scan(v, f, EPS)
    loops, _ = boundary_loops(cf)
    assert len(loops) >= 3
    gaps = {}
    for fair in (False, True):
        out_v, out_f, holes = close_small_holes(cv, cf, max_boundary_fraction=1.0, fair=fair)
        verdict = check_printable(out_v.astype(np.float32).astype(np.float64), out_f)
        assert verdict.ok, verdict.failures()
        assert holes.count == len(loops)
        r = np.linalg.norm(_lid_points(out_v, out_f[len(cf) :]), axis=1)
        gaps[fair] = np.abs(r - RADIUS).max()
        if fair:
            lids = holes.to_dict()["lids"]
            # Every hole but the single-triangle ones (planar, exact as they are).
            assert holes.faired_lids == sum(len(lp) > 3 for lp in loops) >= 3
            assert all(lid["faired"] and lid["new_vertices"] > 0
                       for lid in lids if lid["triangles"] > 1)  # fmt: skip
            # The rim's vertex indices are kept: the shell is untouched, lids appended.
            assert np.array_equal(out_f[: len(cf)], cf)
            assert np.array_equal(out_v[: len(cv)], cv)
    hole_radius = max(holes.max_perimeter / (2 * np.pi), 1e-9)
    # Within a small fraction of the hole's radius of the sphere (the scan's own noise
    # is 5% of an edge, ~0.04 mm: the faired patch is at that level); the flat lid at
    # least twice as far (its chords sag by a sagitta, 0.11 mm here).
    assert gaps[True] <= 0.05 * hole_radius
    assert gaps[False] >= 2 * gaps[True]


def test_repair_of_a_scan_reports_its_faired_lids(tmp_path):
    v, f = noisy_scan(5, RADIUS, seed=0)
    src, out = tmp_path / "scan.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, out, epsilon=EPS, clean="scan")
    written = load_mesh(out)
    assert check_printable(written.vertices, written.faces).ok
    holes = report["holes_closed"]
    assert holes["faired_lids"] >= 1
    assert any(lid["faired"] and lid["new_vertices"] > 0 for lid in holes["lids"])


def _depth_along(v: np.ndarray, tris: np.ndarray, u: np.ndarray) -> float:
    """Distance from the origin along the unit ``u`` to where it meets the triangles
    (the nearest hit; Möller-Trumbore on all of them at once), mm."""
    a, b, c = v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]]
    e1, e2 = b - a, c - a
    p = np.cross(u, e2)
    det = np.einsum("ij,ij->i", e1, p)
    s = -a
    bu = np.einsum("ij,ij->i", s, p) / det
    q = np.cross(s, e1)
    bv = (q @ u) / det
    t = np.einsum("ij,ij->i", e2, q) / det
    hit = (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 0)
    return float(t[hit].min())


def test_a_faired_patch_that_would_cross_a_face_keeps_the_minimal_area_lid():
    """A small closed tetrahedron stands in the hole, between where the flat lid and the
    faired patch pass: the faired patch cuts it (found by the exact crossing test, as
    the repair's carried pairs find it), so that hole is lidded again with its flat lid
    (the others are still faired) and the result has no crossing."""
    from repair.check import check_printable
    from repair.holes import boundary_loops, close_small_holes
    from repair.intersections import intersecting_face_pairs

    v, f = noisy_scan(5, RADIUS, seed=5, spikes=0, holes=4, specks=0)
    cv, cf, _ = clean_scan(v, f, EPS)
    loops, _ = boundary_loops(cf)
    big = max(loops, key=len)
    u = cv[big].mean(axis=0)
    u /= np.linalg.norm(u)
    depth = {}
    for fair in (False, True):
        out_v, out_f, _ = close_small_holes(cv, cf, max_boundary_fraction=1.0, fair=fair)
        depth[fair] = _depth_along(out_v, out_f[len(cf) :], u)
    assert depth[True] - depth[False] > 0.05  # the faired patch bulges out to the sphere
    # The tetrahedron: its tip between the two lids, its base above the faired patch.
    e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    tip = (0.5 * (depth[True] + depth[False])) * u
    angles = 2 * np.pi * np.arange(3) / 3
    ring = np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2
    base = (depth[True] + 0.05) * u + 0.2 * ring
    tet_v = np.vstack([tip, base])
    tet_f = np.array([[1, 2, 3], [0, 2, 1], [0, 3, 2], [0, 1, 3]]) + len(cv)
    if np.dot(np.cross(base[1] - base[0], base[2] - base[0]), u) < 0:
        tet_f = tet_f[:, ::-1]
    sv, sf = np.vstack([cv, tet_v]), np.vstack([cf, tet_f])
    rim = cv[big]
    big_perimeter = round(float(np.linalg.norm(np.roll(rim, -1, axis=0) - rim, axis=1).sum()), 9)
    out_v, out_f, holes = close_small_holes(sv, sf, max_boundary_fraction=1.0, fair=True)
    crossing = holes.faired_crossing(len(out_f), intersecting_face_pairs(out_v, out_f))
    assert [round(holes.lids[i].perimeter, 9) for i in crossing] == [big_perimeter]
    # Made again with that hole flat, as the repair does: nothing crosses.
    out_v, out_f, holes = close_small_holes(sv, sf, max_boundary_fraction=1.0, fair=True,
                                            flat=crossing)  # fmt: skip
    assert holes.faired_crossing(len(out_f), intersecting_face_pairs(out_v, out_f)) == ()
    faired = {round(lid.perimeter, 9): lid.faired for lid in holes.lids}
    assert faired.pop(big_perimeter) is False
    assert sum(faired.values()) == holes.faired_lids >= 2
    verdict = check_printable(out_v, out_f)
    assert verdict.ok, verdict.failures()
    assert verdict.components == 2  # the sphere, closed, and the tetrahedron beside it
