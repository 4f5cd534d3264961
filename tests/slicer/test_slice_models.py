"""Slice real solids and check the replayed G-code against the models' own cross-sections."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gcode_replay import replay
from manifold3d import JoinType
from slice_checks import (
    bead_footprint,
    bridge_part,
    cube,
    expected_layers,
    hollow_box,
    l_sheet,
    layer_heights,
    part_with_holes,
    placed,
    sheet,
    sphere,
    thin_pin,
)
from support_checks import arch, mushroom, ramp, t_bracket

from slicer.engine import slice_mesh
from slicer.profile import Profile

MODELS = {
    "cube": cube,
    "sphere": sphere,
    "holes": part_with_holes,
    "hollow_box": hollow_box,
    "bridge": bridge_part,
    "thin_pin": thin_pin,
    "eps_sheet": sheet,
    "eps_l_sheet": l_sheet,
    # overhangs: printed with the default support = auto
    "mushroom": mushroom,
    "t_bracket": t_bracket,
    "arch": arch,
    "ramp_45": lambda: ramp(45.0),
    "ramp_75": lambda: ramp(75.0),
}

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180)).with_overrides(
    {"skirts": 0}
)
_cache: dict[tuple[str, str], tuple] = {}


def sliced(name: str, overrides: dict | None = None):
    key = (name, repr(sorted((overrides or {}).items())))
    if key not in _cache:
        v, f = MODELS[name]()
        profile = BASE.with_overrides(overrides or {})
        result = slice_mesh(v, f, profile)
        _cache[key] = (v, f, profile, result, replay(result.gcode))
    return _cache[key]


@pytest.mark.parametrize("name", list(MODELS))
def test_extrusions_stay_on_the_bed_and_start_hot(name):
    _, _, profile, _, rep = sliced(name)
    ext = rep.extruding
    assert ext.any(), "no extrusion at all"
    bx, by, bz = profile.build_volume
    for pts in (rep.start[ext], rep.end[ext]):
        assert (pts[:, 0] >= 0).all() and (pts[:, 0] <= bx).all()
        assert (pts[:, 1] >= 0).all() and (pts[:, 1] <= by).all()
        assert (pts[:, 2] > 0).all() and (pts[:, 2] <= bz).all()
    first_line = rep.line_no[np.flatnonzero(rep.de > 0)[0]]
    waited = [s for no, cmd, s in rep.temps if cmd == "M109" and no < first_line]
    assert waited and max(waited) >= 170, "hotend not heated (M109) before the first extrusion"


@pytest.mark.parametrize("name", list(MODELS))
def test_z_only_rises_and_layer_count_is_right(name):
    v, _, profile, result, rep = sliced(name)
    printed_top = -math.inf
    last_z = None
    for s, e, de in zip(rep.start, rep.end, rep.de, strict=True):
        if e[2] < s[2] - 1e-9:
            # only an explicit hop may come down, and never below the printed layers
            assert e[2] >= printed_top - 1e-6, f"Z went down to {e[2]} below {printed_top}"
        if de > 0 and np.hypot(*(e[:2] - s[:2])) > 0:
            if last_z is not None:
                assert e[2] >= last_z - 1e-9
            last_z = e[2]
            printed_top = max(printed_top, e[2])
    height = np.ptp(np.asarray(v)[:, 2])
    want = expected_layers(height, profile.first_layer_height, profile.layer_height)
    assert len(rep.layers()) == want
    assert result.summary["layers"] == want


@pytest.mark.parametrize("name", list(MODELS))
def test_full_infill_volume_matches_mesh(name):
    v, f, profile, result, rep = sliced(name, {"infill_percent": 100})
    volume = placed(v, f, profile.build_volume).volume()
    area = math.pi * (profile.filament_diameter / 2) ** 2
    # the part's own extrusions (support, skirt and brim are labelled apart)
    extruded = rep.de[rep.part].sum() * area
    ratio = extruded / volume
    assert 0.93 <= ratio <= 1.08, f"extruded/mesh volume = {ratio:.3f}"
    assert result.summary["filament_cm3"] == pytest.approx(rep.de.sum() * area / 1000, rel=0.01)
    # and layer by layer: nothing printed twice, nothing left out
    solid = placed(v, f, profile.build_volume)
    layers = rep.layers(rep.part)
    zs = sorted(layers)
    for z, h in zip(zs, layer_heights(zs), strict=True):
        want = solid.slice(z - h / 2).area() * h
        got = rep.de[layers[z]].sum() * area
        if want > 1.0:  # mm³: tiny tips of spheres and pins aside
            assert got / want == pytest.approx(1.0, abs=0.07), f"layer z={z}"


@pytest.mark.parametrize("name", list(MODELS))
def test_beads_cover_the_outer_wall_and_stay_inside(name):
    v, f, profile, _, rep = sliced(name)
    solid = placed(v, f, profile.build_volume)
    layers = rep.layers(rep.part)  # support and brim stand outside the part by design
    zs = sorted(layers)
    worst_cover, worst_out = 1.0, 0.0
    total_out = total_area = 0.0
    for z, h in zip(zs, layer_heights(zs), strict=True):
        section = solid.slice(z - h / 2)
        beads = bead_footprint(rep, layers[z], h, profile.filament_diameter)
        band = section - section.offset(-profile.line_width / 2, JoinType.Miter)
        if band.area() > 1e-6:
            cover = (band ^ beads).area() / band.area()
            worst_cover = min(worst_cover, cover)
        grown = section.offset(profile.nozzle_diameter / 2, JoinType.Round)
        out = (beads - grown).area()
        total_out += out
        total_area += beads.area()
        worst_out = max(worst_out, out / beads.area())
    assert worst_cover >= 0.95, f"outer wall band only {worst_cover:.3f} covered"
    assert worst_out <= 0.02, f"{worst_out:.3%} of a layer's beads outside the part"
    assert total_out / total_area <= 0.02


def test_eps_sheet_is_printed_on_every_layer():
    v, f, profile, _, rep = sliced("eps_sheet")
    layers = rep.layers(rep.part)
    area = math.pi * (profile.filament_diameter / 2) ** 2
    zs = sorted(layers)
    for z, h in zip(zs, layer_heights(zs), strict=True):
        idx = layers[z]
        deposited = rep.de[idx].sum() * area
        # a 0.4 × 20 mm sheet: 8 mm² of cross-section per layer
        assert deposited / h == pytest.approx(0.4 * 20.0, rel=0.15), f"layer z={z}"
    assert len(zs) == expected_layers(10.0, profile.first_layer_height, profile.layer_height)


def test_eps_sheet_is_one_bead_along_its_middle():
    _, _, profile, _, rep = sliced("eps_sheet")
    layers = rep.layers(rep.part)
    area = math.pi * (profile.filament_diameter / 2) ** 2
    mid_x = profile.build_volume[0] / 2
    for z in sorted(layers)[1:]:
        idx = layers[z]
        assert np.allclose(rep.start[idx, 0], mid_x, atol=0.01)
        assert np.allclose(rep.end[idx, 0], mid_x, atol=0.01)
        length = np.hypot(*(rep.end[idx, :2] - rep.start[idx, :2]).T).sum()
        assert length == pytest.approx(20.0, abs=0.5)  # one pass, not a loop
        width = rep.de[idx].sum() * area / (length * profile.layer_height) \
            + profile.layer_height * (1 - math.pi / 4)
        assert width == pytest.approx(0.4 + profile.layer_height * (1 - math.pi / 4), rel=0.03)
