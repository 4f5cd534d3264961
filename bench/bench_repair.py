"""Repair benchmark: preflight's AEAP repair vs pymeshfix (MeshFix) vs trimesh's repair.

For every corpus file (../shared/corpus) and two generated large meshes (a clean closed
1M-triangle sphere; a ~200k-triangle mesh of overlapping shells with holes) prints
per-tool time, triangles/s, peak RSS growth and the printability verdict of the output
(repair.check.check_printable on float32 coordinates). Each tool run happens in a fresh
child process so that peak memory and crashes are per run.

    .venv/bin/python bench/bench_repair.py [--quick] [--only SUBSTR]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / ".." / "shared" / "corpus"
TOOLS = ("preflight", "pymeshfix", "trimesh")


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _sphere(n_tri: int):
    import trimesh

    sub = 0
    while 20 * 4**sub < n_tri:
        sub += 1
    m = trimesh.creation.icosphere(subdivisions=sub, radius=40.0)
    return m.vertices, m.faces


def _broken_200k():
    """Overlapping closed shells (spheres) plus one with a few holes: ~200k triangles."""
    import numpy as np
    import trimesh

    parts = []
    for k in range(3):
        s = trimesh.creation.icosphere(subdivisions=6, radius=20.0)  # 81920 tris
        s.apply_translation((k * 25.0, 0, 0))
        parts.append(s)
    m = trimesh.util.concatenate(parts)
    v, f = m.vertices, m.faces
    keep = np.ones(len(f), bool)
    keep[np.arange(0, len(f), 5000)] = False  # holes
    f = f[keep]
    return v, f[: 200_000]


def _load(spec: str):
    if spec == "gen:clean_1M":
        return _sphere(1_000_000)
    if spec == "gen:broken_200k":
        return _broken_200k()
    from repair.io import load_mesh

    m = load_mesh(spec)
    return m.vertices, m.faces


def _run_one(tool: str, spec: str, q) -> None:
    import numpy as np

    try:
        v, f = _load(spec)
        base = _peak_rss_mb()
        t0 = time.perf_counter()
        if tool == "preflight":
            from repair.pipeline import repair_mesh

            r = repair_mesh(v, f, 0.4)
            ov, of = r.vertices, r.faces
        elif tool == "pymeshfix":
            import pymeshfix

            ov, of = pymeshfix.clean_from_arrays(np.asarray(v, float), np.asarray(f, np.int32))
        else:
            import trimesh

            m = trimesh.Trimesh(v, f, process=True)
            trimesh.repair.fix_normals(m)
            trimesh.repair.fill_holes(m)
            ov, of = m.vertices, m.faces
        dt = time.perf_counter() - t0
        peak = _peak_rss_mb()
        from repair.check import check_printable

        ok = bool(len(of)) and check_printable(
            np.asarray(ov, float), np.asarray(of, np.int64), as_float32=True
        ).ok
        q.put({"tris": int(len(f)), "out": int(len(of)), "s": dt, "peak_mb": peak,
               "delta_mb": peak - base, "ok": ok})  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - report, do not die
        q.put({"error": f"{type(exc).__name__}: {str(exc).splitlines()[0][:60]}"})


def run(tool: str, spec: str, timeout: float) -> dict:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_run_one, args=(tool, spec, q))
    p.start()
    p.join(timeout)
    if p.is_alive():
        p.kill()
        p.join()
        return {"error": f"timeout {timeout:.0f}s"}
    if p.exitcode != 0 and q.empty():
        return {"error": f"crashed (exit {p.exitcode})"}
    return q.get() if not q.empty() else {"error": "no result"}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="corpus only, no large meshes")
    ap.add_argument("--only", default="", help="run only inputs containing this text")
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--json", metavar="FILE", help="also write all results as JSON")
    a = ap.parse_args()
    specs = []
    if CORPUS.is_dir():
        specs += [str(p) for p in sorted(CORPUS.iterdir())
                  if p.suffix.lower() in {".stl", ".obj", ".ply", ".3mf"}]  # fmt: skip
    if not a.quick:
        specs += ["gen:clean_1M", "gen:broken_200k"]
    specs = [s for s in specs if a.only in s]
    results: dict[str, dict[str, dict]] = {}
    hdr = f"{'input':36} {'tris':>8} " + " ".join(f"{t:>30}" for t in TOOLS)
    print(hdr)
    for spec in specs:
        name = Path(spec).name if not spec.startswith("gen:") else spec
        row = {t: run(t, spec, a.timeout) for t in TOOLS}
        results[name] = row
        tris = next((r["tris"] for r in row.values() if "tris" in r), 0)
        cells = []
        for t in TOOLS:
            r = row[t]
            if "error" in r:
                cells.append(f"{r['error'][:30]:>30}")
            else:
                rate = r["tris"] / max(r["s"], 1e-9)
                cells.append(f"{r['s']:6.2f}s {rate / 1e3:7.1f}k/s {r['peak_mb']:5.0f}MB "
                             f"{'OK ' if r['ok'] else 'BAD'}")  # fmt: skip
        print(f"{name[:36]:36} {tris:8d} " + " ".join(cells), flush=True)
    print()
    for t in TOOLS:
        ok = sum(1 for r in results.values() if r[t].get("ok"))
        rates = [r[t]["tris"] / r[t]["s"] for r in results.values()
                 if r[t].get("tris", 0) > 1000 and "s" in r[t]]  # fmt: skip
        med = statistics.median(rates) if rates else float("nan")
        print(f"{t:10} printable {ok}/{len(results)}; median {med / 1e3:.1f}k tri/s on inputs "
              f"> 1k triangles")  # fmt: skip
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
