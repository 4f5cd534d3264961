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
from repair.files import repair_file
from repair.io import load_mesh
from repair.junk import face_winding_sides, failing_faces
from repair.pipeline import RepairError

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "corpus"
EPS = 0.4
FILES = (
    sorted(p.name for p in CORPUS.iterdir() if p.suffix.lower() in {".stl", ".obj", ".ply", ".3mf"})
    if CORPUS.is_dir()
    else []
)
#: Models with nothing printable in them (every triangle collapses to a point).
NOTHING_PRINTABLE = {"Ghostkeeper_zero_size_cube.stl"}
#: Outputs that still hold faces failing the two-sided winding test: none. The last were
#: walls of slits thinner than the probe (another wall of the same shell 1e-9 to 1e-5 mm
#: away: winding 1|1) and blades that thin (0|0), kept from near-coincident input faces
#: by the arrangement and the union. repair.hairline zips, snaps or fills them on
#: outputs of up to 20k faces (admesh_basic: a 600 mm x 3.5e-6 mm needle, 2 -> 0;
#: admesh_remove-unconnected-bad: 2 -> 0) and cuts them out and lids the holes
#: (mikedh_counter's slits, 24 -> 0; mikedh_teapot's blades, 86 -> 0). mikedh_chair_model's
#: blade went with the sheets' eps-blocks (repair.thicken.face_blocks), mikedh_target's 46
#: with its blocks' union (repair.sheet_level_set), mikedh_teapot's 30 when finish
#: separated its touching edges at the first round. mikedh_cycloidal's were 382 slit
#: walls where its closed bodies touch a few float32 ulps apart;
#: repair.body_union.snapped_coordinates left 47 (50 counted exactly: libigl's fast
#: winding number read 3 of them right by error), thin wedges within 4.5e-7 mm of the
#: wall they face. They lie within 2 edge rings of a thin fold (an edge whose faces face
#: opposite ways, one far corner within 4 probe distances of the other face's plane;
#: repair.hairline.fold_suspects: 636 of 111k faces), and are cut out and lidded in 4
#: rounds checked near the cuts only (repair.hairline_cut.local_cut_rounds: a lid back to
#: back with a face cancels with it, so no round needs a mend; one check at the end),
#: the winding numbers from one fast-winding tree of the mesh before the cuts, the faces
#: near each probe summed exactly (repair.junk.WindingFromBase): 50 -> 0, D 1.2e-3 mm
#: (the lids lie within 2.5e-3 of the walls they replace), the hairline stage ~1.1 s CPU
#: (cut-and-lid with a finish per round took 27 s in round 6).
WINDING_KNOWN_FAILURES: set[str] = set()


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
    # So does how far the lids lie from the hairline walls they replace (repair.hairline_cut).
    lid = max(lid, report.get("hairline_gaps", {}).get("lid_deviation_mm", 0.0))
    if thickened:
        # A thickened face's prism lies within eps/2 of it; the eps-prisms along the edges
        # where two sheet faces bend reach eps/2 * sqrt(2) from that edge (a mitre).
        assert report["deviation"] <= max(EPS / np.sqrt(2) + 1e-6, lid)
    else:
        size = float(np.ptp(written.vertices, axis=0).max())
        assert report["deviation"] <= 1e-5 * size + 1e-6 + lid
