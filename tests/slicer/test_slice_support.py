"""Supports, bridges, brim and feature labels, checked on the replayed G-code of real solids.

The earlier geometric checks (volume, wall coverage, material outside, heating, Z) run on the
overhanging models too: they are in test_slice_models.MODELS.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from gcode_replay import NOT_PART, SUPPORT, replay
from manifold3d import CrossSection, JoinType, Manifold
from slice_checks import bridge_part, cube, mesh_of, placed
from support_checks import (
    BUNNY,
    arch,
    comb,
    floating_support_share,
    inside,
    mushroom,
    ramp,
    rotated_bunny,
    support_clearance,
    t_bracket,
    unsupported_share,
)

from slicer.engine import slice_mesh
from slicer.geometry import bead_spacing, contours, layer_tops
from slicer.profile import Profile
from slicer.support import support_paths, support_regions

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180))
LABELS = {"External perimeter", "Perimeter", "Internal infill", "Solid infill",
          "Top solid infill", "Bridge infill", "Support material",
          "Support material interface", "Skirt/Brim"}
_cache: dict = {}


def _slice(name, model, **over):
    key = (name, repr(sorted(over.items())))
    if key not in _cache:
        v, f = model()
        profile = BASE.with_overrides(over)
        result = slice_mesh(v, f, profile)
        _cache[key] = (placed(v, f, profile.build_volume), profile, result,
                       replay(result.gcode))
    return _cache[key]


OVERHANGS = {"mushroom": mushroom, "t_bracket": t_bracket, "arch": arch,
             "ramp_45": lambda: ramp(45.0), "ramp_60": lambda: ramp(60.0),
             "ramp_75": lambda: ramp(75.0), "comb": comb}
NEED_SUPPORT = ("mushroom", "t_bracket", "ramp_75")


@pytest.mark.parametrize("name", list(OVERHANGS))
def test_auto_support_holds_up_the_part_without_fusing_to_it(name):
    solid, profile, result, rep = _slice(name, OVERHANGS[name], support="auto")
    share, per_layer = unsupported_share(rep, solid, profile.line_width)
    worst = max(per_layer, key=per_layer.get)
    assert share <= 0.01, f"{share:.2%} unsupported, worst layer z={worst}"
    if result.summary["support_cm3"] > 0:
        gap = support_clearance(rep, profile.filament_diameter)
        assert gap >= profile.support_xy_gap - 0.03, f"support {gap:.3f} mm from the part"


@pytest.mark.parametrize("name", (*NEED_SUPPORT, "comb"))
def test_support_columns_stand_on_what_is_below_them(name):
    """Base lines (no outline loop but on the first layer) stack on the base lines below and
    the interface crosses them: no support bead hangs over nothing."""
    _, profile, _, rep = _slice(name, OVERHANGS[name], support="auto")
    reach = profile.support_spacing / 2 + profile.line_width
    assert floating_support_share(rep, reach) <= 0.005


@pytest.mark.parametrize("name", (*NEED_SUPPORT, "comb"))
def test_every_support_island_wide_enough_for_a_bead_gets_one(name):
    """Base support is lines without an outline: an island narrower than the line spacing,
    which no line crosses, still gets its loop, so no column is left out."""
    profile = BASE
    solid = placed(*OVERHANGS[name](), profile.build_volume)
    lo, hi = solid.bounding_box()[2], solid.bounding_box()[5]
    tops = layer_tops(hi - lo, profile.first_layer_height, profile.layer_height)
    heights = np.diff(tops, prepend=0.0)
    sections = [solid.slice(float(z)).simplify(profile.resolution) for z in tops - heights / 2]
    widths = [profile.first_layer_line_width] + [profile.line_width] * (len(tops) - 1)
    layers = support_regions(sections, heights, profile, widths)
    assert layers is not None
    islands = 0
    for i, layer in enumerate(layers):
        s = bead_spacing(widths[i], float(heights[i]))
        pts = [p.points for p in support_paths(layer, profile, widths[i], float(heights[i]))]
        for island in layer.area().offset(-s / 2, JoinType.Miter).decompose():
            if island.is_empty():
                continue
            islands += 1
            assert pts and inside(contours(island.offset(s / 4, JoinType.Miter)),
                                  np.concatenate(pts)).any(), f"an island on layer {i} is bare"
    assert islands > 0


@pytest.mark.parametrize("name", NEED_SUPPORT)
def test_without_support_the_same_parts_print_into_the_air(name):
    solid, profile, result, rep = _slice(name, OVERHANGS[name], support="off")
    share, _ = unsupported_share(rep, solid, profile.line_width)
    assert share > 0.02, f"only {share:.2%} unsupported with support off"
    assert not rep.labelled(*SUPPORT).any() and result.summary["support"] == "off"


def test_a_45_degree_ramp_needs_no_support():
    _, _, result, rep = _slice("ramp_45", OVERHANGS["ramp_45"], support="auto")
    assert not (rep.extruding & rep.labelled(*SUPPORT)).any()
    assert result.summary["support"] == "none needed" and result.summary["support_cm3"] == 0


def test_support_is_reported_and_printed_at_its_own_speed_and_flow():
    _, profile, result, rep = _slice("mushroom", mushroom, support_speed=40,
                                     support_interface_speed=20, support_flow=0.9)
    s = result.summary
    assert s["support_cm3"] > 0 and 0 < s["support_seconds"] < s["estimated_seconds"]
    area = math.pi * (profile.filament_diameter / 2) ** 2
    base = rep.extruding & rep.labelled("Support material")
    iface = rep.extruding & rep.labelled("Support material interface")
    assert base.any() and iface.any()
    assert rep.de[base | iface].sum() * area / 1000 == pytest.approx(s["support_cm3"], abs=2e-3)
    above_first = rep.end[:, 2] > profile.first_layer_height + 1e-6
    assert set(rep.feed[base & above_first]) <= {40 * 60.0}  # min layer time may slow it
    assert set(rep.feed[iface & above_first]) <= {20 * 60.0}
    # E per mm of a support line = 0.9 × that of a part line of the same width
    length = np.hypot(*(rep.end[:, :2] - rep.start[:, :2]).T)
    per_mm = rep.de / np.maximum(length, 1e-12)
    part_lines = rep.part & rep.labelled("Internal infill") & above_first
    ratio = np.median(per_mm[base & above_first]) / np.median(per_mm[part_lines])
    assert ratio == pytest.approx(0.9, rel=0.01)
    # interface: dense, under the cap; base: sparse lines
    z_top = max(rep.end[iface, 2])
    assert z_top == pytest.approx(15.0 - profile.layer_height, abs=1e-6)  # one-layer Z gap


def test_bridges_get_no_support_and_overhangs_do():
    solid, profile, result, rep = _slice("bridge", bridge_part, support="auto")
    x0 = profile.build_volume[0] / 2 - 14.5
    sup = rep.extruding & rep.labelled(*SUPPORT)
    mid_x = (rep.start[sup, 0] + rep.end[sup, 0]) / 2
    assert sup.any(), "the 5 mm ledge got no support"
    assert (mid_x > x0 + 24.0).all(), "support under the 16 mm bridge between the pillars"
    assert rep.labelled("Bridge infill").any()


def _block_under_a_shelf():
    """A 10 mm block, and beside it a post carrying a shelf that overhangs the block."""
    block = Manifold.cube([12, 20, 6])
    post = Manifold.cube([6, 20, 16]).translate([20, 0, 0])
    shelf = Manifold.cube([24, 20, 3]).translate([2, 0, 16])
    return mesh_of(block + post + shelf)


@pytest.mark.parametrize("mode", ["buildplate", "auto"])
def test_buildplate_support_never_stands_on_the_part(mode):
    solid, profile, _, rep = _slice("shelf", _block_under_a_shelf, support=mode)
    sup = rep.extruding & rep.labelled(*SUPPORT)
    pts = (rep.start[sup, :2] + rep.end[sup, :2]) / 2
    footprint = CrossSection.square([12, 20]).translate(
        [profile.build_volume[0] / 2 - 13, profile.build_volume[1] / 2 - 10])
    over_block = inside([np.asarray(p, float) for p in footprint.to_polygons()], pts)
    assert sup.any()
    if mode == "buildplate":
        assert not over_block.any()
    else:  # auto supports the shelf above the block too, standing on the block
        assert over_block.any()
        share, _ = unsupported_share(rep, solid, profile.line_width)
        assert share <= 0.01


def test_every_extrusion_carries_a_prusaslicer_feature_label():
    for name, model, over in (("cube", cube, {}), ("bridge", bridge_part, {}),
                              ("mushroom", mushroom, {"skirts": 1})):
        _, _, _, rep = _slice(name, model, **over)
        ext = rep.extruding
        names = {rep.labels[k] for k in np.unique(rep.feature[ext])}
        assert names <= LABELS, names - LABELS
        assert "" not in names
        if name == "cube":
            assert {"External perimeter", "Perimeter", "Internal infill", "Solid infill",
                    "Top solid infill", "Skirt/Brim"} <= names
        if name == "bridge":
            assert "Bridge infill" in names
        if name == "mushroom":
            assert {"Support material", "Support material interface"} <= names
    # the top solid layer of the cube is labelled as such, the bottom one is not
    _, profile, _, rep = _slice("cube", cube)
    layers = rep.layers()
    zs = sorted(layers)
    assert rep.labelled("Top solid infill")[layers[zs[-1]]].any()
    assert not rep.labelled("Top solid infill")[layers[zs[0]]].any()


def _first_layer_reach(rep, profile) -> float:
    """How far (mm) the first layer's extrusions reach outside the part's centred footprint
    along x, skirt excluded (the skirt is the outermost loop)."""
    zs = sorted(rep.layers())
    first = rep.layers()[zs[0]]
    return float(np.abs(rep.end[first, 0] - profile.build_volume[0] / 2).max())


def test_a_tall_pin_gets_a_brim_and_a_cube_does_not():
    pin = _slice("pin", lambda: mesh_of(Manifold.cube([5, 5, 80])), skirts=0)
    _, profile, result, rep = pin
    assert result.summary["brim"] is True
    # brim loops reach brim_width beyond the 5 mm pin's sides, labelled Skirt/Brim
    assert _first_layer_reach(rep, profile) == pytest.approx(2.5 + profile.brim_width, abs=0.5)
    brim = rep.extruding & rep.labelled("Skirt/Brim")
    assert brim.any() and (rep.end[brim, 2] == rep.end[brim, 2].min()).all()
    _, profile, result, rep = _slice("cube", cube, skirts=0)
    assert result.summary["brim"] is False
    assert _first_layer_reach(rep, profile) <= 10.0
    assert not rep.labelled(*NOT_PART).any()
    # asked for: a cube gets one too; the skirt stays, around the brim
    _, profile, result, rep = _slice("cube", cube, brim="on", brim_width=3, skirts=1,
                                     skirt_distance=2)
    assert result.summary["brim"] is True
    assert _first_layer_reach(rep, profile) == pytest.approx(10 + 3 + 2 + 0.5, abs=0.5)


@pytest.mark.slow
@pytest.mark.skipif(not BUNNY.is_file(), reason="corpus not present")
def test_rotated_bunny_chin_is_supported():
    off = _slice("bunny", rotated_bunny, support="off")
    auto = _slice("bunny", rotated_bunny, support="auto")
    share_off, _ = unsupported_share(off[3], off[0], off[1].line_width)
    share_auto, _ = unsupported_share(auto[3], auto[0], auto[1].line_width)
    assert share_auto <= 0.01 and share_auto <= 0.2 * share_off
    assert support_clearance(auto[3], auto[1].filament_diameter) >= auto[1].support_xy_gap - 0.03
    reach = auto[1].support_spacing / 2 + auto[1].line_width
    assert floating_support_share(auto[3], reach) <= 0.005


def test_the_job_report_gives_support_volume_and_time():
    from daemon.journal import Job
    from daemon.report import report_text
    from daemon.states import JobState

    _, _, result, _ = _slice("mushroom", mushroom, support="auto")
    job = Job(id=1, name="mushroom.stl", source_name="mushroom.stl", kind="mesh",
              state=JobState.DONE, created=0.0, updated=0.0, work_dir=None, input_path=None,
              repaired_path=None, gcode_path=None, epsilon=0.4, epsilon_source="printer",
              printer_info=None, repair_report=None, slice_summary=result.summary,
              print_result=None, reason=None, attempts=1, print_requested=True, progress=None,
              outputs=None)
    text = report_text(job, [])
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("support "))
    assert f"{result.summary['support_cm3']:.3g} cm3" in line
    minutes = int(result.summary["support_seconds"] // 60)
    assert f"{minutes}m" in line
