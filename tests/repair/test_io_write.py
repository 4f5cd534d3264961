"""repair.io.write_atomic / atomic_path: the project's one atomic file writer."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from repair.io import atomic_path, load_mesh, write_atomic, write_stl


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _with_umask(mask: int, write) -> None:
    old = os.umask(mask)
    try:
        write()
    finally:
        os.umask(old)


def test_bytes_str_and_mixed_chunks(tmp_path):
    target = tmp_path / "deep" / "er" / "out.txt"  # missing folders are created
    write_atomic(target, [b"one ", "two ", b"three"])
    assert target.read_bytes() == b"one two three"
    write_atomic(target, b"bytes alone")
    assert target.read_bytes() == b"bytes alone"
    write_atomic(target, "text alone, \u00e9")
    assert target.read_text(encoding="utf-8") == "text alone, \u00e9"
    write_atomic(target, (part for part in [b"a", b"b"]))  # any iterable
    assert target.read_bytes() == b"ab"
    write_atomic(target, bytearray(b"a bytearray"))
    assert target.read_bytes() == b"a bytearray"
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.txt"]


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_new_file_mode_follows_the_umask(tmp_path, mask):
    target = tmp_path / "out.bin"
    _with_umask(mask, lambda: write_atomic(target, [b"x"]))
    assert _mode(target) == 0o666 & ~mask
    stl = tmp_path / "cube.stl"
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    _with_umask(mask, lambda: write_stl(stl, verts, np.array([[0, 1, 2]])))
    assert _mode(stl) == 0o666 & ~mask
    assert load_mesh(stl).triangles == 1


def test_failure_mid_write_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    target = tmp_path / "report.json"
    target.write_bytes(b"old content")

    def chunks():
        yield b"new content, first half"
        raise RuntimeError("the producer failed half-way")

    with pytest.raises(RuntimeError, match="half-way"):
        write_atomic(target, chunks())
    assert target.read_bytes() == b"old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]

    with pytest.raises(TypeError):
        write_atomic(target, [b"fine", 42])  # not bytes: refused by the file object
    assert target.read_bytes() == b"old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_disk_full_mid_write_keeps_the_old_file(tmp_path):
    """A real write error from the kernel: the file-size limit (EFBIG) stands in for a
    full disk, in a child process so the limit does not leak into the test run."""
    target = tmp_path / "model.stl"
    target.write_bytes(b"old model")
    script = (
        "import resource, signal, sys\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
        "from repair.io import write_atomic\n"
        "try:\n"
        "    write_atomic(sys.argv[1], [b'x' * 3000, b'y' * 3000])\n"
        "except OSError as exc:\n"
        "    print('refused', exc.errno)\n"
    )
    res = subprocess.run([sys.executable, "-c", script, str(target)], capture_output=True,
                         text=True, cwd=Path(__file__).resolve().parents[2])
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("refused"), res.stdout
    assert target.read_bytes() == b"old model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.stl"]


def test_unwritable_folder_is_an_oserror_and_the_old_file_stays(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root ignores folder permissions")
    target = tmp_path / "locked" / "out.txt"
    target.parent.mkdir()
    target.write_bytes(b"old")
    target.parent.chmod(0o555)
    try:
        with pytest.raises(PermissionError):
            write_atomic(target, b"new")
        assert target.read_bytes() == b"old"
    finally:
        target.parent.chmod(0o755)


def test_atomic_path_for_another_programs_output(tmp_path):
    target = tmp_path / "part.gcode"
    target.write_text("old gcode")
    with atomic_path(target, suffix=".gcode") as tmp:
        assert tmp.parent == tmp_path and tmp.name.endswith(".gcode") and tmp.exists()
        assert target.read_text() == "old gcode"  # nothing visible until the block ends
        subprocess.run(["sh", "-c", f"printf 'G28\\n' > '{tmp}'"], check=True)
    assert target.read_text() == "G28\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["part.gcode"]

    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half a slice")
            raise RuntimeError("the slicer crashed")
    assert target.read_text() == "G28\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["part.gcode"]


def test_atomic_path_new_file_mode_follows_the_umask(tmp_path):
    target = tmp_path / "out.gcode"

    def write() -> None:
        with atomic_path(target) as tmp:
            tmp.write_text("G1 X1\n")

    _with_umask(0o027, write)
    assert _mode(target) == 0o640
