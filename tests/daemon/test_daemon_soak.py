"""The soak (bench/soak.py) keeps working: a short run passes its own checks, and the
checks catch a line run twice, a lost file and a print re-sent without a requeue."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

from soak_checks import Findings, account_files, check_prints, match_prefix  # noqa: E402

from printer.gcode import checksum  # noqa: E402

PRINT = ["G28", "M109 S210", "G1 X1 Y1 E0.1", "G1 X2 Y1 E0.2", "M84"]


def _history(*states: str, start: float = 0.0) -> list[dict]:
    rows, previous = [], None
    for offset, state in enumerate(states):
        rows.append({"from_state": previous, "to_state": state, "at": start + offset,
                     "note": None})
        previous = state
    return rows


def _gcode_job(tmp_path: Path, job_id: int, state: str) -> dict:
    path = tmp_path / f"job{job_id}.gcode"
    path.write_text("; a comment\n" + "\n".join(PRINT) + "\n")
    return {"id": job_id, "kind": "gcode", "state": state, "gcode_path": str(path),
            "outputs": {}, "source_name": path.name}


def test_a_line_run_twice_is_caught():
    match = match_prefix(["G28", "M109 S210", "M105", "G1 X1 Y1 E0.1", "G1 X1 Y1 E0.1"],
                         PRINT)
    assert match.done == 3
    assert match.problem and "'G1 X1 Y1 E0.1'" in match.problem and "line 4" in match.problem


def test_noise_artefacts_are_told_apart_from_lines_run_twice():
    # a flushed line's tail whose '*' noise changed ran again; two lines glued by a
    # changed newline ran as the due one; a checksum tail ran as an unknown command
    tail = f"09 S210+{checksum('N2 M109 S210')}"
    segment = ["G28", "M109 S210", f"M109 S210\x11{checksum('N2 M109 S210')}", tail,
               "G1 X1 Y1 E0.1*106wN5 G1 X2", "121", "G1 X2 Y1 E0.2", "M84"]
    match = match_prefix(segment, PRINT)
    assert match.problem is None and match.done == len(PRINT)
    assert match.artefacts == [segment[2], tail, "G1 X1 Y1 E0.1*106wN5 G1 X2"]
    assert match_prefix(["G28", "M109 S210", "M109 S210"], PRINT).problem
    assert match_prefix(["G28", "M109 S210", "M109 S210+99"], PRINT).problem  # wrong sum


def test_host_tickles_and_a_whole_print_pass(tmp_path):
    job = _gcode_job(tmp_path, 1, "done")
    executed = ["M110 N0", "M115", "M211", "M105", "M110 N0", "G28", "M105", *PRINT[1:]]
    found = Findings()
    check_prints([job], {1: _history("queued", "ready", "printing", "done")}, executed, found)
    assert found.problems == []
    assert found.figures["lines_executed"] == len(PRINT)


def test_a_done_print_missing_lines_is_caught(tmp_path):
    job = _gcode_job(tmp_path, 1, "done")
    found = Findings()
    check_prints([job], {1: _history("queued", "ready", "printing", "done")},
                 ["M110 N0", *PRINT[:-1]], found)
    assert found.problems == ["job 1: printed as done but 4 of 5 lines executed"]


def test_a_print_resent_without_requeue_is_caught(tmp_path):
    job = _gcode_job(tmp_path, 1, "done")
    # interrupted after two lines, then (wrongly) printed again from the start
    history = _history("queued", "ready", "printing", "interrupted", "ready", "printing",
                       "done")
    executed = ["M110 N0", *PRINT[:2], "M110 N0", *PRINT]
    found = Findings()
    check_prints([job], {1: history}, executed, found)
    assert any("went back to ready without a requeue" in p for p in found.problems)
    assert any("printed 2 times" in p for p in found.problems)


def test_a_lost_and_a_doubled_file_are_caught(tmp_path):
    spool = tmp_path / "spool"
    spool.mkdir()
    dropped = {"a.gcode": {"kind": "gcode", "expect": "ok"},
               "b.stl": {"kind": "box", "expect": "ok"}}
    jobs = [{"id": 1, "source_name": "b.stl", "state": "failed", "outputs": {}},
            {"id": 2, "source_name": "b.stl", "state": "failed", "outputs": {}}]
    found = Findings()
    account_files(dropped, jobs, spool, found)
    assert "lost: a.gcode has no job" in found.problems
    assert "processed twice: b.stl has jobs 1, 2" in found.problems
    assert found.figures["lost"] == 1 and found.figures["duplicated"] == 1


@pytest.mark.slow
def test_a_short_soak_passes_its_checks(tmp_path):
    run = tmp_path / "run"
    out = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "soak.py"), "--jobs", "10", "--seed", "7",
         "--faults", "0.5", "--slow", "0.3", "--progress", "5", "--out", str(run)],
        capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "all checks passed" in out.stdout
    assert "lost: 0; processed twice: 0; stray jobs: 0" in out.stdout
    assert (run / "executed.log").stat().st_size > 0
