"""repair.topology on meshes whose edges and components are known by construction."""

from __future__ import annotations

import numpy as np
import trimesh
from mesh_helpers import box, concat

from repair.topology import (
    connected_labels,
    count_duplicate_faces,
    edge_components,
    edge_ids,
    edge_neighbours,
    edge_stats,
    edge_topology,
    edge_topology_memo,
    face_keys,
    is_cycle,
    paired_half_edges,
    undirected_edges,
    unique_faces,
    vertex_components,
    weld_exact,
)


def _sphere() -> np.ndarray:
    return np.asarray(trimesh.creation.icosphere(subdivisions=2).faces, dtype=np.int64)


def test_edge_ids_number_edges_like_numpy_unique_of_the_sorted_half_edges():
    f = _sphere()
    f = np.vstack([f, f[:5], f[7:9, ::-1]])  # edges used 3 and 4 times too
    sorted_he = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    want, want_inv, want_counts = np.unique(
        sorted_he, axis=0, return_inverse=True, return_counts=True
    )
    eid, counts = edge_ids(f)
    assert np.array_equal(eid, want_inv.reshape(-1))
    assert np.array_equal(counts, want_counts)
    edges, uses = undirected_edges(f)
    assert np.array_equal(edges, want) and np.array_equal(uses, want_counts)


def test_census_of_a_closed_sphere_and_of_the_same_with_one_face_flipped_and_one_gone():
    f = _sphere()
    assert edge_stats(f)[:4] == (0, 0, 0, 1)
    assert is_cycle(f)
    broken = f[1:].copy()
    far = int(np.flatnonzero(~np.isin(broken, f[0]).any(axis=1))[0])  # not by the hole
    broken[far] = broken[far, ::-1]
    boundary, nonmanifold, misoriented, shells, _ = edge_stats(broken)
    assert (boundary, nonmanifold, misoriented, shells) == (3, 0, 3, 1)
    assert not is_cycle(broken)


def test_two_boxes_are_two_shells_and_each_pair_of_faces_on_an_edge_is_found():
    v, f = concat(box((0, 0, 0), (1, 1, 1)), box((3, 0, 0), (4, 1, 1)))
    labels = edge_components(f)
    assert np.array_equal(labels, np.repeat([0, 1], 12))
    assert np.array_equal(edge_components(f, edge_ids(f)[0]), labels)
    assert np.array_equal(vertex_components(len(v) + 1, f), np.r_[np.repeat([0, 1], 8), 2])
    h1, h2, use = paired_half_edges(edge_ids(f)[0])
    assert len(h1) == 36 and np.all(use == 2)
    he = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert np.array_equal(np.sort(he[h1], axis=1), np.sort(he[h2], axis=1))
    assert np.array_equal(edge_neighbours(f, [0]), np.flatnonzero(
        np.isin(np.arange(24), [0] + [i for i in range(12) if len(set(f[i]) & set(f[0])) == 2])
    ))


def test_faces_on_the_same_vertices_in_any_order_share_a_key_and_count_as_duplicates():
    f = np.array([[0, 1, 2], [2, 1, 0], [1, 2, 0], [0, 1, 3], [3, 1, 0]])
    k = face_keys(f)
    assert k[0] == k[1] == k[2] and k[3] == k[4] and k[0] != k[3]
    assert count_duplicate_faces(f) == 3
    assert np.array_equal(unique_faces(f), [0, 3])


def test_weld_merges_exactly_equal_points_only_and_treats_signed_zeros_as_one():
    v = np.array([[0.0, 0, 0], [-0.0, 0, 0], [1e-300, 0, 0], [0.0, 0, 0]])
    uv, uf = weld_exact(v, np.array([[0, 1, 2], [3, 2, 1]]))
    assert len(uv) == 2
    assert uf[0, 0] == uf[0, 1] == uf[1, 0] == uf[1, 2] != uf[0, 2]
    assert np.array_equal(uv[uf[:, 2]][0], [1e-300, 0, 0])


def test_connected_labels_are_scipys_on_meshes_paths_and_random_graphs():
    """The numpy labelling gives scipy's labels (lowest node first) on the graphs the
    repair builds -- a mesh's face graph, in its own and in a shuffled numbering -- and on
    long paths numbered at random, random sparse graphs, self-loops and isolated nodes."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    def scipys(n, a, b):
        g = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n, n))
        return connected_components(g, directed=False)[1]

    rng = np.random.default_rng(7)
    sphere = trimesh.creation.icosphere(subdivisions=4)
    faces = concat(box(), box((5.0, 0.0, 0.0)), (sphere.vertices, sphere.faces))[1]
    eid, _ = edge_ids(faces)
    face_of = np.repeat(np.arange(len(faces)), 3)
    graphs = [(len(faces), face_of, len(faces) + eid)]  # bipartite face-edge graph
    perm = rng.permutation(len(faces))
    graphs.append((len(faces), perm[face_of[:-3]], perm[face_of[3:]]))
    path = rng.permutation(5000)
    graphs.append((5000, path[:-1], path[1:]))
    graphs.append((3000, rng.integers(0, 3000, 2500), rng.integers(0, 3000, 2500)))
    graphs.append((10, np.array([3, 4, 4]), np.array([3, 9, 4])))  # self-loops
    graphs.append((4, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)))
    graphs.append((0, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)))
    for n, a, b in graphs:
        n = max(n, int(max(a.max(initial=-1), b.max(initial=-1))) + 1)
        got = connected_labels(n, a, b)
        assert got.dtype == np.int64
        assert np.array_equal(got, scipys(n, a, b))


def test_edge_topology_memo_sorts_equal_faces_once_and_never_returns_a_stale_one():
    f = _sphere()
    alone = edge_topology(f)
    with edge_topology_memo():
        first = edge_topology(f)
        assert edge_topology(f.copy()) is first  # equal faces: found once
        for name in ("eid", "counts", "shells"):
            assert np.array_equal(getattr(first, name), getattr(alone, name))
            assert not getattr(first, name).flags.writeable  # shared: read-only
        assert (first.boundary, first.nonmanifold, first.misoriented) == (0, 0, 0)
        f[0] = f[0, ::-1]  # the caller's array changed in place: not the faces memoised
        flipped = edge_topology(f)
        assert flipped is not first and flipped.misoriented == 3
        assert first.misoriented == 0 and np.array_equal(first.faces[0], f[0, ::-1])
    assert edge_topology(f) is not edge_topology(f)  # nothing outlives the block


def test_is_cycle_answers_the_same_from_a_memoized_topology():
    """Inside a memo where the check sorted the same faces, is_cycle counts on those edge
    ids: the same answers on a closed sphere, one with a hole, one with a face flipped,
    two spheres touching along an edge used four times, and faces with a repeated corner."""
    f = _sphere()
    v = np.asarray(trimesh.creation.icosphere(subdivisions=2).vertices)
    pinned = np.vstack([f, f + len(v)])
    a, b = f[0, 0], f[0, 1]
    pinned[pinned == b + len(v)] = b  # the second sphere shares the first's edge (a, b)...
    pinned[pinned == a + len(v)] = a  # ...and both its corners: four uses, two each way
    flipped = f.copy()
    flipped[5] = flipped[5, ::-1]
    repeated = np.vstack([f, [[3, 3, 7], [7, 3, 3]]])
    lone = np.vstack([f, [[3, 3, 7]]])  # its two real half-edges cancel
    cases = [f, f[1:], flipped, pinned, repeated, lone]
    outside = [is_cycle(c) for c in cases]
    assert outside == [True, False, False, True, True, True]  # a repeated corner: nothing
    with edge_topology_memo():
        for c in cases:
            edge_topology(c)
            assert is_cycle(c.copy()) == outside.pop(0)
