"""Attene's deviation D (repair.deviation): the local distance tree answers exactly as
the whole mesh would."""

from __future__ import annotations

import numpy as np
import trimesh


def test_local_distance_tree_gives_the_same_distances_as_the_whole_mesh():
    import igl

    from repair.deviation import _point_mesh_d2

    m = trimesh.creation.icosphere(subdivisions=6, radius=20.0)  # 81920 triangles
    v, f = np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
    rng = np.random.default_rng(5)
    # Points near a small patch (the local tree answers), plus far ones (it must not).
    near = v[f[:300]].mean(axis=1) + rng.normal(scale=0.05, size=(300, 3))
    far = rng.normal(size=(20, 3)) * 3.0
    pts = np.vstack([near, far])
    want = igl.point_mesh_squared_distance(pts, v, f)[0]
    assert np.array_equal(_point_mesh_d2(pts, v, f), want)
