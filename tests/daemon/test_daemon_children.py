"""The task children and the fork server never outlive the daemon."""

from __future__ import annotations

from pathlib import Path

import pytest
from daemon_helpers import DaemonProc, broken_stl, drop, write_config

from daemon.worker import FAULT_ENV


def descendants(pid: int) -> set[int]:
    """Every live (non-zombie) process below ``pid``, from /proc."""
    parent: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parent[int(entry.name)] = int(fields[1])
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {child for child, ppid in parent.items() if ppid in frontier} - found
        found |= frontier
    return found


def alive(pids: set[int]) -> set[int]:
    live = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            live.add(pid)
    return live


@pytest.fixture
def hanging_daemon(tmp_path):
    d = DaemonProc(write_config(tmp_path), {FAULT_ENV: "repair:hang"})
    yield d
    d.stop()
    if d._journal is not None:
        d._journal.close()


def test_no_child_outlives_a_killed_daemon(tmp_path, hanging_daemon):
    d = hanging_daemon.start()
    drop(d.cfg.spool.path, "model.stl", broken_stl(tmp_path / "b.stl").read_bytes())
    d.wait_for(lambda: d.jobs() and str(d.jobs()[0].state) == "repairing", what="repairing")
    # the fork server and the task child (hanging in its repair) run below the daemon
    below = d.wait_for(lambda: (found := descendants(d.proc.pid)) and len(found) >= 2 and found,
                       what="the fork server and its child")
    d.kill9()
    d.wait_for(lambda: not alive(below), what="exit")
    assert not alive(below)
