"""FIA: isolate the facets of one design surface by region growing over face adjacency.

Two facets sharing a manifold edge belong to the same region when the angle between their
normals is at most ``max_angle`` (a 12-segment circle turns 30° per facet, a CAD edge between
a hole and the face it pierces turns 90°) and, where both have a curvature estimate, those
agree (the turn per unit length across the edge). Regions are then offered to the fits in
``fit.py``; only one whose every vertex lies on an analytic surface becomes a feature.
"""

from __future__ import annotations

import numpy as np

from repair.topology import connected_labels, edge_ids, paired_half_edges

#: the largest turn between two facets of one design surface (8-segment circles: 45°)
MAX_ANGLE_DEG = 40.0
#: two facet pairs' curvatures agree when within this ratio (tessellation varies)
CURVATURE_RATIO = 4.0


def face_geometry(vertices: np.ndarray, faces: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unit normals, areas, centroids) of the faces (a degenerate face gets normal 0)."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    return normals, norm / 2, tri.mean(1)


def face_regions(vertices: np.ndarray, faces: np.ndarray,
                 max_angle_deg: float = MAX_ANGLE_DEG,
                 geometry: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                 ) -> np.ndarray:
    """Region label (0..k-1) of each face: components of the face graph whose edges join
    facets turning by at most ``max_angle_deg``, with consistent curvature. ``geometry``:
    the faces' :func:`face_geometry`, if the caller has it."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    normals, _, centroids = face_geometry(v, f) if geometry is None else geometry
    eid, _ = edge_ids(f)
    first, second, _ = paired_half_edges(eid)
    fa, fb = first // 3, second // 3
    cos = np.einsum("ij,ij->i", normals[fa], normals[fb])
    turn = np.arccos(np.clip(cos, -1.0, 1.0))
    # curvature across the edge: turn per distance between the two centroids
    dist = np.linalg.norm(centroids[fa] - centroids[fb], axis=1)
    kappa = turn / np.maximum(dist, 1e-12)
    proper = np.any(normals != 0, axis=1)  # a degenerate face's normal is 0
    join = (turn <= np.radians(max_angle_deg)) & proper[fa] & proper[fb]
    # a face's curvature: the largest turn rate across its joined edges; curved edges whose
    # rate disagrees with either face's (a sharp crease inside a smooth area) do not join
    bent = join & (turn > np.radians(0.5))
    face_kappa = np.zeros(len(f))
    np.maximum.at(face_kappa, fa[bent], kappa[bent])
    np.maximum.at(face_kappa, fb[bent], kappa[bent])
    ka, kb = face_kappa[fa], face_kappa[fb]
    agree = ~bent | ((kappa * CURVATURE_RATIO >= np.maximum(ka, kb)) & (
        kappa <= CURVATURE_RATIO * np.minimum(np.where(ka > 0, ka, np.inf),
                                              np.where(kb > 0, kb, np.inf))))
    keep = join & agree
    return connected_labels(len(f), fa[keep], fb[keep])
