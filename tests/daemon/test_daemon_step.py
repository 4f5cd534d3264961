"""STEP end to end: the real daemon takes a STEP from its spool folder and from the HTTP
upload, tessellates it at the printer's tolerance, repairs, slices and prints it on the
virtual printer, and shows the tessellation in the status page's 3D view; without the ``cad``
extra, the job fails with the install command."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from daemon_helpers import DaemonProc, drop, write_config
from test_daemon_e2e import read_log, settled

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "repair"))

from step_helpers import (  # noqa: E402
    F32,
    facet_sagitta,
    needs_ocp,
    without_cad_extra_env,
    write_plate_step,
)

from repair.io import load_mesh  # noqa: E402
from repair.io.step import INSTALL_HINT, chordal_deflection  # noqa: E402

#: a small bracket: 16 x 12 x 2 mm, one 4 mm hole, a 3 mm boss; quick to print
BRACKET = {"size": (16.0, 12.0, 2.0), "holes": [(5.0, 6.0, 2.0)], "boss": (11.5, 6.0, 1.5, 2.0)}


@needs_ocp
def test_a_step_from_the_spool_and_from_an_upload_is_printed(tmp_path, web_daemon):
    from test_web_page import get, parse_mesh
    from test_web_safety import upload

    d, port, key = web_daemon()
    step = write_plate_step(tmp_path / "bracket.step", **BRACKET)
    drop(d.cfg.spool.path, "bracket.step", step.read_bytes())
    answer = upload(port, key, "bracket2.stp", step.read_bytes())
    assert answer.status == 201, answer.body
    d.wait_for(lambda: len(d.jobs()) == 2 and all(settled(j) for j in d.jobs()),
               what="two STEP jobs printed")
    assert d.states() == {"bracket.step": "done", "bracket2.stp": "done"}, d.tail()
    printed = [line for line in read_log(tmp_path / "printer.log") if line.startswith("G1 ")]
    assert len(printed) > 200
    for job in d.jobs():  # what was printed is the fine tessellation of the design hole
        report = json.loads(Path(job.outputs["report_json"]).read_text())
        assert report["repair_report"]["input"]["format"] == "step", report
        repaired = load_mesh(job.outputs["repaired"])
        sagitta, _ = facet_sagitta(repaired.vertices, repaired.faces, *BRACKET["holes"][0])
        assert len(sagitta) >= 64
        assert sagitta.max() <= chordal_deflection(report["epsilon"]) + F32
        # the status page's 3D view of the input is that tessellation
        tris, _, _ = parse_mesh(get(port, f"/api/preflight/jobs/{job.id}/mesh/input", key).body)
        assert np.allclose(tris, repaired.vertices[repaired.faces], atol=1e-6)
    # ... and Open CASCADE was loaded only in the repair children, never in the daemon
    maps = Path(f"/proc/{d.proc.pid}/maps").read_text()
    assert "cadquery_ocp" not in maps and "OCP.cpython" not in maps


def test_without_the_cad_extra_a_step_fails_with_the_install_command(tmp_path):
    d = DaemonProc(write_config(tmp_path), env=without_cad_extra_env(tmp_path)).start()
    try:
        step = b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n"
        drop(d.cfg.spool.path, "part.stp", step)
        d.wait_for(lambda: d.jobs() and all(settled(j) for j in d.jobs()), what="the refusal")
        (job,) = d.jobs()
        assert str(job.state) == "failed"
        assert "STEP files need the optional CAD kernel" in job.reason
        assert INSTALL_HINT in job.reason
        assert (d.cfg.failed_dir / "part.stp").read_bytes() == step  # nothing lost
        assert d.alive()
    finally:
        d.stop()
