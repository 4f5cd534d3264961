"""Travel routing benchmark: CPU seconds of the embedded slicer with avoid_crossing_perimeters
on and off (same process, alternating runs, best of N), and what the routing changed: travel
moves, travels routed around a gap, retractions.

Run: .venv/bin/python bench/bench_travel.py [--repeat N]
Models: a 200k-triangle torus, a U-shaped bracket, and the corpus bunny (repaired, 80 mm)
when ../shared/corpus is there.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CORPUS = ROOT.parent / "shared" / "corpus"


def _models():
    import trimesh
    from manifold3d import CrossSection, Manifold

    t = trimesh.creation.torus(30.0, 8.0, major_sections=400, minor_sections=250)
    yield "torus 200k", t.vertices, t.faces
    u = np.array([[0, 0], [40, 0], [40, 40], [28, 40], [28, 12], [12, 12], [12, 40], [0, 40]],
                 float)
    mesh = Manifold.extrude(CrossSection([u]), 20.0).to_mesh()
    yield "U bracket", mesh.vert_properties[:, :3], mesh.tri_verts
    bunny = CORPUS / "mikedh_bunny.ply"
    if bunny.is_file():
        from repair.io import load_mesh
        from repair.pipeline import repair_mesh

        m = load_mesh(bunny)
        r = repair_mesh(m.vertices, m.faces, epsilon=0.4)
        yield "bunny 80 mm", r.vertices * (80 / np.ptp(r.vertices, axis=0).max()), r.faces


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    from slicer.engine import slice_mesh
    from slicer.profile import Profile

    base = Profile.for_printer().with_overrides({"thumbnails": ""})
    retract = re.compile(rf"^G1 E-{base.retract_length:.5f} ", re.MULTILINE)
    print(f"{'model':<13}{'off cpu s':>10}{'on cpu s':>10}{'ratio':>7}{'travels':>9}"
          f"{'extra legs':>11}{'retracts off/on':>17}")
    for name, v, f in _models():
        best = {False: float("inf"), True: float("inf")}
        text = {}
        for _ in range(args.repeat):
            for avoid in (False, True):
                t = time.process_time()
                res = slice_mesh(v, f, base.with_overrides({"avoid_crossing_perimeters": avoid}))
                best[avoid] = min(best[avoid], time.process_time() - t)
                text[avoid] = res.gcode
        travels = text[True].count("\nG0 ")
        routed = travels - text[False].count("\nG0 ")
        r_off, r_on = len(retract.findall(text[False])), len(retract.findall(text[True]))
        print(f"{name:<13}{best[False]:>10.2f}{best[True]:>10.2f}"
              f"{best[True] / best[False]:>7.2f}{travels:>9}{routed:>11}{r_off:>9}/{r_on}")


if __name__ == "__main__":
    main()
