"""SD-card wear: the journal's soft writes (progress, temperatures, the heartbeat) are
not fsynced one by one; its state changes are. SQLite's own fsync/fdatasync calls are
counted with strace on a real journal in a child process."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap

import pytest

CHILD = textwrap.dedent("""
    import sys, time
    from daemon.journal import Journal
    from daemon.states import JobState
    j = Journal(sys.argv[1])
    job = j.add_job(name="a.gcode", source_name="a.gcode", kind="gcode", work_dir="w",
                    input_path="a.gcode", state=JobState.READY)
    j.transition(job, JobState.PRINTING)
    print("soft", time.time(), flush=True)
    for i in range(60):
        j.update(job, progress=i / 60, durable=False)
        j.add_temperatures(job, {"T": [200.0 + i, 210.0], "B": [60.0, 60.0]})
        j.set_meta("status", {"i": i}, durable=False)
        time.sleep(0.01)
    print("durable", time.time(), flush=True)
    j.transition(job, JobState.DONE, progress=1.0)
    print("end", time.time(), flush=True)
    j.close()
    reader = Journal(sys.argv[1], readonly=True)
    assert len(reader.temperatures(job)) == 60, "soft writes are committed"
    assert str(reader.get(job).state) == "done"
""")


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_soft_writes_are_not_synced_one_by_one_but_state_changes_are(tmp_path):
    trace = tmp_path / "trace"
    out = subprocess.run(
        ["strace", "-f", "-ttt", "-e", "trace=fsync,fdatasync", "-o", str(trace),
         sys.executable, "-c", CHILD, str(tmp_path / "journal.sqlite")],
        capture_output=True, text=True, timeout=120, check=True).stdout
    marks = {line.split()[0]: float(line.split()[1]) for line in out.splitlines()}
    syncs = [float(line.split()[1]) for line in trace.read_text().splitlines()
             if "fsync(" in line or "fdatasync(" in line]
    soft = [t for t in syncs if marks["soft"] < t < marks["durable"]]
    durable = [t for t in syncs if marks["durable"] < t < marks["end"]]
    # 180 soft commits within 10 s of the last durable one: none is synced on its own
    assert soft == []
    assert durable  # the state change is on disk before transition() returns
