"""The exact repair's time budget reaches the daemon's repair child (``[repair]
time_budget``, capped by ``[limits] repair_timeout``), and the fallback's result comes
back as the job's report, on a real file in a real forked child."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from daemon.config import Config
from daemon.pipeline import repair_budget
from daemon.worker import run_task
from repair.check import check_printable
from repair.io import load_mesh, write_stl

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "repair"))
from broken_models import triangle_soup  # noqa: E402


def test_budget_leaves_half_the_repair_timeout_to_the_fallback():
    cfg = Config()
    assert repair_budget(cfg) == cfg.repair.time_budget  # 120 s of a 600 s timeout
    short = replace(cfg, limits=replace(cfg.limits, repair_timeout=60.0))
    assert repair_budget(short) == 30.0
    off = replace(cfg, repair=replace(cfg.repair, time_budget=0.0))
    assert repair_budget(off) is None


def test_daemon_repair_child_falls_back_past_its_budget(tmp_path):
    v, f = triangle_soup(8, seed=2)
    src = tmp_path / "soup.stl"
    write_stl(src, v, f)
    spec = {"in": str(src), "out": str(tmp_path / "out.stl"), "epsilon": 0.4,
            "report": str(tmp_path / "r.json"), "time_budget": 1e-6}  # fmt: skip
    report = run_task("repair", spec, work_dir=tmp_path / "w", timeout=600, memory_mb=2048)
    assert report["path"] == "fallback"
    assert report["summary"].startswith("fallback: exact repair exceeded 1e-06 s")
    written = load_mesh(tmp_path / "out.stl")
    assert check_printable(written.vertices, written.faces, as_float32=True).ok
