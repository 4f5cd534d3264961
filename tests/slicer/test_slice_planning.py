"""The planners' shortcuts give what the plain formulas give, on real layers of real solids:
run intersections for the skins, the clipped growth of the part for the support's XY gap,
and the skipped thin-wall search."""

from __future__ import annotations

import numpy as np
import pytest
from manifold3d import CrossSection, JoinType, Manifold, OpType

from slicer.geometry import bead_spacing
from slicer.overhang import near_piece
from slicer.planner import _RunIntersections, plan_shells, skin_regions

MITER = JoinType.Miter


def _layers(solid: Manifold, height: float = 0.2) -> list[CrossSection]:
    lo, hi = solid.bounding_box()[2], solid.bounding_box()[5]
    zs = np.arange(lo + height / 2, hi, height)
    return [solid.slice(float(z)).simplify(0.0125) for z in zs]


def _mushroom() -> Manifold:
    """A 30 mm bowl on an off-centre 8 mm stem, beside a 0.4 mm fin: a widening overhang on
    every layer of the bowl, a thin wall, and a column beside the fin."""
    stem = Manifold.cylinder(12.5, 4.0, 4.0, 64).translate((6.0, 0.0, 0.0))
    bowl = (Manifold.sphere(15.0, 96) ^ Manifold.cube((40.0, 40.0, 15.0), True)
            .translate((0.0, 0.0, -7.5))).translate((0.0, 0.0, 27.0))
    fin = Manifold.cube((0.4, 12.0, 20.0)).translate((-12.0, -6.0, 0.0))
    return stem + bowl + fin


def _same(a: CrossSection, b: CrossSection) -> float:
    """Area (mm²) where two cross-sections differ: intersection points fall on manifold3d's
    1e-8 mm grid, so operations done in another order may differ by a few 1e-8 mm²."""
    return (a - b).area() + (b - a).area()


@pytest.fixture(scope="module")
def layers() -> list[CrossSection]:
    return _layers(_mushroom())


def test_run_intersections_equal_the_batch_intersection(layers):
    runs = _RunIntersections(layers)
    n = len(layers)
    checked = 0
    for lo in range(0, n - 1, 3):
        for length in (1, 2, 3, 4, 5, 7, 8):
            if lo + length > n:
                continue
            whole = CrossSection.batch_boolean(layers[lo:lo + length], OpType.Intersect)
            got = runs.of(lo, lo + length)
            assert _same(got, whole) < 1e-6, (lo, length)
            checked += 1
    assert checked > 100


def test_skins_are_what_the_neighbours_do_not_cover(layers):
    width, height, top, bottom = 0.45, 0.2, 4, 3
    s = bead_spacing(width, height)
    inner = [plan_shells(cs, width, height, 2, True, 0.0125).inner for cs in layers]
    got = skin_regions(inner, layers, top, bottom, [s] * len(layers), False)
    solid_layers = 0
    for i in range(bottom, len(layers) - top):
        neigh = layers[i - bottom:i] + layers[i + 1:i + top + 1]
        solid = inner[i] - CrossSection.batch_boolean(neigh, OpType.Intersect)
        if not solid.is_empty():
            solid = solid.offset(-s / 2, MITER)
        want = solid.offset(1.5 * s, MITER) ^ inner[i] if not solid.is_empty() else solid
        assert _same(got[i], want) < 1e-6, i
        solid_layers += not want.is_empty()
    assert solid_layers > 10  # the bowl's underside and the tops of stem and fin


def test_near_piece_grows_like_the_whole_part_inside_the_box(layers):
    part = max(layers, key=lambda cs: cs.area())  # the cap, 30 mm across
    box = (8.0, -3.0, 12.0, 3.0)  # a column under its edge
    window = CrossSection.square((4.0, 6.0)).translate((8.0, -3.0))
    piece = near_piece(part, box, 0.4)
    assert piece.area() < part.area() / 4  # a small piece of it
    for gap in (0.2, 0.4, 0.8):
        grown = near_piece(part, box, gap).offset(gap, MITER)
        assert _same(grown ^ window, part.offset(gap, MITER) ^ window) < 1e-6
    # a column 0.3 mm beside the fin (x −12 .. −11.6), away from the stem: the fin's growth
    # reaches into its box
    low = layers[5]
    box = (-11.3, -3.0, -8.0, 3.0)
    window = CrossSection.square((3.3, 6.0)).translate((-11.3, -3.0))
    for gap in (0.4, 0.8):
        whole = low.offset(gap, MITER) ^ window
        assert whole.area() > 0.1 * 6.0 * (gap - 0.3)
        grown = near_piece(low, box, gap).offset(gap, MITER)
        assert _same(grown ^ window, whole) < 1e-6


def test_plan_shells_finds_the_thin_walls_the_full_search_finds(layers, monkeypatch):
    import slicer.planner as planner

    width, height = 0.45, 0.2
    fast = [plan_shells(cs, width, height, 2, True, 0.0125) for cs in layers]
    skipped = sum(not planner._may_hold_thin_walls([cs - sh.inner], bead_spacing(width, height))
                  for cs, sh in zip(layers, fast, strict=True))
    monkeypatch.setattr(planner, "_may_hold_thin_walls", lambda parts, spacing: bool(parts))
    full = [plan_shells(cs, width, height, 2, True, 0.0125) for cs in layers]
    with_thin = 0
    for a, b in zip(fast, full, strict=True):
        assert len(a.thin) == len(b.thin)
        for p, q in zip(a.thin, b.thin, strict=True):
            assert p.width == q.width and np.array_equal(p.points, q.points)
        with_thin += bool(a.thin)
    assert with_thin > 5  # the fin's layers
    assert skipped < len(layers)
