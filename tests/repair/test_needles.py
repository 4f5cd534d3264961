"""Needles from CAD export faults: a zero-area triangle (a, mid(a, b), b) hanging off an
existing edge, its midpoint rounded to float32 so it is not exactly collinear."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from repair.check import check_printable, round_to_float32
from repair.clean import clean_soup, hanging_needles, needle_mask
from repair.io import load_mesh
from repair.pipeline import repair_mesh

DATA = Path(__file__).resolve().parents[1] / "data"


def part() -> tuple[np.ndarray, np.ndarray]:
    m = load_mesh(DATA / "cgal_part.obj")
    return np.asarray(m.vertices, np.float64) * 60.0, np.asarray(m.faces, np.int64)


def with_needles(v: np.ndarray, f: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """One needle on the first edge of every 20th face (random faces)."""
    rng = np.random.default_rng(seed)
    pick = rng.integers(len(f), size=max(1, len(f) // 20))
    a, b = f[pick, 0], f[pick, 1]
    mid = len(v) + np.arange(len(pick))
    return np.vstack([v, (v[a] + v[b]) / 2]), np.vstack([f, np.stack([a, mid, b], 1)])


@pytest.mark.parametrize("seed", [0, 1])
def test_needles_on_a_cad_part_are_dropped_not_thickened(seed):
    # They were thickened as sheets (D ~ 0.2 mm, prisms around 7e-6 mm² of needles).
    v, f = part()
    expected = check_printable(v, f).volume
    nv, nf = with_needles(v, f, seed)
    r = repair_mesh(nv, nf, 0.4)
    out = round_to_float32(r.vertices)
    verdict = check_printable(out, r.faces)
    assert verdict.ok, verdict.failures()
    assert verdict.volume == pytest.approx(expected, rel=1e-5)
    assert len(r.faces) == len(f)
    assert r.report["deviation"] < 1e-4


def test_a_flat_face_closing_a_crack_stays():
    # A face split at an edge's midpoint while its neighbour keeps the whole edge: the
    # flat face (a, mid, b) closes the crack, so dropping it would open the surface.
    v, f = part()
    a, b, c = f[0]
    m = len(v)
    v = round_to_float32(np.vstack([v, (v[a] + v[b]) / 2]))
    f = np.vstack([f[1:], [[a, m, c], [m, b, c], [a, m, b][::-1]]])
    assert needle_mask(v, f)[-1]
    assert not hanging_needles(v, f).any()
    cleaned = clean_soup(v, f)
    assert len(cleaned.faces) == len(f)
    assert check_printable(cleaned.vertices, cleaned.faces).closed
