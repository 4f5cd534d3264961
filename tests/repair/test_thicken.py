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



def test_face_blocks_are_convex_eps_thick_solids_within_eps_half_of_their_face():
    from scipy.spatial import ConvexHull

    from repair.thicken import face_blocks
    from repair.winding import winding_numbers

    rng = np.random.default_rng(7)
    # Triangles of all shapes (a sliver, an obtuse one), far apart; plus a degenerate one.
    tris = [rng.normal(size=(3, 3)) + 20.0 * k for k in range(6)]
    tris += [np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1e-3, 0]]) - 20.0,
             np.array([[0.0, 0, 0], [1, 0, 0], [3, 0.2, 0]]) - 40.0,
             np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]]) - 60.0]  # fmt: skip
    v = np.vstack(tris)
    f = np.arange(len(v)).reshape(-1, 3)
    bv, bf = face_blocks(v, f, EPS)
    assert len(bf) == 20 * (len(f) - 1)  # the degenerate face gets none
    for k in range(len(f) - 1):
        corners, faces = bv[12 * k : 12 * k + 12], bf[20 * k : 20 * k + 20] - 12 * k
        verdict = check_printable(corners, faces)
        assert verdict.ok, verdict.failures()
        # Convex and outward: its volume is its corners' hull's.
        assert signed_volume(corners, faces) == pytest.approx(ConvexHull(corners).volume)
        a, b, c = v[f[k]]
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        centre = (a + b + c) / 3
        # eps thick along the face's normal, and every corner within eps/2 of the face
        # (the in-plane ones lie eps/2 out from an edge, the others above/below a corner).
        probes = centre + np.outer([0.499, -0.499, 0.501, -0.501], EPS * n)
        assert np.allclose(winding_numbers(corners, faces, probes), [1, 1, 0, 0], atol=1e-6)
        base = np.array([a, b, c, a, b, c, a, b, b, c, c, a])
        assert np.allclose(np.linalg.norm(corners - base, axis=1), EPS / 2)


def test_region_prism_of_a_face_cut_into_slivers_has_only_the_faces_corners():
    # A triangle cut, as the arrangement cuts one, into 40 slivers fanning out from its
    # apex to points along its base: the pieces' cut points on the base are collinear,
    # and the prism over their union is the triangle's, with its 3 corners top and bottom.
    k = 40
    base = np.column_stack([np.linspace(0.0, 3.0, k + 1), np.zeros(k + 1), np.zeros(k + 1)])
    v = np.vstack([base, [[1.0, 2.0, 0.0]]])
    f = np.column_stack([np.arange(k), np.arange(1, k + 1), np.full(k, k + 1)])
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    pv, pf = region_prisms(v, f, np.zeros(k, dtype=int), n, EPS, grow=0.0)
    pr = check_printable(pv, pf)
    assert pr.ok, pr.failures()
    assert len(pv) == 6
    assert signed_volume(pv, pf) == pytest.approx(3.0 * EPS, rel=1e-6)
