"""``preflight slice`` as a user runs it: real STL in, G-code out, one-line errors."""

from __future__ import annotations

import json
import resource
import subprocess
import sys

import trimesh
from gcode_replay import replay


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon", "slice", *args],
                          capture_output=True, text=True, timeout=300)


def test_slices_an_stl_with_flags_and_profile(tmp_path):
    stl = tmp_path / "part.stl"
    trimesh.creation.cylinder(radius=8, height=6, sections=64).export(stl)
    prof = tmp_path / "p.toml"
    prof.write_text("skirts = 0\nfan_speed = 50\n")
    out = tmp_path / "part.gcode"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = run(str(stl), "-o", str(out), "--nozzle", "0.6", "--infill", "40",
              "--bed", "150,150,100", "--profile", str(prof), "--json")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    rep = replay(out.read_text())
    # 0.6 nozzle: 0.3 mm layers → 6 mm / 0.3 = 20 layers
    assert summary["layers"] == 20 == len(rep.layers())
    ext = rep.extruding
    centre = rep.end[ext, :2].mean(axis=0)
    assert abs(centre[0] - 75) < 1 and abs(centre[1] - 75) < 1
    assert max(s for _, s in rep.fan) == round(255 * 0.5)
    # the process's own CPU, start-up included (the bench's "main cpu"): part of what the
    # process and the children it forked used, as this process's rusage counts them
    used = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    assert 0 < summary["main_cpu_seconds"] <= used + 0.001
    assert 0 <= summary["child_cpu_seconds"] <= used - summary["main_cpu_seconds"] + 0.002


def test_errors_are_one_line(tmp_path):
    stl = tmp_path / "big.stl"
    trimesh.creation.box((300, 20, 20)).export(stl)
    res = run(str(stl), "-o", str(tmp_path / "x.gcode"))
    assert res.returncode != 0
    assert res.stderr.strip().count("\n") == 0
    assert res.stderr.startswith("preflight: ") and "300.0" in res.stderr and "220" in res.stderr
    assert not (tmp_path / "x.gcode").exists()
    res = run(str(stl), "-o", str(tmp_path / "x.gcode"), "--set", "nozzle_colour=red")
    assert res.returncode != 0 and "nozzle_colour" in res.stderr
    res = run(str(tmp_path / "missing.stl"), "-o", str(tmp_path / "x.gcode"))
    assert res.returncode != 0 and res.stderr.startswith("preflight: ")


def test_a_mushroom_is_supported_by_default_and_the_summary_says_so(tmp_path):
    from support_checks import mushroom

    v, f = mushroom()
    stl = tmp_path / "mushroom.stl"
    trimesh.Trimesh(v, f).export(stl)
    out = tmp_path / "mushroom.gcode"
    res = run(str(stl), "-o", str(out))
    assert res.returncode == 0, res.stderr
    assert ", support " in res.stdout and " cm3 " in res.stdout
    rep = replay(out.read_text())
    assert rep.labelled("Support material").any()
    res = run(str(stl), "-o", str(out), "--set", "support=off", "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["support"] == "off" and summary["support_cm3"] == 0
    res = run(str(stl), "-o", str(out), "--set", "support=sometimes")
    assert res.returncode != 0 and res.stderr.count("\n") == 1
    assert "support must be one of auto, buildplate, everywhere, off" in res.stderr


def test_slicing_an_stl_loads_only_what_slicing_needs(tmp_path):
    """Start-up is part of every `preflight slice`: a run without a profile file, on an
    STL, imports neither the web stack, trimesh, scipy, the journal, the daemon's config,
    the TOML parser, the G-code lexer, pkgutil, the other mesh formats' readers nor shutil
    (argparse's default terminal sizing)."""
    stl = tmp_path / "part.stl"
    trimesh.creation.box((10, 10, 4)).export(stl)
    unwanted = ["aiohttp", "trimesh", "scipy", "sqlite3", "asyncio", "daemon.config",
                "tomllib", "printer.gcode", "pkgutil", "zipfile", "repair.io.threemf",
                "repair.io.ply", "repair.io.obj", "repair.io.step", "shutil"]
    probe = (
        "import sys\n"
        "from daemon.cli import main\n"
        f"code = main(['slice', {str(stl)!r}, '-o', {str(tmp_path / 'p.gcode')!r}, '--json'])\n"
        f"print(code, *sorted(m for m in {unwanted!r} if m in sys.modules), file=sys.stderr)\n"
    )
    res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stderr.split() == ["0"]
    assert json.loads(res.stdout)["layers"] == 20
