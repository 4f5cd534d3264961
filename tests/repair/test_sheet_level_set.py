"""A small sheet that wrinkles tighter than eps/2 is thickened by its eps/2 level set
(repair.sheet_level_set): one closed, edge-manifold solid that does not cross itself,
eps thick through every sampled sheet point, covering the sheet, within eps / sqrt(2) of
it; sheets that need few eps-blocks keep their slabs."""

from __future__ import annotations

import numpy as np
from broken_models import uv_sphere
from mesh_helpers import box, signed_volume
from sheet_measures import covered_fraction, wall_thickness
from test_sheets import _repaired

from repair.check import check_printable
from repair.clean import drop_unreferenced
from repair.sheet_level_set import _split_edges, sheet_level_set
from repair.thicken import sheet_slabs
from repair.topology import edge_stats

EPS = 0.4


def _wrinkled_bowl(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """An open bowl 3 mm across whose vertices are jittered by up to 3 % of its radius:
    its slab folds and its corners are too sharp for a slab almost everywhere."""
    v, f = uv_sphere(1.5, 24, 48)
    v, f = drop_unreferenced(v, f[v[f][:, :, 2].min(axis=1) > -0.6])
    rng = np.random.default_rng(seed)
    return v * (1 + rng.uniform(-0.03, 0.03, (len(v), 1))), f


def test_wrinkled_sheet_becomes_one_closed_solid():
    v, f = _wrinkled_bowl()
    sv, sf = sheet_slabs(v, f, EPS)
    boundary, nonmanifold, misoriented, shells, _ = edge_stats(sf)
    assert (boundary, nonmanifold, misoriented, shells) == (0, 0, 0, 1)
    verdict = check_printable(sv, sf)
    assert verdict.ok, verdict.failures()
    assert signed_volume(sv, sf) > 0


def test_level_set_vertices_lie_about_half_eps_from_the_sheet():
    import igl

    v, f = _wrinkled_bowl(seed=5)
    sv, sf = sheet_level_set(v, f, EPS)
    d = np.sqrt(igl.point_mesh_squared_distance(sv, v, f)[0])
    assert d.min() >= 0.5 * EPS
    assert np.median(d) <= 0.55 * EPS
    assert d.max() <= EPS / np.sqrt(2)


def test_wrinkled_sheet_repairs_eps_thick_and_covered(tmp_path):
    v, f = _wrinkled_bowl()
    ov, of, report = _repaired(v, f, tmp_path)  # asserts the written file is printable
    thickness = wall_thickness(v, f, ov, of, rim_margin=EPS)
    assert len(thickness) > 200
    assert thickness.min() >= 0.95 * EPS
    assert covered_fraction(v, f, ov, of) >= 0.99
    assert report["deviation"] <= EPS / np.sqrt(2)


def test_open_box_keeps_its_slabs_and_blocks():
    v, f = box((0, 0, 0), (10, 10, 10))
    sv, sf = sheet_slabs(v, f[2:], EPS)
    # The level set would be one shell; slabs and the corner faces' blocks are several.
    assert edge_stats(sf)[3] > 1


def test_split_edges_keeps_a_closed_solid_closed():
    v, f = uv_sphere(2.0, 12, 16)
    rng = np.random.default_rng(0)
    split = rng.random(3 * len(f)) < 0.3
    sv, sf = _split_edges(v, f, split)
    assert len(sv) > len(v) and len(sf) > len(f)
    boundary, nonmanifold, misoriented, shells, _ = edge_stats(sf)
    assert (boundary, nonmanifold, misoriented, shells) == (0, 0, 0, 1)
    assert np.isclose(signed_volume(sv, sf), signed_volume(v, f), rtol=1e-12)
    assert check_printable(sv, sf).ok
