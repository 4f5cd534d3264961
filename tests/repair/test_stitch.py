"""γ-stitching (Attene Sec. 5.2) on written float32 files: a sphere made of two patches
with a crack between them comes out closed, genus 0, within γ of the input."""

from __future__ import annotations

import numpy as np
import pytest
from crack_models import cracked_sphere, hemisphere
from mesh_helpers import concat

from repair.check import check_printable
from repair.files import repair_file
from repair.io import load_mesh, write_stl
from repair.pipeline import STITCH_GAMMA
from repair.stitch import stitch_cracks
from repair.topology import edge_stats, undirected_edges

EPS = 0.4
GAMMA = STITCH_GAMMA * EPS


def _euler(v: np.ndarray, f: np.ndarray) -> int:
    used = len(np.unique(f))
    return used - len(undirected_edges(f)[0]) + len(f)


@pytest.mark.parametrize(
    ("offset", "segments"), [(0.03, (48, 40)), (0.06, (40, 40)), (0.01, (64, 36))]
)
def test_two_patch_cracked_sphere_comes_out_closed_genus_0(tmp_path, offset, segments):
    v, f = cracked_sphere(10.0, offset, segments)
    assert edge_stats(f)[0] == sum(segments)  # two open rims
    src, out = tmp_path / "cracked.stl", tmp_path / "out.stl"
    write_stl(src, v, f)
    report = repair_file(src, out, epsilon=EPS)
    written = load_mesh(out)
    verdict = check_printable(written.vertices, written.faces)
    assert verdict.ok, verdict.failures()
    assert verdict.components == 1
    assert _euler(written.vertices, written.faces) == 2  # one closed genus-0 surface
    assert report["after"]["sheet_triangles_thickened"] == 0  # not thickened along the crack
    assert report["deviation"] <= GAMMA
    assert report["stitched"]["boundary_edges_after"] == 0
    assert report["stitched"]["gamma"] == GAMMA
    # The volume is the sphere's (UV sphere of 12 rings each side: within 3%).
    assert verdict.volume == pytest.approx(4 / 3 * np.pi * 1000, rel=0.03)


def test_patches_further_apart_than_gamma_are_not_stitched():
    vu, fu = hemisphere(10.0, 48, 12, upper=True)
    vl, fl = hemisphere(10.0, 40, 12, upper=False)
    v, f = concat((vu, fu), (vl - [0, 0, 2 * GAMMA], fl))
    out_f, done = stitch_cracks(v, f, GAMMA)
    assert done.snapped == 0 and done.inserted == 0
    assert np.array_equal(out_f, f)


def test_matching_rim_vertices_are_snapped_without_moving_more_than_gamma():
    vu, fu = hemisphere(10.0, 32, 8, upper=True)
    vl, fl = hemisphere(10.0, 32, 8, upper=False)
    v, f = concat((vu, fu), (vl - [0, 0, 0.5 * GAMMA], fl))
    out_f, done = stitch_cracks(v, f, GAMMA)
    assert done.snapped == 32 and done.inserted == 0 and done.boundary_after == 0
    assert edge_stats(out_f)[:4] == (0, 0, 0, 1)
    assert len(out_f) == len(f)
    # The kept vertices are the input's; every corner moved at most gamma.
    moved = np.linalg.norm(v[out_f] - v[f], axis=2).max()
    assert 0 < moved <= GAMMA
