"""No repaired model keeps specks: shells far below what a nozzle of diameter eps can print
(:func:`repair.union.speck_volume`), which a union of many eps-blocks and the outer hull
of a mend's crumbs used to leave next to the part (mikedh_target: 6e-11 and 4e-8 mm³)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from repair.check import check_printable
from repair.files import repair_file
from repair.io import load_mesh
from repair.meshes import shell_volumes
from repair.topology import edge_components
from repair.union import manifold_union, speck_volume, without_specks
from tests.repair.mesh_helpers import box

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"
EPS = 0.4


def _shell_volumes(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    labels = edge_components(f)
    return shell_volumes(v, f, labels, int(labels.max()) + 1)


def test_speck_volume_is_a_cube_of_one_percent_of_eps():
    assert speck_volume(EPS) == pytest.approx((0.004) ** 3)


def test_union_leaves_out_specks_and_keeps_what_is_printable():
    # Two crossing boxes, a detached 2 µm speck, and a detached 0.5 mm cube.
    parts = [
        box((0, 0, 0), (10, 10, 10)), box((5, 5, 5), (15, 15, 15)),
        box((20, 0, 0), (20.002, 0.002, 0.002)), box((0, 20, 0), (0.5, 20.5, 0.5)),
    ]  # fmt: skip
    kept = manifold_union(parts)
    assert kept is not None
    assert len(_shell_volumes(*kept)) == 3  # without a threshold the speck stays
    out = manifold_union(parts, min_volume=speck_volume(EPS))
    assert out is not None
    vols = np.sort(_shell_volumes(*out))
    assert vols == pytest.approx([0.125, 1875.0], rel=1e-5)
    assert check_printable(*out).ok


def test_a_speck_cavity_goes_with_the_island_in_it_and_a_real_cavity_stays():
    outer_v, outer_f = box((0, 0, 0), (10, 10, 10))
    meshes = [box((1, 1, 1), (1.003, 1.003, 1.003)), box((5, 5, 5), (7, 7, 7))]
    island = box((1.001, 1.001, 1.001), (1.002, 1.002, 1.002))  # inside the speck cavity
    v, f = outer_v, outer_f
    for cv, cf in meshes:  # cavities: inverted boxes
        f = np.vstack([f, cf[:, ::-1] + len(v)])
        v = np.vstack([v, cv])
    f = np.vstack([f, island[1] + len(v)])
    v = np.vstack([v, island[0]])
    ov, of = without_specks(v, f, speck_volume(EPS))
    vols = np.sort(_shell_volumes(ov, of))
    assert vols == pytest.approx([-8.0, 1000.0])
    assert len(of) == 24


@pytest.mark.slow
@pytest.mark.skipif(not (CORPUS / "mikedh_target.obj").is_file(), reason="corpus not present")
def test_mikedh_target_comes_out_as_one_solid_without_outer_specks(tmp_path):
    out = tmp_path / "target.stl"
    repair_file(CORPUS / "mikedh_target.obj", out, epsilon=EPS)
    written = load_mesh(out)
    vols = _shell_volumes(written.vertices, written.faces)
    # One open, self-crossing surface thickened by eps: one solid, no speck beside it.
    assert len(vols) == 1, np.sort(vols)
    assert vols[0] > 1.0
    assert check_printable(written.vertices, written.faces).ok
