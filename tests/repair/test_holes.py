"""Known-answer cases for closing the small holes of almost-closed shells (repair.holes)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from repair.check import check_printable
from repair.holes import boundary_loops, close_small_holes


def icosphere(radius: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    s = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


def test_small_holes_of_a_sphere_get_oriented_lids():
    v, f = icosphere()
    targets = [np.argmax(v @ d) for d in np.eye(3)]
    open_f = f[~np.isin(f, targets).any(axis=1)]
    loops, _ = boundary_loops(open_f)
    assert len(loops) == 3 and all(len(x) in (5, 6) for x in loops)
    out_v, out_f, holes = close_small_holes(v, open_f)
    assert holes.count == 3
    assert np.array_equal(out_f[: len(open_f)], open_f)  # the shell is kept as it was
    verdict = check_printable(out_v, out_f)
    assert verdict.ok, verdict.failures()  # closed, manifold, consistently oriented
    lid = out_f[len(open_f) :]
    p = out_v[lid]
    lid_area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    assert holes.area == pytest.approx(lid_area, rel=1e-9)


def test_open_topped_box_is_a_sheet_not_a_hole():
    lo, hi = np.zeros(3), np.full(3, 5.0)
    m = trimesh.creation.box(bounds=[lo, hi])
    v, f = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    f = f[v[f][:, :, 2].min(axis=1) < 5.0]
    out_v, out_f, holes = close_small_holes(v, f)
    assert holes.count == 0
    assert np.array_equal(out_f, f) and np.array_equal(out_v, v)


def test_a_finely_meshed_bowl_is_not_closed():
    # Few boundary edges against many faces, but the rim is as large as the shell.
    v, f = icosphere()
    bowl = f[v[f][:, :, 2].max(axis=1) <= 0.0]
    _, _, holes = close_small_holes(v, bowl)
    assert len(boundary_loops(bowl)[0]) == 1
    assert holes.count == 0


def test_a_shell_that_would_stay_open_gets_no_lids():
    # Two small holes and one large one: lidding the small ones would not close it.
    v, f = icosphere()
    small = [np.argmax(v @ d) for d in np.eye(3)[:2]]
    keep = ~np.isin(f, small).any(axis=1) & (v[f][:, :, 2].max(axis=1) < 9.0)
    assert len(boundary_loops(f[keep])[0]) == 3
    out_v, out_f, holes = close_small_holes(v, f[keep])
    assert holes.count == 0
    assert np.array_equal(out_f, f[keep])


def test_lids_that_gain_no_vertex_are_the_same_when_faired():
    # One-vertex holes of a regular sphere: their lids' triangles are as fine as the rim
    # already (Liepa's density rule splits none), so fairing leaves them as they were.
    v, f = icosphere()
    targets = [np.argmax(v @ d) for d in np.eye(3)]
    open_f = f[~np.isin(f, targets).any(axis=1)]
    plain_v, plain_f, plain = close_small_holes(v, open_f)
    out_v, out_f, holes = close_small_holes(v, open_f, fair=True)
    assert holes.count == 3 and holes.faired_lids == 0
    assert np.array_equal(out_f, plain_f) and np.array_equal(out_v, plain_v)
    assert all(not lid["faired"] and lid["new_vertices"] == 0 for lid in holes.to_dict()["lids"])


def test_a_planar_hole_keeps_its_exact_lid_when_fairing():
    lo, hi = np.zeros(3), np.full(3, 5.0)
    m = trimesh.creation.box(bounds=[lo, hi])
    v, f = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    open_f = f[1:]
    out_v, out_f, holes = close_small_holes(v, open_f, fair=True)
    assert holes.count == 1 and holes.faired_lids == 0 and holes.facet_lids == 1
    assert len(out_f) == 12 and np.array_equal(out_v, v)
    assert check_printable(out_v, out_f).ok
