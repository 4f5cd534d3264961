"""The fixed costs of a ``preflight slice`` process: its exit, and garbage collection of the
start-up's objects (issue 17: a small model's run is mostly these)."""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys

import trimesh

from slicer.parallel import forked

PROBE = (
    "import atexit, sys\n"
    "atexit.register(lambda: print('TEARDOWN', file=sys.stderr))\n"
    "from daemon.cli import script\n"
    "sys.argv = ['preflight', *sys.argv[1:]]\n"
    "script()\n"
)


def test_a_slice_skips_the_teardown_with_its_output_complete(tmp_path):
    """``slice`` ends with os._exit (no atexit handler runs) after flushing stdout, which is
    a file here (block-buffered): the JSON summary is whole and the G-code on disk; a failed
    slice's one-line error is flushed too, and a run started without a stdout ends as well.
    Other commands exit as usual."""
    stl = tmp_path / "part.stl"
    trimesh.creation.cylinder(radius=6, height=3, sections=48).export(stl)
    out, log = tmp_path / "part.gcode", tmp_path / "summary.json"
    with log.open("w") as sink:
        res = subprocess.run([sys.executable, "-c", PROBE, "slice", str(stl), "-o", str(out),
                              "--json"], stdout=sink, stderr=subprocess.PIPE, text=True,
                             timeout=300)
    assert res.returncode == 0, res.stderr
    assert "TEARDOWN" not in res.stderr
    summary = json.loads(log.read_text())
    assert summary["layers"] == 15
    text = out.read_text()
    assert text.count(";LAYER:") == 15 and "M73 P100 R0\n" in text and text.endswith("\n")
    bad = subprocess.run([sys.executable, "-c", PROBE, "slice", str(tmp_path / "none.stl"),
                          "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1 and bad.stderr.startswith("preflight: no such file")
    assert "TEARDOWN" not in bad.stderr
    out.unlink()
    closed = subprocess.run([sys.executable, "-m", "daemon", "slice", str(stl), "-o", str(out)],
                            preexec_fn=lambda: os.close(1), stderr=subprocess.PIPE, text=True,
                            timeout=300)  # started without a stdout: sys.stdout is None
    assert closed.returncode == 0 and closed.stderr == "" and out.stat().st_size > 0
    other = subprocess.run([sys.executable, "-c", PROBE, "example-config"],
                           capture_output=True, text=True, timeout=300)
    assert other.returncode == 0 and "TEARDOWN" in other.stderr


def test_workers_leave_the_callers_frozen_objects_frozen():
    """slicer.parallel.forked freezes the objects that exist while its workers run; it lets
    them back into collection afterwards only when nothing was frozen before it (the CLI
    freezes its start-up's objects, which must stay out of every later collection)."""
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with forked([(lambda: 6 * 7, "answer")]) as workers:
            assert workers[0].result() == 42
        assert gc.get_freeze_count() >= frozen > 0
    finally:
        gc.unfreeze()
    with forked([(lambda: 1, "one")]) as workers:
        assert workers[0].result() == 1
    assert gc.get_freeze_count() == 0
