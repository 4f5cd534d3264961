"""Runs of equal layers (prismatic parts, a support column down a stem) are worked out once:
the G-code is the same, byte for byte, as when every layer is written afresh, and the
support under a repeated section is the same shape on every layer."""

from __future__ import annotations

import numpy as np
import pytest
from slice_checks import placed
from support_checks import arch, comb, mushroom, ramp, t_bracket

from slicer import layers
from slicer.engine import slice_mesh
from slicer.geometry import layer_tops, shape_ids, shape_key
from slicer.overhang import overhangs
from slicer.profile import Profile
from slicer.support import support_regions

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180))


def _written(monkeypatch, model, afresh: bool, **over) -> tuple[str, int]:
    """The G-code and how many layers were written (not repeated)."""
    count = [0]
    write = layers.LayerRun._write

    def counted(run, i):
        count[0] += 1
        return write(run, i)

    with monkeypatch.context() as patch:
        patch.setattr(layers.LayerRun, "_write", counted)
        if afresh:
            patch.setattr(layers, "layer_keys", lambda model, profile: [None] * len(model.tops))
        v, f = model()
        gcode = slice_mesh(v, f, BASE.with_overrides({"workers": "1", **over})).gcode
    return gcode, count[0]


@pytest.mark.parametrize("name, model, over, repeats", [
    ("mushroom", mushroom, {"support": "auto"}, True),
    ("mushroom, solid, support everywhere", mushroom,
     {"support": "everywhere", "infill_percent": 100}, True),
    ("mushroom, z lift, absolute E", mushroom,
     {"support": "auto", "retract_lift": 0.4, "relative_e": False}, False),
    ("t_bracket rectilinear", t_bracket,
     {"support": "auto", "infill_pattern": "rectilinear", "support_interface_layers": 0},
     True),
])
def test_repeated_layers_are_the_gcode_written_afresh(monkeypatch, name, model, over,
                                                      repeats):
    """Relative E and no Z lift: the stem's layers repeat. A Z lift names the layer's
    height in its text and absolute E the running E count: no layer repeats."""
    fresh, n_fresh = _written(monkeypatch, model, True, **over)
    repeated, n_written = _written(monkeypatch, model, False, **over)
    assert repeated == fresh
    layer_count = fresh.count(";LAYER:")
    assert n_fresh == layer_count
    if repeats:
        assert n_written < layer_count / 2, f"{n_written} of {layer_count} layers written"
    else:
        assert n_written == layer_count


def test_aligned_seams_write_every_layer(monkeypatch):
    """Each aligned seam follows the one below: no layer is a repeat of another."""
    gcode, written = _written(monkeypatch, mushroom, False, seam_position="aligned")
    assert written == gcode.count(";LAYER:")


def _sections(model):
    solid = placed(*model(), BASE.build_volume)
    lo, hi = solid.bounding_box()[2], solid.bounding_box()[5]
    tops = layer_tops(hi - lo, BASE.first_layer_height, BASE.layer_height)
    heights = np.diff(tops, prepend=0.0)
    sections = [solid.slice(float(z)).simplify(BASE.resolution) for z in tops - heights / 2]
    widths = [BASE.first_layer_line_width] + [BASE.line_width] * (len(tops) - 1)
    return sections, heights, widths


def test_the_column_down_a_stem_is_one_shape_and_the_same_support():
    sections, heights, widths = _sections(mushroom)
    ids = shape_ids(sections)
    with_ids = support_regions(sections, heights, BASE, widths, ids=ids)
    without = support_regions(sections, heights, BASE, widths)
    stem = [i for i in range(2, len(sections) - 1) if ids[i] == ids[1] and ids[i - 1] == ids[1]]
    assert len(stem) > 20
    bases = {shape_key(with_ids[i].base) for i in stem if not with_ids[i].base.is_empty()}
    assert len(bases) <= 2, "the column under a repeated section changes from layer to layer"
    for a, b in zip(with_ids, without, strict=True):  # the same support, up to rounding
        assert abs(a.base.area() - b.base.area()) < 1e-6
        assert abs(a.interface.area() - b.interface.area()) < 1e-6
        assert (a.base ^ b.base).area() == pytest.approx(a.base.area(), abs=1e-6)


@pytest.mark.parametrize("model", [mushroom, t_bracket, arch, comb, lambda: ramp(75.0)])
def test_overhangs_of_repeated_layers_are_those_found_afresh(model):
    sections, heights, _ = _sections(model)
    s = 0.45
    found = overhangs(sections, heights, 55.0, s, 1.0, shape_ids(sections))
    fresh = overhangs(sections, heights, 55.0, s, 1.0)
    assert [shape_key(a) for a in found] == [shape_key(b) for b in fresh]


def test_a_workers_overhead_moves_layers_to_the_parent():
    work = np.full(100, 10.0)
    assert layers.layer_shares(work, 2) == [(0, 50), (50, 100)]
    (a, b), (c, d) = layers.layer_shares(work, 2, overhead=200.0)
    assert b - a == 60 and d - c == 40  # 600 = 400 + 200 of the worker's own
    shares = layers.layer_shares(work, 3, overhead=100.0)
    assert [e - s for s, e in shares] == [40, 30, 30]


@pytest.mark.parametrize("model", [mushroom, t_bracket, lambda: ramp(60.0)])
def test_skins_of_repeated_layers_are_those_found_afresh(model):
    from slicer.geometry import bead_spacing
    from slicer.planner import plan_shells, skin_regions

    sections, heights, widths = _sections(model)
    ids = shape_ids(sections)
    planned: dict = {}  # equal layers share their infill region, as layer_plans plans them
    inner = []
    for i, section in enumerate(sections):
        key = (ids[i], widths[i], float(heights[i]))
        if key not in planned:
            planned[key] = plan_shells(section, widths[i], float(heights[i]), BASE.perimeters,
                                       BASE.thin_walls, BASE.resolution).inner
        inner.append(planned[key])
    spacing = [bead_spacing(w, float(h)) for w, h in zip(widths, heights, strict=True)]
    found = skin_regions(inner, sections, 4, 3, spacing, False, ids)
    fresh = skin_regions(inner, sections, 4, 3, spacing, False)
    assert [shape_key(a) for a in found] == [shape_key(b) for b in fresh]
    assert any(not a.is_empty() for a in found)
