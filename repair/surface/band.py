"""Ruled features (cylinders, cones) whose facets form one band between two rims.

The paper's three-way split of a long cylinder facet makes ever thinner triangles, and
splitting its diagonal puts vertices half way up the wall whose new edges sag again: the
triangle count grows past 10x. On a cylinder or cone the chordal error of an edge depends
only on the angle it spans around the axis, so once both rims are refined (their edge
points moved onto the surface, in both faces), the band is re-connected rim to rim: a
zipper that advances along whichever rim's next vertex comes first around the axis. Each
new edge then spans at most one rim step, and the band has one triangle per rim vertex.
"""

from __future__ import annotations

import numpy as np

from repair.surface.fit import Surface, _frame
from repair.surface.patches import border_loops


def _angles(surface: Surface, points: np.ndarray) -> np.ndarray:
    frame = _frame(surface.axis)
    rel = points - surface.origin
    return np.arctan2(rel @ frame[1], rel @ frame[0]) % (2 * np.pi)


def _monotone(surface: Surface, v: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The loop's vertices in increasing angle from the smallest, and their angles; raises
    ValueError when the loop does not go once around the axis."""
    theta = _angles(surface, v[loop])
    step = (np.diff(np.r_[theta, theta[0]]) + np.pi) % (2 * np.pi) - np.pi
    if np.all(step < 0):
        loop, theta, step = loop[::-1], theta[::-1], -step[::-1]
    if not np.all(step > 0) or abs(step.sum() - 2 * np.pi) > 1e-6:
        raise ValueError("the feature is not a band around its axis")
    start = int(np.argmin(theta))
    return np.roll(loop, -start), np.roll(theta, -start)


def zip_band(surface: Surface, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """New faces for the band ``faces`` (two border loops around the axis), oriented like
    the old ones. Raises ValueError when ``faces`` is not such a band."""
    loops = border_loops(faces, len(vertices))
    if len(loops) != 2:
        raise ValueError("the feature is not a band between two rims")
    (a, ta), (b, tb) = (_monotone(surface, vertices, lp) for lp in loops)
    # advance events: A's vertex k+1 at angle ta[k+1] (the last wraps to ta[0] + 2π)
    na, nb = len(a), len(b)
    key = np.r_[np.r_[ta[1:], ta[0] + 2 * np.pi], np.r_[tb[1:], tb[0] + 2 * np.pi]]
    is_a = np.r_[np.ones(na, bool), np.zeros(nb, bool)]
    order = np.argsort(key, kind="stable")
    is_a = is_a[order]
    i = np.cumsum(is_a) - is_a  # A advances before this event
    j = np.cumsum(~is_a) - ~is_a
    tri = np.where(is_a[:, None],
                   np.column_stack([a[i % na], a[(i + 1) % na], b[j % nb]]),
                   np.column_stack([a[i % na], b[(j + 1) % nb], b[j % nb]]))
    # orient like the old faces: their normals' side of the surface
    old = _side(surface, vertices, faces)
    new = _side(surface, vertices, tri, each=True)
    tri = np.where((new * old < 0)[:, None], tri[:, [0, 2, 1]], tri)
    return tri


def _side(surface: Surface, vertices: np.ndarray, faces: np.ndarray, each: bool = False):
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    dots = np.einsum("ij,ij->i", n, surface.normal(tri.mean(1)))
    return dots if each else float(np.sign(dots.sum()))
