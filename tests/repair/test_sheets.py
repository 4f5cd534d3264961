"""Visible sheets are thickened whole and eps thick, measured on the written float32 STL:
random-triangle soups keep their area (sample points on the input triangles lie inside
or on the output solid), and the wall through every sampled sheet point is >= 0.95 eps
thick (along the sheet's normal, both ways; points within eps of a sheet's open rim,
where the wall ends, are left out)."""

from __future__ import annotations

import numpy as np
import pytest
from broken_models import _grid_faces, triangle_soup
from mesh_helpers import box
from sheet_measures import covered_fraction, wall_thickness

from repair.check import check_printable
from repair.files import repair_file
from repair.io import load_mesh, write_stl

EPS = 0.4


def _repaired(v, f, tmp_path, eps=EPS):
    src, dst = tmp_path / "in.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, dst, epsilon=eps)
    w = load_mesh(dst)
    ov, of = np.asarray(w.vertices, float), np.asarray(w.faces, np.int64)
    verdict = check_printable(ov, of)
    assert verdict.ok, verdict.failures()
    return ov, of, report


@pytest.mark.parametrize("count", [5, 10, 20])
def test_random_triangle_soups_keep_their_whole_area(count, tmp_path):
    v, f = triangle_soup(count, seed=count)
    ov, of, report = _repaired(v, f, tmp_path)
    assert covered_fraction(v, f, ov, of) >= 0.99
    assert report["deviation"] <= 0.6 * EPS


@pytest.mark.slow
@pytest.mark.parametrize("count", [40, 80])
def test_larger_random_triangle_soups_keep_their_whole_area(count, tmp_path):
    v, f = triangle_soup(count, seed=count)
    ov, of, _ = _repaired(v, f, tmp_path)
    assert covered_fraction(v, f, ov, of) >= 0.99


def _grid_sheet(height):
    g = np.linspace(-10.0, 10.0, 11)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x, y, height(x, y)], -1).reshape(-1, 3)
    return v, _grid_faces(10, 11, False)


def _open_cube():
    """A 100 mm cube with one face and half of the next one missing: a non-planar hole
    as large as a face, so an open box (a sheet), with sharp corners everywhere."""
    v, f = box((0, 0, 0), (100, 100, 100))
    return v, np.delete(f, [0, 1, 4], axis=0)


@pytest.mark.parametrize(
    "sheet",
    [
        lambda: _grid_sheet(lambda x, y: 0 * x),
        lambda: _grid_sheet(lambda x, y: (x**2 - y**2) / 40.0),
        _open_cube,
    ],
    ids=["flat", "saddle", "open_cube"],
)
def test_thickened_walls_are_eps_thick_everywhere(sheet, tmp_path):
    v, f = sheet()
    ov, of, report = _repaired(v, f, tmp_path)
    assert report["after"]["sheet_triangles_thickened"] > 0
    thickness = wall_thickness(v, f, ov, of, rim_margin=EPS)
    assert len(thickness) > 300
    assert np.all(np.isfinite(thickness))
    assert thickness.min() >= 0.95 * EPS
    assert covered_fraction(v, f, ov, of) >= 0.99
