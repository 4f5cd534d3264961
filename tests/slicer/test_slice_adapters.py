"""External slicer adapters: same profile mapped onto CuraEngine / PrusaSlicer.

The runs skip when the tool is not installed; the argument mapping is checked always.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import trimesh
from gcode_replay import replay
from slice_checks import expected_layers

from slicer import adapters
from slicer.engine import SliceError
from slicer.profile import Profile

HAVE = adapters.available()
PROFILE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180)).with_overrides(
    {"skirts": 0, "infill_percent": 100})


def test_cura_command_passes_derived_values_and_extruder_settings_after_e0():
    p = Profile.for_printer().with_overrides({"infill_percent": 25, "infill_pattern": "grid"})
    cmd = adapters.cura_command(p, Path("in.stl"), Path("out.gcode"), "CuraEngine",
                                Path("/defs"))
    e0 = cmd.index("-e0")
    settings_after = [cmd[i + 1] for i in range(e0, len(cmd) - 1) if cmd[i] == "-s"]
    settings_before = [cmd[i + 1] for i in range(e0) if cmd[i] == "-s"]
    assert "material_diameter=1.75" in settings_after
    assert "center_object=true" in settings_before
    # no formulas in CuraEngine: the infill line distance is given, grid = 2 lines per cell
    assert f"infill_line_distance={2 * 0.45 * 100 / 25:.6g}" in settings_after
    assert cmd.index("-l") > e0


def test_prusa_arguments_carry_the_bed_and_centre():
    args = adapters.prusa_args(Profile.for_printer(build_volume=(180, 160, 150)))
    assert args[args.index("--bed-shape") + 1] == "0x0,180x0,180x160,0x160"
    assert args[args.index("--center") + 1] == "90,80"
    assert "--use-relative-e-distances" in args


@pytest.mark.parametrize("tool", ["prusa", "cura"])
def test_external_slicer_output_replays_correctly(tool, tmp_path):
    if not HAVE[tool]:
        pytest.skip(f"{adapters.BINARIES[tool]} not installed")
    stl = tmp_path / "cube.stl"
    trimesh.creation.box((20, 20, 10)).export(stl)
    out = tmp_path / "cube.gcode"
    summary = adapters.slice_external(tool, stl, out, PROFILE)
    rep = replay(out.read_text())
    ext = rep.extruding
    assert ext.any()
    centre = (rep.end[ext, :2].min(0) + rep.end[ext, :2].max(0)) / 2
    assert abs(centre[0] - 100) < 1 and abs(centre[1] - 100) < 1
    assert len(rep.layers()) == expected_layers(10.0, 0.2, 0.2)
    area = math.pi * (PROFILE.filament_diameter / 2) ** 2
    assert 0.93 <= rep.de.sum() * area / 4000.0 <= 1.08
    assert summary["slicer"] == tool and summary["filament_mm"] > 0


@pytest.mark.parametrize("tool", ["prusa", "cura"])
def test_external_slicer_errors_are_surfaced(tool, tmp_path):
    if not HAVE[tool]:
        pytest.skip(f"{adapters.BINARIES[tool]} not installed")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"solid nothing\nthis is not an stl\n")
    with pytest.raises(SliceError) as info:
        adapters.slice_external(tool, bad, tmp_path / "x.gcode", PROFILE)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "x.gcode").exists()


def test_slice_with_dispatches_and_rejects_unknown(tmp_path):
    stl = tmp_path / "c.stl"
    trimesh.creation.box((10, 10, 4)).export(stl)
    summary = adapters.slice_with("embedded", stl, tmp_path / "c.gcode", PROFILE)
    assert summary["slicer"] == "embedded" and summary["layers"] == 20
    with pytest.raises(SliceError, match="simplify3d"):
        adapters.slice_with("simplify3d", stl, tmp_path / "d.gcode", PROFILE)
