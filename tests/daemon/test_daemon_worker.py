"""Repair/slicing children: crashes, endless loops and out-of-memory fail the task,
not the caller; a real repair goes through."""

import os
import signal
import threading
from pathlib import Path

import pytest

from daemon.worker import FAULT_ENV, FORK_SERVER, WorkerCancelled, WorkerFailed, run_task

DATA = Path(__file__).resolve().parents[2] / "daemon" / "data"


def spec(tmp_path, name="model.stl"):
    src = tmp_path / name
    src.write_bytes((DATA / "open_cube_stuck_to_side.stl").read_bytes())
    return {"in": str(src), "out": str(tmp_path / "out.stl"), "epsilon": 0.4}


@pytest.mark.parametrize("action, expect", [
    ("abort", "crashed with SIGABRT"),
    ("oom", "ran out of memory"),
])
def test_child_fault_fails_the_task(tmp_path, monkeypatch, action, expect):
    monkeypatch.setenv(FAULT_ENV, f"repair:{action}")
    with pytest.raises(WorkerFailed, match=expect):
        run_task("repair", spec(tmp_path), work_dir=tmp_path / "w", timeout=120,
                 memory_mb=400)
    assert os.getpid() > 0  # we are alive to tell


def test_endless_loop_hits_the_timeout(tmp_path, monkeypatch):
    monkeypatch.setenv(FAULT_ENV, "repair:hang")
    with pytest.raises(WorkerFailed, match="longer than the limit of 1 s"):
        run_task("repair", spec(tmp_path), work_dir=tmp_path / "w", timeout=1, memory_mb=1024)


def test_cancel_kills_the_child(tmp_path, monkeypatch):
    monkeypatch.setenv(FAULT_ENV, "repair:hang")
    ev = threading.Event()
    pids = []
    threading.Timer(0.5, ev.set).start()
    with pytest.raises(WorkerCancelled):
        run_task("repair", spec(tmp_path), work_dir=tmp_path / "w", timeout=600,
                 memory_mb=1024, cancel=ev, on_start=pids.append)
    with pytest.raises(ProcessLookupError):
        os.kill(pids[0], 0)


def test_fault_filter_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv(FAULT_ENV, "repair:abort:crashme")
    report = run_task("repair", spec(tmp_path, "fine.stl"), work_dir=tmp_path / "w",
                      timeout=300, memory_mb=2048)
    assert report["after"]["triangles"] > 0
    with pytest.raises(WorkerFailed, match="SIGABRT"):
        run_task("repair", spec(tmp_path, "crashme.stl"), work_dir=tmp_path / "w2",
                 timeout=300, memory_mb=2048)


def test_real_repair_reports_progress_and_writes_the_mesh(tmp_path):
    stages = []
    s = spec(tmp_path)
    report = run_task("repair", s, work_dir=tmp_path / "w", timeout=300, memory_mb=2048,
                      progress=lambda st, f: stages.append((st, f)))
    assert Path(s["out"]).stat().st_size > 84
    assert report["epsilon"] == 0.4
    assert report["printable"]["ok"] is True
    assert report["printable"]["closed"] is True and report["printable"]["oriented"] is True
    assert stages and stages[0][0] == "load" and all(0 <= f <= 1 for _, f in stages)
    assert isinstance(report["summary"], str) and report["summary"]


def test_bad_input_gives_the_readers_message(tmp_path):
    bad = tmp_path / "junk.stl"
    bad.write_bytes(b"\x00" * 10)
    with pytest.raises(WorkerFailed) as e:
        run_task("repair", {"in": str(bad), "out": str(tmp_path / "o.stl"), "epsilon": 0.4},
                 work_dir=tmp_path / "w", timeout=300, memory_mb=2048)
    assert "\n" not in str(e.value)


def test_a_killed_fork_server_is_replaced(tmp_path):
    """kill -9 of the fork server: the next task starts a new one and runs."""
    run_task("repair", spec(tmp_path, "first.stl"), work_dir=tmp_path / "w1", timeout=300,
             memory_mb=2048)
    server = FORK_SERVER.pid
    assert server is not None
    os.kill(server, signal.SIGKILL)
    report = run_task("repair", spec(tmp_path, "second.stl"), work_dir=tmp_path / "w2",
                      timeout=300, memory_mb=2048)
    assert report["after"]["triangles"] > 0
    assert FORK_SERVER.pid not in (None, server)


def test_fork_server_forks_from_a_single_thread(monkeypatch):
    """numpy/OpenBLAS and the other imports leave no thread in the server to be forked,
    even when the environment asks for a BLAS thread pool."""
    from daemon.forkserver import ForkServer

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    server = ForkServer()
    try:
        server.ensure_started()
        assert os.listdir(f"/proc/{server.pid}/task") == [str(server.pid)]
    finally:
        server.shutdown()


def test_a_task_whose_fork_server_is_killed_fails_with_the_reason(tmp_path, monkeypatch):
    """kill -9 of the server mid-task: the task's child dies with it, the task fails
    with a reason (it does not wait for its timeout), and the next task runs."""
    monkeypatch.setenv(FAULT_ENV, "repair:hang")
    children = []

    def kill_server(pid):
        children.append(pid)
        os.kill(FORK_SERVER.pid, signal.SIGKILL)

    with pytest.raises(WorkerFailed, match="the fork server ended"):
        run_task("repair", spec(tmp_path), work_dir=tmp_path / "w1", timeout=600,
                 memory_mb=1024, on_start=kill_server)
    monkeypatch.delenv(FAULT_ENV)
    report = run_task("repair", spec(tmp_path, "next.stl"), work_dir=tmp_path / "w2",
                      timeout=300, memory_mb=2048)
    assert report["after"]["triangles"] > 0
    stat = Path(f"/proc/{children[0]}/stat")
    assert not stat.exists() or stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"
