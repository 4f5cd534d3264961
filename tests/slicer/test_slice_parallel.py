"""The embedded slicer on several processes: the same G-code as one process, byte for byte;
a worker that dies is a clear SliceError, not a hang; no worker outlives the slice."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from manifold3d import Manifold
from slice_checks import mesh_of, sphere
from support_checks import BUNNY, mushroom, rotated_bunny, t_bracket

from slicer.engine import SliceError, slice_mesh
from slicer.parallel import Worker, WorkerError, available_cpus
from slicer.profile import Profile, ProfileError, load_profile

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180))


def _children() -> set[int]:
    """This process's child processes, zombies included (Linux /proc)."""
    out: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        try:
            out.update(int(x) for x in (task / "children").read_text().split())
        except OSError:
            continue
    return out


def _islands():
    """Four posts of different heights and a bar over two of them: layers with several
    islands, so where the nozzle enters a layer changes where it leaves it."""
    posts = [Manifold.cylinder(h, 3, 3, 32).translate([x, y, 0])
             for x, y, h in ((0, 0, 12), (20, 0, 9), (0, 20, 15), (20, 20, 6))]
    bar = Manifold.cube([26, 4, 2]).translate([-3, -2, 12])
    return mesh_of(sum(posts[1:], posts[0]) + bar)


def _gcode(model, workers: str, **over) -> tuple[str, dict]:
    v, f = model()
    result = slice_mesh(v, f, BASE.with_overrides({"workers": workers, **over}))
    return result.gcode, result.summary


@pytest.mark.parametrize("name, model, over", [
    ("mushroom", mushroom, {"support": "auto"}),
    ("t_bracket aligned seam", t_bracket, {"support": "auto", "seam_position": "aligned"}),
    ("sphere", lambda: sphere(12.0, 4), {}),
    ("islands nearest seam", _islands, {"seam_position": "nearest"}),
    ("islands absolute E", _islands, {"relative_e": False, "seam_position": "aligned"}),
])
def test_workers_write_the_same_gcode_as_one_process(name, model, over):
    before = _children()  # other tests' long-lived children (servers, pools) are not ours
    one, s1 = _gcode(model, "1", **over)
    for workers in ("2", "3"):
        many, sn = _gcode(model, workers, **over)
        assert sn["workers"] == int(workers)
        assert many == one, f"{name}: {workers} workers changed the G-code"
    assert s1["workers"] == 1
    assert not _children() - before


@pytest.mark.slow
@pytest.mark.skipif(not BUNNY.is_file(), reason="corpus not present")
def test_rotated_bunny_with_support_is_the_same_on_two_processes():
    v, f = rotated_bunny()
    one = slice_mesh(v, f, BASE.with_overrides({"workers": "1", "support": "auto"}))
    two = slice_mesh(v, f, BASE.with_overrides({"workers": "2", "support": "auto"}))
    assert two.summary["workers"] == 2 and two.gcode == one.gcode
    assert two.summary["worker_peak_mb"] > 0


def test_a_killed_worker_is_a_slice_error_and_leaves_no_process():
    v, f = mushroom()
    killed: list[int] = []
    before = _children()  # other tests' long-lived children: never killed, not counted

    def kill_a_worker(stage: str, fraction: float) -> None:
        if stage == "gcode" and not killed:
            for pid in _children() - before:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

    with pytest.raises(SliceError, match="killed by SIGKILL"):
        slice_mesh(v, f, BASE.with_overrides({"workers": "2", "support": "auto"}),
                   progress=kill_a_worker)
    assert killed
    assert not _children() - before


def test_a_killed_planning_worker_is_a_slice_error_and_leaves_no_process():
    """The shells are planned on the workers before the layers are written: a worker killed
    then (a 20k-triangle sphere: a tenth of a second of planning each) is a one-line
    SliceError as well."""
    v, f = sphere(20.0, 5)
    killed: list[int] = []
    before = _children()

    def kill_a_planner(stage: str, fraction: float) -> None:
        if stage == "shells" and not killed:
            for pid in _children() - before:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

    with pytest.raises(SliceError, match="planning layers .* killed by SIGKILL") as err:
        slice_mesh(v, f, BASE.with_overrides({"workers": "2"}), progress=kill_a_planner)
    assert killed and "\n" not in str(err.value)
    assert not _children() - before


def test_shells_planned_on_workers_are_those_planned_in_one_process():
    """Each layer's shells and solid skin, planned by any process, are the same arrays."""
    from slicer import engine
    from slicer.geometry import shape_key

    v, f = mushroom()
    planned = {}
    for workers in ("1", "3"):
        profile = BASE.with_overrides({"workers": workers, "support": "auto"})
        model, man = engine._placed(*engine._checked_mesh(v, f), profile)
        engine._plan_layers(model, man, profile, engine._Reporter(None))  # shells, skins
        assert model.plan_workers == int(workers)
        planned[workers] = [
            ([p.points.tobytes() for p in sh.loops + sh.thin], shape_key(sh.inner),
             shape_key(solid)) for sh, solid in zip(model.shells, model.solids, strict=True)]
    assert len(planned["1"]) >= 100 and planned["3"] == planned["1"]


@pytest.mark.skipif(available_cpus() < 2, reason="one CPU: auto never forks")
def test_auto_plans_a_detailed_model_on_the_cores_and_a_prismatic_one_in_one_process():
    from slicer import engine

    for model, several in ((lambda: sphere(20.0, 5), True), (mushroom, False)):
        v, f = model()
        profile = BASE.with_overrides({"support": "auto"})
        placed, man = engine._placed(*engine._checked_mesh(v, f), profile)
        engine._plan_layers(placed, man, profile, engine._Reporter(None))
        assert (placed.plan_workers > 1) == several


def test_the_summary_counts_every_workers_cpu():
    """Planning and writing workers: the summary's worker CPU is what this process's reaped
    children used during the slice (thumbnails off here: their child is not counted)."""
    import resource

    def children_cpu() -> float:
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        return usage.ru_utime + usage.ru_stime

    v, f = sphere(20.0, 5)
    before = children_cpu()
    summary = slice_mesh(v, f, BASE.with_overrides({"workers": "2", "thumbnails": ""})).summary
    used = children_cpu() - before
    assert used > 0 and summary["worker_cpu_seconds"] == pytest.approx(used, abs=0.01)


def test_the_summary_shows_how_the_writing_was_split():
    """The parent's CPU writing its share, then each writing worker's (their sum within the
    children's CPU this slice used), and the parent's wait for their G-code; none where one
    process writes alone (its summary stays the same from run to run)."""
    import resource

    def cpu(who: int) -> float:
        usage = resource.getrusage(who)
        return usage.ru_utime + usage.ru_stime

    v, f = sphere(20.0, 5)
    profile = BASE.with_overrides({"thumbnails": ""})
    own, children = cpu(resource.RUSAGE_SELF), cpu(resource.RUSAGE_CHILDREN)
    two = slice_mesh(v, f, profile.with_overrides({"workers": "2"})).summary
    own, children = cpu(resource.RUSAGE_SELF) - own, cpu(resource.RUSAGE_CHILDREN) - children
    parent, *workers = two["write_cpu_seconds"]
    assert len(workers) == 1 and parent > 0 and workers[0] > 0
    assert parent <= own + 0.01 and workers[0] <= children + 0.01
    assert two["write_wait_seconds"] >= 0
    one = slice_mesh(v, f, profile.with_overrides({"workers": "1"})).summary
    assert "write_cpu_seconds" not in one and "write_wait_seconds" not in one


def test_a_worker_that_raises_names_the_error():
    worker = Worker(lambda: 1 / 0, "test")
    with pytest.raises(WorkerError, match="ZeroDivisionError"):
        worker.result()
    assert worker.pid not in _children()


def test_auto_keeps_a_small_model_in_one_process():
    v, f = mesh_of(Manifold.cube([10, 10, 5]))
    assert slice_mesh(v, f, BASE).summary["workers"] == 1


@pytest.mark.parametrize("value", ["0", "-1", "many", "2.5", "999"])
def test_a_bad_worker_count_is_refused_with_its_name(value):
    with pytest.raises(ProfileError, match="workers"):
        BASE.with_overrides({"workers": value})


def test_workers_from_a_toml_profile_take_a_number(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text("[slicer]\nworkers = 2\n")
    assert load_profile(path, BASE).workers == "2"
    path.write_text('[slicer]\nworkers = "auto"\n')
    assert load_profile(path, BASE).workers == "auto"


def test_the_cli_takes_workers_and_refuses_a_bad_count_in_one_line(tmp_path):
    import json
    import subprocess
    import sys

    import trimesh

    v, f = mushroom()
    stl = tmp_path / "mushroom.stl"
    trimesh.Trimesh(v, f).export(stl)
    outs = {}
    for workers in ("1", "2"):
        out = tmp_path / f"w{workers}.gcode"
        res = subprocess.run([sys.executable, "-m", "daemon", "slice", str(stl), "-o", str(out),
                              "--workers", workers, "--json"],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        assert json.loads(res.stdout)["workers"] == int(workers)
        outs[workers] = out.read_bytes()
    assert outs["1"] == outs["2"]
    res = subprocess.run([sys.executable, "-m", "daemon", "slice", str(stl), "-o",
                          str(tmp_path / "x.gcode"), "--workers", "0"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode != 0 and res.stderr.count("\n") == 1 and "workers" in res.stderr
    assert not (tmp_path / "x.gcode").exists()


def test_when_no_worker_can_be_forked_the_parent_writes_every_layer(monkeypatch):
    import slicer.parallel

    one, _ = _gcode(mushroom, "1", support="auto")

    def no_fork() -> int:
        raise BlockingIOError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(slicer.parallel.os, "fork", no_fork)
    many, summary = _gcode(mushroom, "3", support="auto")
    assert summary["workers"] == 1 and many == one


def test_the_daemons_slicing_child_uses_workers_under_its_memory_cap(tmp_path):
    """The daemon's slicing child (forked by its fork server, address space capped) forks
    its own workers; the G-code is the one process's and the task leaves no process."""
    import trimesh

    from daemon.worker import run_task

    v, f = mushroom()
    stl = tmp_path / "mushroom.stl"
    trimesh.Trimesh(v, f).export(stl)
    outs = {}
    for workers in ("1", "2"):
        spec = {"in": str(stl), "out": str(tmp_path / f"w{workers}.gcode"), "nozzle": 0.4,
                "overrides": {"workers": workers}}
        got = run_task("slice", spec, work_dir=tmp_path / f"work{workers}", timeout=600,
                       memory_mb=2048)
        assert got["summary"]["workers"] == int(workers)
        outs[workers] = Path(spec["out"]).read_bytes()
    assert outs["1"] == outs["2"]
    if int(got["summary"]["worker_peak_mb"]):
        assert got["summary"]["worker_peak_mb"] < 300
