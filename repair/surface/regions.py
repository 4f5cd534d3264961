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
    normals, norm, centroids = _face_columns(vertices, faces)
    return np.stack(normals, axis=1), norm / 2, np.stack(centroids, axis=1)


def _face_columns(vertices: np.ndarray, faces: np.ndarray
                  ) -> tuple[list[np.ndarray], np.ndarray, list[np.ndarray]]:
    """(unit normal, twice the area, centroid) of each face, the vectors as three
    coordinate columns: 1-D gathers and unit-stride arithmetic, several times faster than
    the same operations on (m, 3) rows (a 500k-face mesh: 0.07 s of CPU instead of 0.24),
    in the same order on the same values, so the same numbers."""
    v = np.asarray(vertices, dtype=float).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    cols = [np.ascontiguousarray(v[:, d]) for d in range(3)]
    a, b, c = ([x[np.ascontiguousarray(f[:, k])] for x in cols] for k in range(3))
    u = [bd - ad for ad, bd in zip(a, b, strict=True)]
    w = [cd - ad for ad, cd in zip(a, c, strict=True)]
    cross = [u[i] * w[j] - u[j] * w[i] for i, j in ((1, 2), (2, 0), (0, 1))]
    norm = np.sqrt(cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2])
    proper = norm > 0
    normals = [np.divide(x, norm, out=np.zeros_like(x), where=proper) for x in cross]
    # + 0.0: a zero sum is +0.0, as the mean of rows (a sum from 0.0) gives it
    centroids = [(ad + bd + cd + 0.0) / 3 for ad, bd, cd in zip(a, b, c, strict=True)]
    return normals, norm, centroids


def face_regions(vertices: np.ndarray, faces: np.ndarray,
                 max_angle_deg: float = MAX_ANGLE_DEG,
                 geometry: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 eid: np.ndarray | None = None) -> np.ndarray:
    """Region label (0..k-1) of each face: components of the face graph whose edges join
    facets turning by at most ``max_angle_deg``, with consistent curvature. ``geometry``:
    the faces' :func:`face_geometry`, ``eid`` their :func:`repair.topology.edge_ids`, if
    the caller has them."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    if geometry is None:
        normals, norm, centroids = _face_columns(v, f)
        proper = norm > 0  # a degenerate face's normal is 0
    else:
        normals, centroids = ([np.ascontiguousarray(x[:, d]) for d in range(3)]
                              for x in (geometry[0], geometry[2]))
        proper = (normals[0] != 0) | (normals[1] != 0) | (normals[2] != 0)
    if eid is None:
        eid, _ = edge_ids(f)
    first, second, _ = paired_half_edges(eid)
    fa, fb = first // 3, second // 3
    # Coordinate by coordinate (1-D gathers): the same sums of products as on rows.
    cos = sum_of_products(normals, fa, fb)
    turn = np.arccos(np.clip(cos, -1.0, 1.0))
    # curvature across the edge: turn per distance between the two centroids
    d = [x[fa] - x[fb] for x in centroids]
    dist = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    kappa = turn / np.maximum(dist, 1e-12)
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


def sum_of_products(cols: list[np.ndarray], ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """Dot products of the vectors ``ia`` and ``ib`` of three coordinate columns, summed
    x, y, z in that order (what ``einsum("ij,ij->i")`` on the rows gives)."""
    x, y, z = cols
    return x[ia] * x[ib] + y[ia] * y[ib] + z[ia] * z[ib]
