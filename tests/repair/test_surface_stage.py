"""The surface stage end to end: ``preflight repair --surface``, the repair report, the
configuration key the daemon passes to its repair child."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plate_model as plate  # noqa: E402

from daemon.config import parse_config  # noqa: E402
from repair.check import check_printable  # noqa: E402
from repair.io import load_mesh, write_stl  # noqa: E402
from repair.pipeline import RepairError, repair_mesh  # noqa: E402
from repair.surface.stage import feature_lines  # noqa: E402


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon", *args], capture_output=True,
                          text=True, timeout=600)


@pytest.fixture(scope="module")
def plate_stl(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("surface") / "plate12.stl"
    write_stl(path, *plate.plate(12))
    return path


def test_cli_repair_refines_the_holes_by_default(plate_stl, tmp_path):
    out, report = tmp_path / "out.stl", tmp_path / "r.json"
    done = cli("repair", str(plate_stl), "-o", str(out), "--report", str(report))
    assert done.returncode == 0, done.stderr
    assert "4 curved feature(s) refined" in done.stdout
    section = json.loads(report.read_text())["surface"]
    assert section["mode"] == "holes" and section["tolerance_mm"] == 0.01
    assert [f["status"] for f in section["features"]] == ["refined"] * 4
    assert all(f["chordal_error_after"]["max"] <= 0.01 < f["chordal_error_before"]["max"]
               for f in section["features"])
    lines = feature_lines(section)  # the job's text report
    assert len(lines) == 4 and all("cylinder r " in ln and "(refined)" in ln for ln in lines)
    assert any(ln.startswith("  cylinder r 3 mm: chordal error max 0.102 -> ") for ln in lines)
    mesh = load_mesh(out)
    assert len(mesh.faces) == 216 + section["triangles_added"]
    assert check_printable(mesh.vertices, mesh.faces).ok


def test_cli_surface_off_keeps_the_mesh(plate_stl, tmp_path):
    out = tmp_path / "out.stl"
    done = cli("repair", str(plate_stl), "-o", str(out), "--surface", "off")
    assert done.returncode == 0, done.stderr
    assert "kept unchanged" in done.stdout
    assert len(load_mesh(out).faces) == 216


def test_cli_refuses_an_unknown_surface_mode(plate_stl, tmp_path):
    done = cli("repair", str(plate_stl), "-o", str(tmp_path / "o.stl"), "--surface", "most")
    assert done.returncode != 0 and "--surface" in done.stderr


def test_repair_mesh_reports_the_surface_stage_and_its_time():
    v, f = plate.plate(24)
    result = repair_mesh(v, f, 0.4, surface="holes")
    assert "surface" in result.report["stages"]
    assert result.report["after"]["triangles"] == len(result.faces) > len(f)
    assert np.array_equal(result.vertices, result.vertices.astype(np.float32))
    with pytest.raises(RepairError, match="surface must be one of"):
        repair_mesh(v, f, 0.4, surface="most")


def test_config_key_defaults_to_holes_and_is_checked():
    assert parse_config({}).repair.surface == "holes"
    assert parse_config({"repair": {"surface": "all"}}).repair.surface == "all"
    with pytest.raises(ValueError, match="surface"):
        parse_config({"repair": {"surface": "most"}})


def test_daemon_repair_task_applies_the_configured_surface_mode(plate_stl, tmp_path, capsys):
    """The daemon's repair child runs ``_task_repair`` with the spec its pipeline builds
    from ``[repair] surface``; the refined STL is what it then slices."""
    from daemon.worker import _task_repair

    out = tmp_path / "repaired.stl"
    spec = {"in": str(plate_stl), "out": str(out), "epsilon": 0.4, "surface": "holes"}
    report = _task_repair(spec)
    assert [f["status"] for f in report["surface"]["features"]] == ["refined"] * 4
    assert len(load_mesh(out).faces) == report["after"]["triangles"] > 216
    assert '"stage": "surface"' in capsys.readouterr().out  # its progress line
    report = _task_repair({**spec, "surface": "off"})
    assert "surface" not in report and len(load_mesh(out).faces) == 216
