"""Fuzz targets of the repair: small random triangle soups through ``repair_mesh``.

Inputs are what an STL or OBJ can hold: coordinates from a small integer grid (so
duplicate vertices, duplicate and degenerate triangles, coplanar overlaps and edges
shared by many faces are common) or arbitrary float32 values, either as a soup of 1-24
triangles (three corners each) or as 1-60 triangles indexed into 3-12 shared vertices. The
property: a printable result (checked) or a :class:`repair.pipeline.RepairError`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from harness import Target
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from repair.check import check_printable
from repair.pipeline import RepairError, repair_mesh

#: Sheet thickness and wire diameter the targets repair with (mm).
EPSILON = 0.4
#: Triangles of a soup. Every soup triangle is a sheet crossing the others: 50-60 of
#: them arrange and thicken into ~16k triangles, 2-8 s each here, too close to the
#: harness's 10 s hang bound on a loaded machine for a CI run.
MAX_SOUP_TRIANGLES = 24

_grid = st.integers(-3, 3).map(float)
_any = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False, width=32)
_coordinate = st.one_of(_grid, _grid, _any)


def _soups() -> st.SearchStrategy:
    """Triangle soups: (n, 3, 3) corners, n in 1..MAX_SOUP_TRIANGLES."""
    def faces_of(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(corners)
        return corners.reshape(-1, 3), np.arange(3 * n, dtype=np.int64).reshape(n, 3)

    shapes = st.integers(1, MAX_SOUP_TRIANGLES).map(lambda n: (n, 3, 3))
    return arrays(np.float64, shapes, elements=_coordinate).map(faces_of)


def _indexed() -> st.SearchStrategy:
    """Indexed meshes: 3..12 vertices, 1..60 faces of indices into them."""
    def mesh(k: int, n: int) -> st.SearchStrategy:
        vertices = arrays(np.float64, (k, 3), elements=_coordinate)
        faces = arrays(np.int64, (n, 3), elements=st.integers(0, k - 1))
        return st.tuples(vertices, faces)

    return st.tuples(st.integers(3, 12), st.integers(1, 60)).flatmap(lambda kn: mesh(*kn))


def repair_soup(value: tuple[np.ndarray, np.ndarray]) -> Any:
    """Repair; a result must pass the printability check on its own coordinates."""
    vertices, faces = value
    result = repair_mesh(vertices, faces, EPSILON)
    verdict = check_printable(result.vertices, result.faces)
    assert verdict.ok, f"repair_mesh returned an unprintable mesh: {verdict.failures()}"
    return result


TARGETS: list[Target] = [
    Target(
        name="repair-soup",
        strategy=st.one_of(_soups(), _indexed()),
        run=repair_soup,
        expected=(RepairError,),
        modules=("repair.pipeline", "repair.clean", "repair.hull", "repair.finish",
                 "repair.thicken", "repair.union", "repair.topology"),
    ),
]
