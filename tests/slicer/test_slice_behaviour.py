"""Behaviour of the G-code beyond geometry: skins, retraction, fan, progress, E modes, time."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gcode_replay import replay
from manifold3d import CrossSection, JoinType
from slice_checks import bead_footprint, bridge_part, cube, layer_heights, part_with_holes, sphere

from slicer.engine import SliceError, slice_mesh
from slicer.gcode import trapezoid_time
from slicer.profile import Profile

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180))


def _slice(model, **over):
    v, f = model()
    profile = BASE.with_overrides(over)
    result = slice_mesh(v, f, profile)
    return v, f, profile, result, replay(result.gcode)


def _per_layer_volume(rep, profile):
    area = math.pi * (profile.filament_diameter / 2) ** 2
    layers = rep.layers()
    zs = sorted(layers)
    return zs, [rep.de[layers[z]].sum() * area for z in zs]


def test_top_and_bottom_skins_are_solid_and_the_middle_is_sparse():
    _, _, profile, _, rep = _slice(cube, skirts=0, infill_percent=20)
    zs, vol = _per_layer_volume(rep, profile)
    hs = layer_heights(zs)
    fill = [v / (h * 400.0) for v, h in zip(vol, hs, strict=True)]  # 20 × 20 mm section
    for i in list(range(profile.bottom_layers)) + list(range(-profile.top_layers, 0)):
        assert fill[i] == pytest.approx(1.0, abs=0.06), f"layer {i} not solid"
    middle = fill[len(fill) // 2]
    assert 0.15 < middle < 0.5, f"middle layer fill {middle:.2f}"


def test_bridge_deck_is_solid_over_the_gap():
    v, f, profile, _, rep = _slice(bridge_part, skirts=0, infill_percent=10)
    layers = rep.layers()
    zs = sorted(layers)
    # placement: the 29 × 8 mm footprint is centred on the bed; the gap is x = 4..20
    x0 = profile.build_volume[0] / 2 - 14.5
    y0 = profile.build_volume[1] / 2 - 4.0
    gap = CrossSection.square([16.0, 8.0]).translate([x0 + 4.0, y0])
    overhang = CrossSection.square([5.0, 8.0]).translate([x0 + 24.0, y0])
    z = min(z for z in zs if z > 10.0)  # first deck layer, printed over air
    beads = bead_footprint(rep, layers[z], z - max(q for q in zs if q < z),
                           profile.filament_diameter)
    for region in (gap, overhang):
        inner = region.offset(-0.25, JoinType.Miter)  # the part's wall band aside
        assert (inner ^ beads).area() / inner.area() >= 0.97
    # on a sparse (10 %) layer inside the pillars' height the gap is empty
    z_low = max(z for z in zs if z < 9.0)
    low = bead_footprint(rep, layers[z_low], profile.layer_height, profile.filament_diameter)
    assert (gap.offset(-0.1, JoinType.Miter) ^ low).area() == 0.0


def test_travels_leaving_the_part_are_retracted():
    v, f, profile, _, rep = _slice(part_with_holes, skirts=0, retract_min_travel=2.0)
    xy = np.hypot(*(rep.end[:, :2] - rep.start[:, :2]).T)
    retracted = 0.0
    checked = 0
    last_extrusion = int(np.flatnonzero(rep.extruding)[-1])
    for i in range(last_extrusion):
        if xy[i] == 0 and rep.de[i] != 0:
            retracted -= rep.de[i]
            continue
        if xy[i] > 0 and rep.de[i] == 0 and rep.end[i, 2] == rep.start[i, 2] \
                and rep.start[i, 2] > 0 and xy[i] > profile.retract_min_travel:
            checked += 1
            assert retracted == pytest.approx(profile.retract_length), \
                f"long travel at line {rep.line_no[i]} without retraction"
        if rep.de[i] > 0 and xy[i] > 0:
            assert abs(retracted) < 1e-6, f"extruding while retracted, line {rep.line_no[i]}"
    assert checked > 0


def test_fan_progress_and_first_layer_settings():
    _, _, profile, result, rep = _slice(cube, first_layer_speed=15, disable_fan_first_layers=2)
    text = result.gcode
    layers = rep.layers()
    zs = sorted(layers)
    # fan: off at start, on (M106) only when layer index 2 begins
    first_on = next(no for no, s in rep.fan if s > 0)
    layer2_first = rep.line_no[layers[zs[2]][0]]
    layer1_first = rep.line_no[layers[zs[1]][0]]
    assert layer1_first < first_on < layer2_first
    assert rep.fan[-1][1] == 0  # switched off at the end
    # progress climbs monotonically to 100
    ps = [p for _, p in rep.progress]
    assert ps == sorted(ps) and ps[-1] == 100 and len(ps) >= len(zs)
    # first layer at first-layer speed and first-layer width
    first = layers[zs[0]]
    assert set(np.unique(rep.feed[first])) == {15 * 60.0}
    seg = np.hypot(*(rep.end[first, :2] - rep.start[first, :2]).T)
    area = math.pi * (profile.filament_diameter / 2) ** 2
    h = zs[0]
    width = rep.de[first] * area / (seg * h) + h * (1 - math.pi / 4)
    long = seg > 5
    assert np.median(width[long]) == pytest.approx(profile.first_layer_line_width, rel=0.02)
    assert "M109" in text.split(";LAYER:0")[0]


def test_absolute_and_relative_e_deposit_the_same():
    _, _, profile, _, rel = _slice(sphere, relative_e=True)
    _, _, _, res_abs, ab = _slice(sphere, relative_e=False)
    assert "M82" in res_abs.gcode and "G92 E0" in res_abs.gcode
    assert ab.de.sum() == pytest.approx(rel.de.sum(), rel=1e-4)
    assert ab.de.sum() > 0
    np.testing.assert_allclose(ab.end[ab.extruding][:, :2], rel.end[rel.extruding][:, :2])


def test_time_estimate_is_between_cruise_time_and_a_sane_bound():
    _, _, profile, result, rep = _slice(cube)
    length = np.linalg.norm(rep.end - rep.start, axis=1)
    moving = length > 0
    cruise = float((length[moving] / (rep.feed[moving] / 60.0)).sum())
    est = result.summary["estimated_seconds"]
    assert cruise < est < 2.5 * cruise


def test_trapezoid_of_a_single_long_move():
    pts = np.array([[0.0, 0.0], [100.0, 0.0]])
    t = trapezoid_time(pts, np.array([100.0]), np.array([1000.0]), jerk=8.0)
    # start/end at jerk/2 = 4 mm/s; accelerate at 1000 mm/s² to 100 mm/s, cruise, brake
    v0 = 4.0
    ramp = (100.0 - v0) / 1000.0
    d_ramp = (100.0 ** 2 - v0 ** 2) / 2000.0
    assert t == pytest.approx(2 * ramp + (100.0 - 2 * d_ramp) / 100.0, rel=1e-9)
    # a short move never reaches cruise speed and takes longer than length/speed
    short = trapezoid_time(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([100.0]),
                           np.array([1000.0]), jerk=8.0)
    assert short > 1.0 / 100.0


def test_model_larger_than_the_bed_names_both_sizes():
    v, f = cube(30.0)
    with pytest.raises(SliceError, match=r"30\.0 × 30\.0 × 30\.0.*25 × 25 × 100"):
        slice_mesh(v, f, BASE.with_overrides({"build_volume": (25, 25, 100)}))


def test_open_mesh_is_refused():
    v, f = cube(10.0)
    with pytest.raises(SliceError, match="manifold"):
        slice_mesh(v, f[:-1], BASE)


def test_skirt_surrounds_the_first_layer_only():
    v, f, profile, _, rep = _slice(cube, skirts=1, skirt_distance=3.0)
    layers = rep.layers()
    zs = sorted(layers)
    cx, cy = profile.build_volume[0] / 2, profile.build_volume[1] / 2
    first = layers[zs[0]]
    reach = np.abs(rep.end[first, :2] - [cx, cy]).max(axis=1)
    assert reach.max() > 10.0 + 3.0  # beyond the 20 mm cube by the skirt distance
    for z in zs[1:]:
        idx = layers[z]
        assert np.abs(rep.end[idx, :2] - [cx, cy]).max() <= 10.0 + 0.2


def test_z_hop_returns_to_the_layer_and_never_below():
    _, _, profile, _, rep = _slice(part_with_holes, retract_lift=0.4, skirts=0)
    dz = rep.end[:, 2] - rep.start[:, 2]
    downs = np.flatnonzero(dz < -1e-9)
    assert len(downs) > 0, "no hop at all"
    printed = np.maximum.accumulate(np.where(rep.extruding, rep.end[:, 2], 0.0))
    last_extrusion = int(np.flatnonzero(rep.extruding)[-1])
    for i in downs[downs < last_extrusion]:
        assert dz[i] == pytest.approx(-0.4, abs=1e-6)  # exactly undoing the hop
        assert rep.end[i, 2] >= printed[i] - 1e-9


def test_heating_is_added_when_the_start_template_has_none():
    _, _, _, result, rep = _slice(cube, start_gcode="G28\n; my printer\n", temperature=205,
                                  first_layer_temperature=205)
    first_line = rep.line_no[np.flatnonzero(rep.de > 0)[0]]
    waits = [(no, s) for no, cmd, s in rep.temps if cmd == "M109"]
    assert waits and waits[0][0] < first_line and waits[0][1] == 205


def test_unknown_template_placeholder_is_a_slice_error():
    v, f = cube(10.0)
    with pytest.raises(SliceError, match="nozzle_temp"):
        slice_mesh(v, f, BASE.with_overrides({"start_gcode": "M109 S{nozzle_temp}"}))


def test_stl_soup_is_welded_before_slicing():
    v, f = sphere(radius=5.0, subdivisions=3)
    soup_v = np.asarray(v)[np.asarray(f)].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    welded = slice_mesh(v, f, BASE).summary
    from_soup = slice_mesh(soup_v, soup_f, BASE).summary
    assert from_soup == welded


def test_inside_out_mesh_is_sliced_as_the_same_solid():
    v, f = cube(12.0)
    normal = slice_mesh(v, f, BASE).summary
    inverted = slice_mesh(v, np.asarray(f)[:, ::-1], BASE).summary
    assert inverted == normal


def test_progress_climbs_per_layer_to_one():
    v, f = sphere()
    events: list[tuple[str, float]] = []
    result = slice_mesh(v, f, BASE, progress=lambda s, x: events.append((s, x)))
    fractions = [x for _, x in events]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    gcode_events = [x for s, x in events if s == "gcode"]
    # on a 100-layer job the G-code stage reports about once per layer
    assert len(gcode_events) >= result.summary["layers"] // 2


def test_small_layers_are_slowed_down_to_the_minimum_layer_time():
    from slice_checks import thin_pin

    _, _, profile, _, rep = _slice(lambda: thin_pin(3.0, 10.0), min_layer_time=6.0,
                                   min_print_speed=1.0, skirts=0)
    layers = rep.layers()
    zs = sorted(layers)
    lengths = np.hypot(*(rep.end[:, :2] - rep.start[:, :2]).T)
    for z in zs[2:-1]:
        idx = layers[z]
        # a lower bound from the replay itself: every extrusion at its commanded feedrate
        cruise = float((lengths[idx] / (rep.feed[idx] / 60.0)).sum())
        slowest = rep.feed[idx].min() / 60.0
        assert cruise >= 6.0 * 0.85 or slowest <= 1.0 + 1e-6, f"layer {z}: {cruise:.2f} s"
    _, _, _, _, fast = _slice(lambda: thin_pin(3.0, 10.0), min_layer_time=0, skirts=0)
    assert fast.feed[fast.extruding].min() > rep.feed[rep.extruding].min()


def test_bridge_lines_span_the_gap_slowly_with_the_bridge_fan():
    _, _, profile, _, rep = _slice(bridge_part, skirts=0, infill_percent=10, fan_speed=50,
                                   bridge_fan_speed=100, bridge_speed=20)
    layers = rep.layers()
    zs = sorted(layers)
    x0 = profile.build_volume[0] / 2 - 14.5
    y0 = profile.build_volume[1] / 2 - 4.0
    z = min(z for z in zs if z > 10.0)
    idx = layers[z]
    mid = (rep.start[idx, :2] + rep.end[idx, :2]) / 2
    # inside the gap and clear of the deck's walls
    in_gap = idx[(mid[:, 0] > x0 + 5) & (mid[:, 0] < x0 + 19) & (mid[:, 1] > y0 + 1.2)
                 & (mid[:, 1] < y0 + 6.8)]
    d = rep.end[in_gap, :2] - rep.start[in_gap, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    along_x = np.abs(d[:, 0]) > 0.99 * length
    assert length[along_x].sum() > 0.9 * length.sum()  # pillar to pillar, not diagonal
    long = in_gap[length > 10]
    assert len(long) > 10 and set(rep.feed[long]) == {20 * 60.0}
    first_bridge_line = rep.line_no[long].min()
    last_bridge_line = rep.line_no[long].max()
    before = [s for no, s in rep.fan if no < first_bridge_line]
    after = [s for no, s in rep.fan if last_bridge_line < no < rep.line_no[idx].max() + 50]
    assert before[-1] == 255 and after and after[0] == round(255 * 0.5)


@pytest.mark.parametrize("over", [
    {"top_layers": 0, "bottom_layers": 0},
    {"perimeters": 0},
    {"infill_percent": 0},
    {"infill_pattern": "rectilinear", "relative_e": False, "retract_lift": 0.3},
    {"perimeters": 5, "infill_percent": 60, "skirts": 3},
])
def test_setting_extremes_still_print_inside_the_part(over):
    v, f, profile, result, rep = _slice(sphere, **{"skirts": 0, **over})
    ext = rep.extruding
    assert ext.any() and result.summary["filament_mm"] > 0
    c = np.array(profile.build_volume[:2]) / 2
    reach = np.hypot(*(rep.end[ext, :2] - c).T).max()
    assert reach <= 10.0 + 0.3 + (profile.skirt_distance + 3 * 0.45 if profile.skirts else 0)


def _layers_starting_at_the_rear(rep) -> float:
    layers = rep.layers(rep.part)  # the part's loops (support under the sphere aside)
    zs = sorted(layers)[5:-5]
    hits = 0
    for z in zs:
        idx = layers[z]
        rear = rep.start[idx, 1].max()
        begins = idx[~rep.extruding[idx - 1]]  # extrusions right after a non-extruding move
        hits += bool((np.abs(rep.start[begins, 1] - rear) < 1e-6).any())
    return hits / len(zs)


def test_external_perimeter_seams_line_up_at_the_rear():
    # a path (the outer loop) begins at the rearmost point of every layer
    _, _, _, _, rear = _slice(sphere, skirts=0, seam_position="rear")
    assert _layers_starting_at_the_rear(rear) == 1.0
    _, _, _, _, nearest = _slice(sphere, skirts=0, seam_position="nearest")
    assert _layers_starting_at_the_rear(nearest) < 0.5
