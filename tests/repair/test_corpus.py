"""Every real broken model in ../shared/corpus comes out printable (on the float32
coordinates actually written), with Attene's deviation D <= 0.6 eps where sheets or wires
were thickened, D ~ 0 where the outer hull was already closed, and D within the lid's
reach from its rim where small holes were closed; and no written face has a winding
number other than 0 just outside it or 1 just inside it (but the known failures)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from repair.check import check_printable
from repair.io import load_mesh
from repair.junk import face_winding_sides, failing_faces
from repair.pipeline import RepairError, repair_file

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"
EPS = 0.4
FILES = (
    sorted(p.name for p in CORPUS.iterdir() if p.suffix.lower() in {".stl", ".obj", ".ply", ".3mf"})
    if CORPUS.is_dir()
    else []
)
#: Models with nothing printable in them (every triangle collapses to a point).
NOTHING_PRINTABLE = {"Ghostkeeper_zero_size_cube.stl"}
#: Outputs that still hold faces failing the two-sided winding test (47):
#: walls of slits thinner than the probe (another wall of the same shell 1e-9 to 1e-5 mm
#: away: winding 1|1) whose corners do not face each other, and blades that thin (0|0)
#: -- kept from near-coincident input faces by the arrangement and the union.
#: repair.hairline zips, snaps or fills them on outputs of up to 20k faces where the
#: result rounds to a printable mesh (admesh_basic: a 600 mm x 3.5e-6 mm needle, zipped,
#: 2 -> 0; admesh_remove-unconnected-bad: 2 -> 0), and cuts them out and lids the holes
#: (mikedh_counter's slits, 24 -> 0, found near folds on its 88k faces; mikedh_teapot's
#: blades, 86 -> 0); not on these. (mikedh_chair_model's
#: blade went with the sheets' eps-blocks, repair.thicken.face_blocks; mikedh_target's 46
#: with its blocks' union, the sheet now being thickened by its level set,
#: repair.sheet_level_set; mikedh_teapot's 30 when finish separated its touching edges
#: at the first round, repair.finish.) mikedh_cycloidal's were 382 slit walls that
#: manifold3d's union of its closed bodies left where bodies touch a few float32 ulps
#: apart; snapping the bodies' coordinates onto their planes first
#: (repair.body_union.snapped_coordinates) leaves 47, within 4.5e-7 mm of the wall they
#: face: 33 share an edge with it (thin wedges, e.g. one corner 6e-6 mm off the other's
#: plane: out of the snap's reach; snapping 32-64 ulps leaves 46-43 but D goes
#: 1.6e-5 -> 0.02 mm), 12 a corner, 2 none. Cut and lidded (repair.hairline with the
#: search near folds ungated) they go, 47 -> 0, but D grows to 9.5e-3 mm and CPU
#: 8 -> 27 s; zipped, 47 -> 42. Finding them is cheap: all 47 lie within 2 edge rings
#: of a thin fold (an edge whose faces face opposite ways, dot < -0.9, and one far
#: corner within 4 probe distances of the other face's plane): 408 of 111k faces, 0.17 s
#: CPU, then hairline_suspects ~0.35 s and the exact winding ~0.9 s; the cost is the cut
#: rounds' finish on 111k faces (~11 s a round: repair.face_grid's cells are 0.39 mm on
#: this 1.9 mm part, so a region near 136 changed faces holds 99k; after a mend with
#: unknown pairs all faces are tested): CPU median 10.6 -> 32.1 s (3 runs each, same
#: minutes), D 9.5e-3 mm. Cutting the thin
#: folds in the union's output before rounding (no winding test) leaves 72-129, D
#: 0.014-0.019 mm. Moving a body's corners within 4-22 probes of a facing body's crossing
#: face (dot < -0.99) onto its plane before the union makes touching edges that finish
#: thickens at eps (D 0.2 mm); moving only corners inside that body leaves 126.
#: Known failures, asserted so, so that a fix shows up here.
WINDING_KNOWN_FAILURES = {
    "mikedh_cycloidal.ply",
}


@pytest.mark.slow
@pytest.mark.skipif(not CORPUS.is_dir(), reason="corpus not present")
@pytest.mark.parametrize("name", FILES)
def test_corpus_model_repairs_to_a_printable_solid(name, tmp_path):
    src = CORPUS / name
    out = tmp_path / "out.stl"
    if name in NOTHING_PRINTABLE:
        with pytest.raises(RepairError, match="nothing printable"):
            repair_file(src, out, epsilon=EPS)
        return
    report = repair_file(src, out, epsilon=EPS, report_path=tmp_path / "r.json")
    written = load_mesh(out)
    verdict = check_printable(written.vertices, written.faces)
    assert verdict.ok, verdict.failures()
    assert verdict.volume > 0
    outside, inside = face_winding_sides(written.vertices, written.faces)
    bad = int(failing_faces(outside, inside).sum())
    assert (bad > 0) == (name in WINDING_KNOWN_FAILURES), f"{bad} faces fail the winding test"
    after = report["after"]
    thickened = (
        after["sheet_triangles_thickened"] or after["wires_inflated"]
        or after["singular_edges_thickened"]
    )  # fmt: skip
    # A lid over a small hole adds surface the input did not have: D (output -> input)
    # there is bounded by how far the lid reaches from its rim, not by eps.
    lid = report["holes_closed"]["max_lid_radius"]
    if thickened:
        # A thickened face's prism lies within eps/2 of it; the eps-prisms along the edges
        # where two sheet faces bend reach eps/2 * sqrt(2) from that edge (a mitre).
        assert report["deviation"] <= max(EPS / np.sqrt(2) + 1e-6, lid)
    else:
        size = float(np.ptp(written.vertices, axis=0).max())
        assert report["deviation"] <= 1e-5 * size + 1e-6 + lid
