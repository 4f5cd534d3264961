"""The report pictures' server side: the layer preview's G-code reader (on G-code from
the embedded slicer and on the modal states a slicer's G-code uses: relative moves and
extrusion, G92, ;TYPE:), and the size limits of the previews."""

from __future__ import annotations

import pytest
from daemon_helpers import DATA

from daemon.web.toolpath import read_layers


def test_sliced_model_layers_match_the_slicer(tmp_path):
    from repair.files import repair_file
    from slicer.engine import slice_file
    from slicer.profile import Profile

    repaired = tmp_path / "cube.stl"
    repair_file(DATA / "open_cube_stuck_to_side.stl", repaired, epsilon=0.4)
    gcode = tmp_path / "cube.gcode"
    summary = slice_file(repaired, gcode, Profile.for_printer(0.4))
    with open(gcode, encoding="utf-8") as f:
        layers = read_layers(f)
    assert len(layers.z) == summary["layers"]
    assert layers.z == sorted(layers.z) and layers.z[0] > 0
    for paths in layers.paths:
        assert paths
        for _, pts in paths:
            assert len(pts) >= 4 and len(pts) % 2 == 0
    # the drawn moves cover the model's plan (a skirt may go around it)
    from repair.io import load_mesh

    v = load_mesh(repaired).vertices
    size = v.max(axis=0) - v.min(axis=0)
    x0, y0, x1, y1 = layers.bounds
    assert size[0] - 1 <= x1 - x0 <= size[0] + 25
    assert size[1] - 1 <= y1 - y0 <= size[1] + 25


def test_modal_states_and_types():
    gcode = """; a hand-written file
G21
G90
M82
G92 E0
G1 Z0.2 F600
;TYPE:Perimeter
G1 X10 Y10 F3000        ; travel: no E
G1 X20 Y10 E1.0          ; extrude
G1 X20 Y20 E2.0
G1 E1.2                  ; retract
G1 X30 Y30               ; travel
G1 E2.0                  ; unretract
;TYPE:Solid infill
G1 X40 Y30 E3.0
G92 E0                   ; reset: the next E1 extrudes
G1 X40 Y40 E1
G91
G1 Z0.2
M83
G1 X-10 E0.5             ; relative: to X30 Y40 at z 0.4
G90
G1 X50 Y50 Z5 F9000      ; travel up
"""
    layers = read_layers(gcode.splitlines())
    assert layers.types == ["extrusion", "Perimeter", "Solid infill"]
    assert [round(z, 3) for z in layers.z] == [0.2, 0.4]
    first, second = layers.paths
    assert [(t, list(p)) for t, p in first] == [
        (1, [10.0, 10.0, 20.0, 10.0, 20.0, 20.0]),
        (2, [30.0, 30.0, 40.0, 30.0, 40.0, 40.0]),
    ]
    assert [(t, list(p)) for t, p in second] == [(2, [40.0, 40.0, 30.0, 40.0])]
    assert layers.bounds == [10.0, 10.0, 40.0, 40.0]


def test_no_extrusion_no_layers():
    layers = read_layers(["G28", "G1 X10 Y10 F3000", "M104 S0", "garbage line", ""])
    assert layers.z == [] and layers.paths == []


def test_previews_refuse_what_is_too_big_to_draw(tmp_path):
    """A mesh over the triangle limit gets a 413 with the reason, not a daemon that
    loads it into memory."""
    import tomli_w
    from daemon_helpers import box, write_binary_stl

    from daemon.config import load_config
    from daemon.journal import Journal
    from daemon.web.previews import mesh_bytes
    from daemon.web.uploads import Refused

    cfg_path = tmp_path / "preflight.toml"
    cfg_path.write_text(tomli_w.dumps({"spool": {"path": str(tmp_path / "spool")},
                                       "daemon": {"state_dir": str(tmp_path / "state")},
                                       "limits": {"max_triangles": 10}}))
    cfg = load_config(cfg_path)
    stl = tmp_path / "box.stl"
    write_binary_stl(stl, *box())  # 12 triangles
    journal = Journal(tmp_path / "journal.db")
    job_id = journal.add_job(name="box.stl", source_name="box.stl", kind="mesh",
                             work_dir=str(tmp_path), input_path=str(stl))
    with pytest.raises(Refused) as refused:
        mesh_bytes(cfg, journal.get(job_id), "input")
    assert refused.value.status == 413 and "triangles" in refused.value.reason
    with pytest.raises(Refused) as refused:
        mesh_bytes(cfg, journal.get(job_id), "repaired")
    assert refused.value.status == 404


def test_the_idle_daemon_does_not_load_numpy_for_the_page():
    """numpy, the mesh readers and libigl load with the first 3D view, not with the web
    server: the daemon idles small on a Pi."""
    import subprocess
    import sys

    code = ("import sys, daemon.service, daemon.web.server, daemon.web.page; "
            "print('numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
