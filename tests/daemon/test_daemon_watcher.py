"""Completeness detection on a real folder with real inotify events."""

import os
import time

import pytest

from daemon.watcher import SpoolWatcher


def wait_due(w: SpoolWatcher, seconds: float) -> list:
    """Collect what the watcher hands over during ``seconds``."""
    got = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        got += [p.name for p in w.due()]
        time.sleep(0.05)
    return got


@pytest.mark.slow
def test_file_written_in_chunks_is_taken_only_after_close(tmp_path):
    w = SpoolWatcher(tmp_path, settle_seconds=0.3, close_grace_seconds=0.2)
    w.start()
    try:
        with open(tmp_path / "slow.stl", "wb") as f:
            for _ in range(8):           # pauses longer than settle_seconds
                f.write(b"x" * 1000)
                f.flush()
                os.fsync(f.fileno())
                assert wait_due(w, 0.5) == []
        got = wait_due(w, 1.5)
        assert got == ["slow.stl"]
        assert (tmp_path / "slow.stl").stat().st_size == 8000
    finally:
        w.stop()


def test_existing_files_are_found_by_the_start_up_scan(tmp_path):
    (tmp_path / "a.stl").write_bytes(b"1")
    (tmp_path / "b.gcode").write_bytes(b"2")
    (tmp_path / "c.stl.part").write_bytes(b"3")
    (tmp_path / ".hidden.stl").write_bytes(b"4")
    (tmp_path / "sub").mkdir()
    w = SpoolWatcher(tmp_path, settle_seconds=0.3, close_grace_seconds=0.1)
    w.start()
    try:
        got = wait_due(w, 1.5)
    finally:
        w.stop()
    assert sorted(got) == ["a.stl", "b.gcode"]


def test_rename_from_a_partial_name_is_taken(tmp_path):
    w = SpoolWatcher(tmp_path, settle_seconds=30, close_grace_seconds=0.1)
    w.start()
    try:
        (tmp_path / "x.stl.part").write_bytes(b"data")
        assert wait_due(w, 0.5) == []
        os.rename(tmp_path / "x.stl.part", tmp_path / "x.stl")
        assert wait_due(w, 1.0) == ["x.stl"]
    finally:
        w.stop()


def test_polling_mode_waits_for_stable_size(tmp_path):
    w = SpoolWatcher(tmp_path, settle_seconds=0.6, close_grace_seconds=0.1, poll=True)
    w.start()
    try:
        with open(tmp_path / "p.stl", "wb") as f:
            for _ in range(4):
                f.write(b"y" * 100)
                f.flush()
                assert wait_due(w, 0.3) == []
        assert wait_due(w, 2.5) == ["p.stl"]
    finally:
        w.stop()


def test_file_renamed_in_from_outside_is_taken_once_stable(tmp_path):
    spool = tmp_path / "spool"
    spool.mkdir()
    (tmp_path / "m.stl").write_bytes(b"model")
    w = SpoolWatcher(spool, settle_seconds=0.4, close_grace_seconds=0.1)
    w.start()
    try:
        os.rename(tmp_path / "m.stl", spool / "m.stl")
        assert wait_due(w, 1.5) == ["m.stl"]
    finally:
        w.stop()


def test_empty_new_file_waits_for_its_writer(tmp_path):
    w = SpoolWatcher(tmp_path, settle_seconds=0.3, close_grace_seconds=0.1)
    w.start()
    try:
        fh = open(tmp_path / "e.stl", "wb")  # noqa: SIM115
        assert wait_due(w, 1.0) == []      # created, empty, still open
        fh.write(b"data")
        fh.close()
        assert wait_due(w, 1.0) == ["e.stl"]
    finally:
        w.stop()
