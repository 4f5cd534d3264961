"""Per-face labels of what the repair changed, on real broken meshes repaired for real."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mesh_helpers import sphere

from repair.changes import LABELS, face_changes
from repair.io import load_mesh
from repair.pipeline import repair_mesh

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / ".." / "shared" / "corpus"


def _labelled(path: Path, eps: float = 0.4):
    mesh = load_mesh(path)
    result = repair_mesh(mesh.vertices, mesh.faces, eps)
    after = result.report["after"]
    thick = bool(after["sheet_triangles_thickened"] or after["wires_inflated"]
                 or after["singular_edges_thickened"])
    lids = bool((result.report.get("holes_closed") or {}).get("count"))
    changes = face_changes(mesh.vertices, mesh.faces, result.vertices, result.faces, eps,
                           thickened=thick, lids=lids)
    return mesh, result, changes


def test_united_cubes_keep_their_faces_and_drop_the_inner_wall():
    mesh, result, changes = _labelled(ROOT / "daemon" / "data" / "open_cube_stuck_to_side.stl")
    assert changes.input.shape == (len(mesh.faces),)
    assert changes.output.shape == (len(result.faces),)
    counts = changes.counts()
    # the outside walls come through untouched; the wall between the cubes goes
    assert counts["output"]["kept"] >= len(mesh.faces) // 2
    assert counts["input"].get("dropped", 0) >= 1
    assert "thickened" not in counts["output"] and "thickened" not in counts["input"]
    # a kept output face sits on exactly the points of an input face
    kept = np.flatnonzero(changes.output == LABELS.index("kept"))
    out_tris = {tuple(sorted(map(tuple, t))) for t in result.vertices[result.faces[kept]]}
    in_tris = {tuple(sorted(map(tuple, t)))
               for t in mesh.vertices.astype(np.float32).astype(np.float64)[mesh.faces]}
    assert out_tris <= in_tris


def test_an_already_printable_mesh_is_all_kept():
    v, f = sphere(2, 10.0)
    result = repair_mesh(v, f, 0.4)
    changes = face_changes(v, f, result.vertices, result.faces, 0.4)
    assert changes.counts() == {"input": {"kept": len(f)}, "output": {"kept": len(f)}}


@pytest.mark.skipif(not (CORPUS / "Ghostkeeper_vertical_line.stl").exists(),
                    reason="the shared corpus is not here")
def test_a_wire_becomes_a_thickened_prism():
    _, result, changes = _labelled(CORPUS / "Ghostkeeper_vertical_line.stl")
    assert set(changes.output.tolist()) == {LABELS.index("thickened")}
    assert set(changes.input.tolist()) == {LABELS.index("thickened")}
    assert len(result.faces) > 1


@pytest.mark.skipif(not (CORPUS / "Ghostkeeper_extra_surface.stl").exists(),
                    reason="the shared corpus is not here")
def test_a_sheet_on_a_solid_is_thickened_and_the_solid_kept():
    _, _, changes = _labelled(CORPUS / "Ghostkeeper_extra_surface.stl")
    counts = changes.counts()
    assert counts["output"]["thickened"] > 100
    assert counts["output"]["kept"] > 1000
    assert counts["input"]["thickened"] > 100
