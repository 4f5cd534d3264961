"""Unit tests of repair.thicken's solids (units mm)."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_helpers import signed_volume

from repair.check import check_printable
from repair.thicken import region_prisms

EPS = 0.4


def test_region_prism_covers_the_union_of_a_faces_pieces():
    # A unit square in the tilted plane x + z = 1, cut into four pieces: two of them
    # overlap (as arrangement pieces never do, but the union must not care), and one
    # is listed clockwise.
    u = np.array([1.0, 0.0, -1.0]) / np.sqrt(2)
    w = np.array([0.0, 1.0, 0.0])
    n = np.cross(u, w)
    o = np.array([0.0, 0.0, 1.0])
    sq = [(0, 0), (1, 0), (1, 1), (0, 1), (0.5, 0.5)]
    v = np.array([o + a * u + b * w for a, b in sq])
    f = np.array([[0, 1, 4], [1, 2, 4], [2, 4, 3], [3, 0, 4], [0, 1, 2]])
    pv, pf = region_prisms(v, f, np.zeros(len(f), dtype=int), np.tile(n, (len(f), 1)), EPS)
    pr = check_printable(pv, pf)
    assert pr.ok, pr.failures()
    assert pr.components == 1
    assert signed_volume(pv, pf) == pytest.approx(1.0 * EPS, rel=1e-6)
    # Every corner lies eps/2 off the plane, over the square.
    d = (pv - o) @ n
    assert np.allclose(np.abs(d), EPS / 2, atol=1e-7)
    # (manifold3d's 2-D booleans work on a 1e-8 mm grid)
    assert np.all(((pv - o) @ u > -1e-7) & ((pv - o) @ u < 1 + 1e-7))


def test_region_prisms_one_per_group_and_grown():
    # Two triangles in different planes, each its own group.
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 5], [0, 2, 5], [0, 0, 7.0]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    nrm = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    pv, pf = region_prisms(v, f, np.array([7, 3]), nrm, EPS, grow=0.1)
    pr = check_printable(pv, pf)
    assert pr.ok, pr.failures()
    assert pr.components == 2
    # Each triangle (area 2) grown by 0.1 mm all round: more than 2 * eps, less than
    # the triangle's grown bounding box.
    assert 2 * 2 * EPS < signed_volume(pv, pf) < 2 * 2.4 * 2.4 * EPS


def test_region_prisms_of_nothing_are_empty():
    none = np.zeros((0, 3))
    pv, pf = region_prisms(none, none.astype(int), np.zeros(0), none, EPS)
    assert pv.shape == (0, 3) and pf.shape == (0, 3)

