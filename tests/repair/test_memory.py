"""Bounded memory: CGAL's exact intersection test holds every pair of faces whose boxes
meet; a mesh of many crossing slabs has hundreds of millions of them (the arrangement of
a CAD part with needles and T-junctions took 2.3 GB before CGAL's ``std::bad_alloc``).
Such a test is refused by its budget instead, and the exact repair falls back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from repair.errors import BudgetExceeded
from repair.intersections import MAX_BOX_PAIRS, intersecting_face_pairs
from repair.io import load_mesh

DATA = Path(__file__).resolve().parents[1] / "data"
HERE = Path(__file__).resolve().parent


def _stacked(copies: int) -> tuple[np.ndarray, np.ndarray]:
    """``copies`` of CGAL's part (scaled to 60 mm), each shifted 1 um from the last:
    every copy crosses every other one."""
    m = load_mesh(DATA / "cgal_part.obj")
    v = np.asarray(m.vertices, np.float64) * 60.0
    f = np.asarray(m.faces, np.int64)
    shift = 1e-3 * np.arange(copies)[:, None, None] * np.array([1.0, 0.7, 0.3])
    vs = (v[None] + shift).reshape(-1, 3)
    fs = (f[None] + len(v) * np.arange(copies)[:, None, None]).reshape(-1, 3)
    return vs, fs


def test_a_test_of_too_many_overlapping_faces_is_refused_by_its_budget():
    # 400 copies of 346 faces (138k): ~300M pairs of overlapping boxes (4 GB in CGAL).
    v, f = _stacked(400)
    with pytest.raises(BudgetExceeded, match="overlapping boxes"):
        intersecting_face_pairs(v, f)


def test_a_tessellated_surface_is_within_the_budget():
    # The bunny (16k faces: 7 box pairs per face) is tested as before.
    m = load_mesh(DATA / "bunny.ply")
    v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)
    assert len(f) * 64 < MAX_BOX_PAIRS
    assert intersecting_face_pairs(v, f).shape[1] == 2


_CHILD = """
import json, resource, sys
sys.path.insert(0, {here!r})
resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))
from test_cad_faults import real_model, t_junctions
from test_needles import with_needles
from repair.check import check_printable
from repair.pipeline import RepairError, repair_mesh
v, f = real_model("cgal_part.obj", 60.0)
try:
    r = repair_mesh(*t_junctions(*with_needles(v, f, {seed}), {seed}), 0.4)
    out = {{"ok": check_printable(r.vertices, r.faces).ok, "report": r.report["summary"]}}
except RepairError as e:
    out = {{"refused": str(e)}}
print(json.dumps(out))
"""


@pytest.mark.slow
def test_needles_and_t_junctions_stay_within_a_memory_limit():
    # Seed 1 of needles plus T-junctions on CGAL's part: the finish's arrangement grew
    # to 259k faces of crossing slabs, whose intersection test died of std::bad_alloc
    # under a 5 GB limit (the OOM killer on a 4 GB printer host). Under 3 GB it now ends
    # printable or refused with its reason, never out of memory.
    limit = 3 << 30
    code = _CHILD.format(here=str(HERE), limit=limit, seed=1)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out.get("ok", False) or "refused" in out, out
