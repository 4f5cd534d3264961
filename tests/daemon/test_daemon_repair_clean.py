"""The scan cleanup choice reaches the repair: from `preflight repair --clean` and from
the daemon's repair child (``[repair] clean``), on a real noisy scan file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.worker import run_task
from repair.io import write_stl

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "repair"))
from scan_models import noisy_scan  # noqa: E402


@pytest.fixture(scope="module")
def scan_file(tmp_path_factory) -> Path:
    # Below the auto-detection's size: only an explicit "scan" cleans it.
    v, f = noisy_scan(4, 20.0, seed=5)
    path = tmp_path_factory.mktemp("scan") / "scan.stl"
    write_stl(path, v, f)
    return path


@pytest.mark.parametrize("clean", ["scan", "auto"])
def test_cli_clean_option(tmp_path, scan_file, clean):
    report = tmp_path / "r.json"
    done = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(scan_file), "-o", str(tmp_path / "o.stl"),
         "--clean", clean, "--report", str(report)],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    r = json.loads(report.read_text())
    if clean == "scan":
        assert r["scan_cleanup"]["why"].startswith("asked")
    else:
        assert "scan_cleanup" not in r


def test_cli_refuses_an_unknown_clean_mode(tmp_path, scan_file):
    done = subprocess.run(
        [sys.executable, "-m", "daemon", "repair", str(scan_file), "-o", str(tmp_path / "o.stl"),
         "--clean", "deep"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert done.returncode != 0 and "--clean" in done.stderr


def test_daemon_repair_child_gets_the_clean_setting(tmp_path, scan_file):
    spec = {"in": str(scan_file), "out": str(tmp_path / "out.stl"), "epsilon": 0.4,
            "report": str(tmp_path / "r.json"), "clean": "scan"}  # fmt: skip
    report = run_task("repair", spec, work_dir=tmp_path / "w", timeout=600, memory_mb=2048)
    assert report["scan_cleanup"]["why"].startswith("asked")
    from repair.check import check_printable
    from repair.io import load_mesh

    written = load_mesh(tmp_path / "out.stl")
    assert report["printable"]["ok"] and check_printable(written.vertices, written.faces).ok
