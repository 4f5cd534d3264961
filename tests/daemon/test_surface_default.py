"""Which surface refinement a user gets from each entry point (issue 18): the CLI and
the daemon's repair child, given no choice, take ``[repair] surface``'s default from
the config schema -- one place; the library (:func:`repair.files.repair_file`,
:func:`repair.pipeline.repair_mesh`) defaults to "off", so a caller gets the exact
repair unless it asks (documented on repair_file). On the design plate of issue 19,
whose holes and boss "holes" refines."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.config import RepairConfig
from daemon.worker import run_task
from repair.files import repair_file
from repair.io import write_stl

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "repair"))
import plate_model  # noqa: E402

#: What a user gets unless configured otherwise.
USER_DEFAULT = RepairConfig().surface


@pytest.fixture(scope="module")
def plate_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plate") / "plate.stl"
    write_stl(path, *plate_model.plate(12))
    return path


def _refined(report: dict) -> str:
    """The refinement mode a repair report says ran ("off" when it has no section); a
    mode that ran refined the plate's circles."""
    section = report.get("surface")
    if section is None:
        return "off"
    assert section["triangles_added"] > 0
    return section["mode"]


def test_the_cli_takes_the_config_default(tmp_path, plate_file) -> None:
    report = tmp_path / "r.json"
    done = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(plate_file), "-o",
         str(tmp_path / "o.stl"), "--report", str(report)],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert _refined(json.loads(report.read_text())) == USER_DEFAULT


def test_the_daemon_child_takes_the_config_default(tmp_path, plate_file) -> None:
    # A spec without the setting (the daemon sends [repair] surface; the child's own
    # default is the same, not the library's).
    spec = {"in": str(plate_file), "out": str(tmp_path / "out.stl"), "epsilon": 0.4}
    report = run_task("repair", spec, work_dir=tmp_path / "w", timeout=600, memory_mb=2048)
    assert _refined(report) == USER_DEFAULT


def test_the_library_default_is_the_exact_repair(tmp_path, plate_file) -> None:
    report = repair_file(plate_file, tmp_path / "o.stl")
    assert _refined(report) == "off"
    assert report["after"]["triangles"] == report["before"]["triangles"]
