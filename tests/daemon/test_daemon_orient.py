"""The daemon's slicing default: a model is turned only when that avoids support entirely
(orient = if-needed), [profile] orient overrides it, and the text report says so."""

from __future__ import annotations

import trimesh
from manifold3d import Manifold

from daemon.config import parse_config
from daemon.journal import Job
from daemon.pipeline import slice_overrides
from daemon.report import report_text
from daemon.states import JobState
from daemon.worker import _task_slice


def _upside_down_cup(path):
    cup = (Manifold.cylinder(12, 10, 10, 48)
           - Manifold.cylinder(12, 8, 8, 48).translate([0, 0, 2])).to_mesh()
    mesh = trimesh.Trimesh(cup.vert_properties[:, :3] * [1, -1, -1], cup.tri_verts)
    mesh.export(path)
    return path


def _slice(tmp_path, profile: dict) -> dict:
    spec = {"in": str(_upside_down_cup(tmp_path / "cup.stl")), "out": str(tmp_path / "c.gcode"),
            "nozzle": 0.4, "overrides": slice_overrides(parse_config({"profile": profile}))}
    return _task_slice(spec)["summary"]


def test_the_daemon_turns_an_upside_down_cup_and_reports_it(tmp_path):
    summary = _slice(tmp_path, {})
    turned = summary["orientation"]
    assert turned["mode"] == "if-needed" and turned["rotated"]
    assert turned["cost"]["support_mm2"] < 1.0 < turned["cost_as_saved"]["support_mm2"]
    job = Job(1, "cup.stl", "cup.stl", "mesh", JobState.DONE, 0.0, 0.0, None, None, None, None,
              0.4, "nozzle", None, None, summary, None, None, 1, True, None, None)
    text = report_text(job, [])
    assert "turned 180° about" in text and "support" in text


def test_profile_orient_keep_leaves_it_as_saved(tmp_path):
    summary = _slice(tmp_path, {"orient": "keep", "thumbnails": ""})
    assert summary["orientation"] == {"mode": "keep", "rotated": False}
