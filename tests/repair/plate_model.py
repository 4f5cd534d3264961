"""The design plate of issue 19: a plate with through-holes and a boss, from exact geometry.

The design constants are module constants so every test (STL export at a chosen number of
segments, a STEP of the same part, the G-code hole gauge) refers to one design. Units mm; the
plate's lower corner is at the origin, its bottom face on z = 0.

Built with manifold3d CSG: ``Manifold.cylinder`` puts its ``segments`` vertices exactly on the
design radius, so a hole's facets lie inside the design circle (the hole prints undersized)
and a boss's facets inside its design circle too (the flats are undersized, the corners
exact).
"""

from __future__ import annotations

import numpy as np
from manifold3d import Manifold

#: plate size x, y, z (thickness)
PLATE_SIZE = (60.0, 40.0, 6.0)
#: through-holes: (centre x, centre y, radius), all along z through the plate
HOLES = ((12.0, 12.0, 3.0), (12.0, 28.0, 2.0), (30.0, 20.0, 4.0))
#: the boss: a cylinder standing on the plate's top face
BOSS_CENTRE = (47.0, 20.0)
BOSS_RADIUS = 6.0
BOSS_HEIGHT = 8.0
#: segment counts the issue's Test 1 exports at
SEGMENTS = (12, 24, 48)


def plate_manifold(segments: int) -> Manifold:
    """The plate with each circle of the design approximated by ``segments`` facets."""
    sx, sy, sz = PLATE_SIZE
    part = Manifold.cube([sx, sy, sz])
    boss = Manifold.cylinder(BOSS_HEIGHT + 1.0, BOSS_RADIUS, BOSS_RADIUS, segments)
    part = part + boss.translate([BOSS_CENTRE[0], BOSS_CENTRE[1], sz - 1.0])
    for cx, cy, r in HOLES:
        drill = Manifold.cylinder(sz + 2.0, r, r, segments).translate([cx, cy, -1.0])
        part = part - drill
    return part


def plate(segments: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) float64, faces (m, 3) int64) of the plate at ``segments``."""
    mesh = plate_manifold(segments).to_mesh()
    vertices = np.asarray(mesh.vert_properties[:, :3], dtype=np.float64)
    return vertices, np.asarray(mesh.tri_verts, dtype=np.int64)


def bounding_box() -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corner of the design part (the boss lies inside the plate's outline)."""
    sx, sy, sz = PLATE_SIZE
    return np.zeros(3), np.array([sx, sy, sz + BOSS_HEIGHT])
