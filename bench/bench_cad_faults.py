"""CAD fault sweep (issue 18): real CAD models of tests/data with the faults exporters
leave, one kind at a time or several at once; each must come out the intact solid,
printable as written (float32 STL, exact check on the file read back).

usage: .venv/bin/python bench/bench_cad_faults.py [--kinds single|combo|pairs]
           [--seeds N | --seeds A-B | --seeds 1,5,9] [--models part,step,...] [--jobs J]
           [--only KIND,...] [-v]
Defaults: single 6 seeds (0-5) x 8 kinds x 4 models = 192 cases; combo 30 seeds
(0-29, 3 kinds each drawn by combo_kinds(seed)) x 4 models = 120 cases; pairs: every
ordered pair of two kinds x 4 seeds (0-3) x 4 models = 896 cases (~30 s on 2 cores).
A case is flagged when the written file is not printable, the volume ratio (out / intact)
is outside [0.99, 1.01], D (the report's deviation) exceeds 0.05 mm plus the shift of a
body written twice where no faces were deleted (a hole's lid is new surface: D is the
lid's distance from the holed input, volume says whether it is right), or the repair raises.
Generators: tests/repair/cad_fault_models.py (the tests' own); the cases the sweep
once flagged are tests in tests/repair/test_cad_fault*.py. Prints figures; not a test.
"""

from __future__ import annotations

import argparse
import itertools
import resource
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.repair.cad_fault_models import (  # noqa: E402  (after the path is set)
    FAULTS,
    MODELS,
    combo_kinds,
    faulted,
    intact_volume,
    real_model,
    repaired_and_written,
)  # fmt: skip


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def _shift(v0: np.ndarray, kinds: list[str], v: np.ndarray) -> float:
    """Largest shift of a body written twice (dup_shell's offset, mm), else 0."""
    return 0.0 if "dup_shell" not in kinds else float(np.ptp(v0, axis=0).max()) * 1e-3


def run_case(case: tuple[str, int, tuple[str, ...] | None]) -> dict:
    model, seed, kinds = case
    name, scale = MODELS[model]
    v0, f0 = real_model(name, scale)
    if kinds is None:
        rng, kinds = combo_kinds(seed)
    else:
        rng, kinds = np.random.default_rng(seed), list(kinds)
    v, f = faulted(v0, f0, kinds, rng)
    expected = intact_volume(name, scale)
    row = {"model": model, "seed": seed, "kinds": "+".join(kinds), "vr": float("nan"),
           "D": float("nan"), "tris": 0, "cpu": 0.0, "verdict": "", "flag": True}
    t = _cpu()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            w, verdict, report = repaired_and_written(v, f, Path(tmp) / "out.stl")
    except Exception as e:  # noqa: BLE001
        row.update(cpu=_cpu() - t, verdict="ERR " + str(e).splitlines()[0][:60])
        return row
    row["cpu"] = _cpu() - t
    vr, d = verdict.volume / expected, float(report.get("deviation", float("nan")))
    bad = []
    if not verdict.ok:
        bad.append("NOT-PRINTABLE:" + ",".join(verdict.failures())[:40])
    if not 0.99 <= vr <= 1.01:
        bad.append("VR")
    if "holes" not in kinds and not d <= 0.05 + _shift(v0, kinds, v):
        bad.append("D")
    row.update(vr=vr, D=d, tris=len(w.faces), verdict=" ".join(bad) or "ok", flag=bool(bad))
    row["path"] = report.get("path", "")
    return row


def _seeds(text: str | None, default: int) -> list[int]:
    if not text:
        return list(range(default))
    if "," in text:
        return [int(s) for s in text.split(",")]
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return list(range(int(text)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--kinds", choices=["single", "combo", "pairs"], default="single")
    ap.add_argument("--seeds", default=None)
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--only", default=None, help="single: these fault kinds only")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("-v", action="store_true", help="print every case, not only flagged")
    a = ap.parse_args()
    models = a.models.split(",")
    if a.kinds == "single":
        kinds = a.only.split(",") if a.only else list(FAULTS)
        cases = [(m, s, (k,)) for m in models for k in kinds for s in _seeds(a.seeds, 6)]
    elif a.kinds == "pairs":
        two = list(itertools.permutations(FAULTS, 2))
        cases = [(m, s, k) for m in models for k in two for s in _seeds(a.seeds, 4)]
    else:
        cases = [(m, s, None) for m in models for s in _seeds(a.seeds, 30)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=a.jobs) as pool:
        rows = list(pool.map(run_case, cases, chunksize=1))
    print(f"{'model':9} {'seed':>4} {'kinds':32} {'vr':>8} {'D mm':>9} {'tris':>5} "
          f"{'CPU s':>6} verdict")
    for r in rows:
        if a.v or r["flag"]:
            print(f"{r['model']:9} {r['seed']:4d} {r['kinds']:32} {r['vr']:8.4f} {r['D']:9.2e} "
                  f"{r['tris']:5d} {r['cpu']:6.2f} {r['verdict']}")
    cpu = sum(r["cpu"] for r in rows)
    print(f"flagged {sum(r['flag'] for r in rows)} of {len(rows)} "
          f"(CPU {cpu:.1f} s, wall {time.perf_counter() - t0:.1f} s, jobs {a.jobs})")


if __name__ == "__main__":
    main()
