"""Orientation (orient = keep | auto | if-needed) and arrangement (arrange = true) end to end:
the G-code is replayed and compared with the model turned by the rotation the report gives."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gcode_replay import replay
from manifold3d import CrossSection, FillRule, Manifold
from slice_checks import (
    bead_footprint,
    cube,
    cup,
    expected_layers,
    flanged_pin_on_its_side,
    mesh_of,
    overhang_area,
    placed,
    sphere,
)

from slicer.engine import SliceError, slice_mesh
from slicer.profile import Profile

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180)).with_overrides(
    {"skirts": 0, "thumbnails": ""})
AREA = math.pi * (BASE.filament_diameter / 2) ** 2


def _first_layer_area(rep, h):
    layers = rep.layers()
    z = min(layers)
    return float(rep.de[layers[z]].sum() * AREA / h)


@pytest.mark.parametrize("model", [lambda: cup(flipped=True), flanged_pin_on_its_side],
                         ids=["cup_upside_down", "pin_on_its_side"])
def test_auto_orientation_prints_without_support(model):
    v, f = model()
    assert overhang_area(v, f) > 100.0  # as saved, it needs support
    result = slice_mesh(v, f, BASE.with_overrides({"orient": "auto", "infill_percent": 100}))
    report = result.summary["orientation"]
    assert report["rotated"] and report["cost_as_saved"]["support_mm2"] > 100
    rot = np.array(report["rotation"])
    assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) and np.linalg.det(rot) > 0
    turned = np.asarray(v) @ rot.T
    assert overhang_area(turned, f) < 1.0
    # the G-code is the turned model: its layer count and first layer match, not the saved one
    rep = replay(result.gcode)
    height = float(np.ptp(turned[:, 2]))
    assert len(rep.layers()) == expected_layers(height, BASE.first_layer_height,
                                                BASE.layer_height)
    h = BASE.first_layer_height
    want = placed(turned, f, BASE.build_volume).slice(h / 2).area()
    assert _first_layer_area(rep, h) == pytest.approx(want, rel=0.08)
    volume = placed(turned, f, BASE.build_volume).volume()
    assert rep.de.sum() * AREA / volume == pytest.approx(1.0, abs=0.07)


def test_keep_is_the_default_and_keeps_the_saved_orientation():
    v, f = cup(flipped=True)
    result = slice_mesh(v, f, BASE)
    assert result.summary["orientation"] == {"mode": "keep", "rotated": False}
    rep = replay(result.gcode)
    h = BASE.first_layer_height
    ring = placed(v, f, BASE.build_volume).slice(h / 2).area()  # standing on its rim
    assert _first_layer_area(rep, h) == pytest.approx(ring, rel=0.08)


def test_if_needed_turns_only_when_that_avoids_support_entirely():
    v, f = cup(flipped=True)
    turned = slice_mesh(v, f, BASE.with_overrides({"orient": "if-needed"})).summary
    assert turned["orientation"]["rotated"]
    assert turned["orientation"]["cost"]["support_mm2"] < 1.0
    # a sphere needs support whichever way it lies: kept, and the report says why
    sv, sf = sphere()
    kept = slice_mesh(sv, sf, BASE.with_overrides({"orient": "if-needed"})).summary
    assert not kept["orientation"]["rotated"]
    assert "no orientation avoids support" in kept["orientation"]["reason"]
    # a cube saved upright needs nothing: kept too
    cv, cf = cube()
    assert not slice_mesh(cv, cf, BASE.with_overrides(
        {"orient": "if-needed"})).summary["orientation"]["rotated"]


def test_bad_orient_value_names_the_setting():
    from slicer.profile import ProfileError

    with pytest.raises(ProfileError, match="orient"):
        BASE.with_overrides({"orient": "sideways"})


# ---- arrangement -----------------------------------------------------------------------
def _islands(rep, h):
    layers = rep.layers()
    beads = bead_footprint(rep, layers[min(layers)], h, BASE.filament_diameter)
    return [CrossSection(c.to_polygons(), FillRule.Positive) for c in beads.decompose()]


def test_separate_bodies_are_set_apart_on_the_bed():
    # two 20 mm cubes 1 mm apart, the second floating 5 mm up: they print as two parts,
    # both on the bed, at least arrange_gap apart
    a = Manifold.cube([20, 20, 20])
    b = Manifold.cube([20, 20, 20]).translate([21, 0, 5])
    v, f = mesh_of(a + b)
    gap = 8.0
    result = slice_mesh(v, f, BASE.with_overrides({"arrange": True, "arrange_gap": gap,
                                                   "infill_percent": 100}))
    assert result.summary["arrangement"]["bodies"] == 2
    rep = replay(result.gcode)
    h = BASE.first_layer_height
    islands = _islands(rep, h)
    assert len(islands) == 2
    assert all(i.area() == pytest.approx(400.0, rel=0.05) for i in islands)
    (x0, y0, x1, y1), (u0, v0, u1, v1) = (i.bounds() for i in islands)
    apart = max(u0 - x1, x0 - u1, v0 - y1, y0 - v1)
    assert apart >= gap - BASE.first_layer_line_width
    assert rep.de.sum() * AREA == pytest.approx(16000.0, rel=0.07)
    assert len(rep.layers()) == expected_layers(20.0, h, BASE.layer_height)


def test_a_hollow_part_is_one_body_and_is_not_split():
    # an inner void is a second shell inside the first: arranging must leave it in place
    v, f = mesh_of(Manifold.cube([20, 20, 20]) - Manifold.cube([10, 10, 10]).translate([5, 5, 5]))
    plain = slice_mesh(v, f, BASE).summary
    arranged = slice_mesh(v, f, BASE.with_overrides({"arrange": True})).summary
    assert arranged["arrangement"]["bodies"] == 1
    assert {k: x for k, x in arranged.items() if k != "arrangement"} == plain


def test_bodies_that_do_not_fit_give_a_clear_error():
    parts = Manifold.batch_boolean([Manifold.cube([80, 80, 10]).translate([100 * i, 0, 0])
                                    for i in range(5)], __import__("manifold3d").OpType.Add)
    v, f = mesh_of(parts)
    with pytest.raises(SliceError, match=r"5 separate bodies need .* the bed is 200 × 200 mm"):
        slice_mesh(v, f, BASE.with_overrides({"arrange": True}))


def test_auto_does_not_stand_a_ring_on_its_edge_and_lays_a_tall_pin_down():
    import trimesh

    from slicer.orient import choose_orientation

    # a 24k-vertex torus lying flat: standing it on its edge would need less support, but a
    # ring on its edge wobbles (the tipping term); its hull is taken from a subsample
    ring = trimesh.creation.torus(30.0, 8.0, major_sections=200, minor_sections=120)
    kept = choose_orientation(ring.vertices, ring.faces, "auto")
    assert not kept.rotated and kept.terms["tipping"] == 0.0
    assert overhang_area(ring.vertices, ring.faces) > 100.0  # it does need support flat
    pin = trimesh.creation.box((5.0, 5.0, 80.0))
    laid = choose_orientation(pin.vertices, pin.faces, "auto")
    assert laid.rotated and laid.terms["height_mm"] == pytest.approx(5.0)
    assert laid.kept_terms["tipping"] == 1.0
