"""Model builders and geometric checks for the slicer tests (independent of slicer code).

Models are closed manifold solids in mm built with trimesh/manifold3d. Checks replay the
G-code (gcode_replay) and compare the deposited beads with the model's own cross-sections.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh
from gcode_replay import Replay
from manifold3d import CrossSection, FillRule, JoinType, Manifold, Mesh

BEAD_SHAPE = 1.0 - math.pi / 4.0  # rounded-rectangle bead: area = h·(w − h·BEAD_SHAPE)


def manifold_of(vertices, faces) -> Manifold:
    return Manifold(Mesh(vert_properties=np.asarray(vertices, np.float32),
                         tri_verts=np.asarray(faces, np.uint32)))


def mesh_of(m: Manifold) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], float), np.asarray(mesh.tri_verts, np.int64)


def cube(size=20.0):
    b = trimesh.creation.box((size, size, size))
    return b.vertices, b.faces


def sphere(radius=10.0, subdivisions=4):
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return s.vertices, s.faces


def part_with_holes():
    plate = Manifold.cube([30, 20, 6])
    hole = Manifold.cylinder(20, 3.0, 3.0, 48).translate([8, 10, -5])
    hole2 = Manifold.cylinder(20, 2.0, 2.0, 40).translate([22, 10, -5])
    return mesh_of(plate - hole - hole2)


def hollow_box(wall=0.8):
    outer = Manifold.cube([20, 20, 12])
    inner = Manifold.cube([20 - 2 * wall, 20 - 2 * wall, 20]).translate([wall, wall, 1.0])
    return mesh_of(outer - inner)


def bridge_part():
    """Two pillars joined by a 16 mm bridge, plus a 5 mm overhanging ledge."""
    left = Manifold.cube([4, 8, 10])
    right = Manifold.cube([4, 8, 10]).translate([20, 0, 0])
    deck = Manifold.cube([29, 8, 2]).translate([0, 0, 10])
    return mesh_of(left + right + deck)


def thin_pin(diameter=2.0, height=25.0):
    return mesh_of(Manifold.cylinder(height, diameter / 2, diameter / 2, 32))


def sheet(thickness=0.4, length=20.0, height=10.0):
    """A repaired sheet: a plate exactly ``thickness`` thick, standing up."""
    return mesh_of(Manifold.cube([thickness, length, height]))


def l_sheet(thickness=0.4):
    """Two ε sheets meeting at a corner, standing up (an L in plan view)."""
    return mesh_of(Manifold.cube([thickness, 20, 8]) + Manifold.cube([15, thickness, 8]))


# ---------------------------------------------------------------------------------------
def placed(vertices, faces, bed_xy):
    """The placement the slicer promises: dropped onto z = 0, bbox centred on the bed."""
    v = np.asarray(vertices, float)
    lo, hi = v.min(0), v.max(0)
    shift = np.array([bed_xy[0] / 2 - (lo[0] + hi[0]) / 2, bed_xy[1] / 2 - (lo[1] + hi[1]) / 2,
                      -lo[2]])
    return manifold_of(v + shift, faces)


def expected_layers(height, first, layer):
    """Count of layers whose mid-plane lies inside a model ``height`` tall."""
    count = 0
    while True:
        mid = first / 2 if count == 0 else first + (count - 0.5) * layer
        if mid >= height - 1e-9:
            return count
        count += 1


def _octagon(c, r):
    a = np.linspace(0, 2 * np.pi, 9)[:-1]
    return np.stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a)], axis=1)


def bead_footprint(rep: Replay, idx: np.ndarray, height: float, filament_diameter: float
                   ) -> CrossSection:
    """Union of the beads of moves ``idx``; each bead's width follows from its E."""
    p0 = rep.start[idx, :2]
    p1 = rep.end[idx, :2]
    d = p1 - p0
    length = np.hypot(d[:, 0], d[:, 1])
    area_fil = math.pi * (filament_diameter / 2) ** 2
    width = rep.de[idx] * area_fil / (length * height) + height * BEAD_SHAPE
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / length[:, None] * (width[:, None] / 2)
    rects = np.stack([p0 - n, p1 - n, p1 + n, p0 + n], axis=1)
    contours = list(rects)
    # round ends and joints: an octagon (inscribed, never larger than the bead) at both ends
    for c, w in zip(np.vstack([p0, p1]), np.concatenate([width, width]), strict=True):
        contours.append(_octagon(c, w / 2))
    return CrossSection(contours, FillRule.Positive)


def layer_heights(zs: list[float]) -> list[float]:
    return [zs[0]] + [b - a for a, b in zip(zs[:-1], zs[1:], strict=True)]


# ---------------------------------------------------------------------------------------
def cup(flipped=False):
    """A cup (Ø30 × 16 mm, 2 mm floor and walls); ``flipped``: saved standing on its rim."""
    v, f = mesh_of(Manifold.cylinder(16, 15, 15, 64)
                   - Manifold.cylinder(16, 13, 13, 64).translate([0, 0, 2]))
    return (v * [1, -1, -1], f) if flipped else (v, f)


def flanged_pin_on_its_side():
    """A Ø20 × 3 mm flange under a Ø8 × 20 mm post, saved lying on its side."""
    v, f = mesh_of(Manifold.cylinder(3, 10, 10, 64) + Manifold.cylinder(23, 4, 4, 48))
    return v[:, [0, 2, 1]] * [1, 1, -1], f


def overhang_area(vertices, faces, support_angle=50.0, bed_tolerance=0.1):
    """Area (mm²) of faces facing down more steeply than ``support_angle`` from vertical
    that do not rest on the bed (the lowest z), for the mesh as it stands."""
    v = np.asarray(vertices, float)
    tri = v[np.asarray(faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1) / 2
    down = -cross[:, 2] / np.maximum(2 * area, 1e-300)
    on_bed = tri[:, :, 2].max(axis=1) <= v[:, 2].min() + bed_tolerance
    steep = down > math.cos(math.radians(90.0 - support_angle))
    return float(area[steep & ~on_bed].sum())


def u_shape():
    """A U in plan view (30 × 30 mm, a 10 × 20 mm notch), 4 mm tall."""
    outline = np.array([[0, 0], [30, 0], [30, 30], [20, 30], [20, 10], [10, 10], [10, 30],
                        [0, 30]], float)
    return mesh_of(Manifold.extrude(CrossSection([outline]), 4.0))


def ring():
    """A ring: Ø30 outside, Ø20 hole, 4 mm tall."""
    return mesh_of(Manifold.cylinder(4, 15, 15, 64) - Manifold.cylinder(10, 10, 10, 64)
                   .translate([0, 0, -3]))


def travels_leaving_their_island(rep: Replay, solid: Manifold, layer_height: float,
                                 first_layer_height: float) -> tuple[int, int]:
    """(travels checked, travels that leave the island holding both their ends).

    For every travel between two extrusions of a layer whose two ends lie in one island of
    the model's cross-section, each leg is drawn as a hair-thin strip and cut against the
    island grown by 10 µm; anything left over is a crossing of the island's outline."""
    checked = crossings = 0
    islands_at: dict[float, list[CrossSection]] = {}
    for z, legs in rep.travel_chains():
        if z not in islands_at:
            mid = z - (first_layer_height if z <= first_layer_height + 1e-6
                       else layer_height) / 2
            islands_at[z] = [i.offset(0.01, JoinType.Miter)
                             for i in solid.slice(mid).decompose()]
        a, b = rep.start[legs[0], :2], rep.end[legs[-1], :2]
        home = [i for i in islands_at[z] if _inside(i, a) and _inside(i, b)]
        if not home:
            continue
        checked += 1
        for k in legs:
            p, q = rep.start[k, :2], rep.end[k, :2]
            d = q - p
            n = np.array([-d[1], d[0]]) / np.hypot(*d) * 5e-4
            strip = CrossSection([np.array([p - n, q - n, q + n, p + n])], FillRule.Positive)
            if (strip - home[0]).area() > 1e-6:
                crossings += 1
                break
    return checked, crossings


def _inside(cs: CrossSection, pt) -> bool:
    dot = CrossSection.square([1e-3, 1e-3], center=True).translate([float(pt[0]), float(pt[1])])
    return (dot - cs).area() < 1e-9
