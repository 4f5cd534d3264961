"""The culled ray test (repair.rays.RayCaster) answers exactly as the full one does."""

from __future__ import annotations

import numpy as np
import pytest

from repair.rays import RayCaster, ray_hits_any


def _soup(rng: np.random.Generator, n: int, spread: float, offset: float) -> np.ndarray:
    centres = rng.uniform(-spread, spread, size=(n, 1, 3)) + offset
    return centres + rng.normal(scale=spread / 10, size=(n, 3, 3))


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_culled_rays_answer_as_the_full_test(offset: float) -> None:
    rng = np.random.default_rng(1)
    tri = _soup(rng, 3000, 20.0, offset)
    caster = RayCaster(tri)
    hits = 0
    for k in range(400):
        face = int(rng.integers(len(tri)))
        # From a hair off a face (as the cell search casts), or aimed through a corner
        # (a grazing hit, which must count as a hit in both).
        origin = tri[face].mean(axis=0) + rng.normal(scale=1e-6, size=3)
        d = rng.normal(size=3) if k % 2 else tri[int(rng.integers(len(tri))), 0] - origin
        d /= np.linalg.norm(d)
        full = ray_hits_any(origin, d, tri, face)
        assert caster.hits_any(origin, d, face) == full
        hits += full
    assert 0 < hits < 400  # both answers occur


def test_a_ray_out_of_a_closed_box_hits_it_and_one_away_does_not() -> None:
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    caster = RayCaster(corners[faces])
    inside = np.array([0.5, 0.4, 0.3])
    for d in np.r_[np.eye(3), -np.eye(3)]:
        assert caster.hits_any(inside, d, -1)
    assert not caster.hits_any(np.array([0.5, 0.5, 2.0]), np.array([0.0, 0.0, 1.0]), -1)
    assert caster.hits_any(np.array([0.5, 0.5, 2.0]), np.array([0.0, 0.0, -1.0]), -1)
