"""STEP input benchmark (needs the cad extra): what reading a STEP costs against reading the
same triangles from a binary STL, at the deflections of common nozzles, and what loading
Open CASCADE costs once per process.

For each nozzle: the chordal deflection min(0.01, nozzle/40), the plate's triangle count,
the largest sagitta of a hole or boss facet against the design circle (mm), the time of
``load_mesh`` on the STEP (best of ``--repeat``) and on the STL of that same tessellation
(the reference, in the same process), and their ratio. Then, in fresh interpreters, the
time and peak memory (RSS) of importing the kernel, against importing numpy alone.

Usage: .venv/bin/python bench/bench_step.py [--repeat N]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from importlib.util import find_spec
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "repair"))

NOZZLES = (0.6, 0.4, 0.25, 0.15)
IMPORT_PROBE = ("import resource, sys, time; t = time.perf_counter(); {imports}; "
                "print(time.perf_counter() - t, "
                "resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)")


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def import_cost(imports: str) -> tuple[float, float]:
    """(seconds, peak RSS MB) of a fresh interpreter running ``imports``."""
    out = subprocess.run([sys.executable, "-c", IMPORT_PROBE.format(imports=imports)],
                         capture_output=True, text=True, check=True, cwd=ROOT).stdout.split()
    return float(out[0]), float(out[1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    if find_spec("OCP") is None:
        print("bench_step: the cad extra is not installed: pip install 'preflight[cad]'",
              file=sys.stderr)
        return 1
    # fresh interpreters first: a child forked after this process loaded the kernel would
    # inherit its peak RSS
    t_np, rss_np = import_cost("import numpy")
    kernel = ("import numpy; from OCP.STEPControl import STEPControl_Reader; "
              "from OCP.BRepMesh import BRepMesh_IncrementalMesh")
    t_ocp, rss_ocp = import_cost(kernel)
    kernel_line = (f"kernel import: {t_ocp:.2f} s, peak RSS {rss_ocp:.0f} MB (numpy alone: "
                   f"{t_np:.2f} s, {rss_np:.0f} MB; the kernel adds {rss_ocp - rss_np:.0f} MB)")
    from plate_model import BOSS_CENTRE, BOSS_RADIUS, HOLES
    from step_helpers import facet_sagitta, write_plate_step

    from repair.io import load_mesh, write_stl
    from repair.io.step import chordal_deflection

    circles = [tuple(h) for h in HOLES] + [(*BOSS_CENTRE, BOSS_RADIUS)]
    with tempfile.TemporaryDirectory() as tmp:
        step = write_plate_step(Path(tmp) / "plate.step")
        stl = Path(tmp) / "plate.stl"
        print("nozzle  deflection  triangles  max sagitta   STEP read   STL read  ratio")
        for nozzle in NOZZLES:
            d = chordal_deflection(nozzle)
            mesh = load_mesh(step, deflection=d)
            write_stl(stl, mesh.vertices, mesh.faces)
            sag = max(facet_sagitta(mesh.vertices, mesh.faces, *c)[0].max() for c in circles)
            t_step = best_time(lambda d=d: load_mesh(step, deflection=d), args.repeat)
            t_stl = best_time(lambda: load_mesh(stl), args.repeat)
            print(f"{nozzle:6.2f}  {d:8.5f}mm  {mesh.triangles:9d}  {sag:9.6f}mm  "
                  f"{t_step * 1e3:8.1f}ms  {t_stl * 1e3:7.2f}ms  {t_step / t_stl:5.1f}x")
    print(kernel_line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
