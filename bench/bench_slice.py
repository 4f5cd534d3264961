"""Slicing benchmark: time and peak memory of the embedded slicer, side by side with
prusa-slicer / CuraEngine when installed, on a 20 mm cube, an 82k-triangle sphere
(trimesh icosphere, subdivisions=6, 40 mm), a 100k-triangle torus, and two models that need
support: a mushroom (a 50 mm cap on a 16 mm stem) and the corpus bunny (repaired, 62 mm,
tipped 20° forward so its chin overhangs). Every slicer runs with the default profile, so
support is on where needed (PrusaSlicer: automatic support, the same angle, gaps, spacing
and interface layers); "support cm3" is the filament under ``;TYPE:Support material*``.

Run: .venv/bin/python bench/bench_slice.py [--repeat N] [--only mushroom,bunny]

The embedded slicer runs twice per round: "embedded" on the machine's cores (profile
``workers = auto``: forked workers write the layers; "procs" says how many processes did)
and "emb-1proc" on one process (``workers = 1``); the G-code is the same. "floor" is what
no slice can avoid, measured in the same rounds: the interpreter importing numpy and
manifold3d (``python -c "import numpy, manifold3d"``, same environment), so the share of
a small model's time that is start-up shows.

Every slice is a whole process, as a user runs it: the embedded slicer is ``preflight slice
IN -o OUT --json`` (python -m daemon.cli: interpreter start-up, imports, load, slice,
thumbnails, write), PrusaSlicer/CuraEngine their own binaries. The slicers' runs are
interleaved (embedded, prusa, cura, embedded, ...) so a load change on a shared machine
hits them alike; each figure is the median of the repeats, and "emb/prusa" gives the
per-pair ratios of runs made back to back (median, and the range). "wall s" is the child's
elapsed time, "cpu s" its user+system CPU (resource.getrusage(RUSAGE_CHILDREN) before and
after; PrusaSlicer's threads are included), "slice s" (embedded only) the CLI's own time
after its imports. Peak memory is the child's ru_maxrss (from os.wait4: the largest of the
slicer process and the workers it reaped), so the figures include the interpreter and
imported libraries; "wkr MB" is the largest worker's own (from the slice's summary).
"main cpu" is the CPU of the slicer's main process alone, exit included (cpu s less the
``child_cpu_seconds`` of ``--json``: its layer workers and thumbnail child): on an
idle machine with a core per process its wall time is about that, since the workers'
shares are sized to end with the main process's own; on a busy shared machine the wall
times say little and this is the figure to compare with "emb-1proc"'s cpu. Linux counts
the parent's resident memory at fork into a child's ru_maxrss, so this parent stays
small: mesh generation and G-code parsing run in helper children too. Volume accuracy:
the sphere sliced at 100 % infill, extruded filament volume ÷ mesh volume.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: The embedded slicer as benchmarked: on the machine's cores ("auto"), and on one process.
EMBEDDED_TOOLS = {"embedded": {}, "emb-1proc": {"workers": "1"}}


def make_models(folder: Path) -> dict[str, tuple[Path, float, int]]:
    """Write the three STL files (in a helper child, to keep this process small)."""
    _, _, code_, out, err, _ = run_child([sys.executable, __file__, "--make-models", str(folder)])
    if code_ != 0:
        raise SystemExit(f"cannot build the models: {err.strip()}")
    data = json.loads(out.strip().splitlines()[-1])
    return {k: (Path(v[0]), float(v[1]), int(v[2])) for k, v in data.items()}


def _make_models(folder: Path) -> dict[str, tuple[Path, float, int]]:
    import trimesh

    models = {
        "cube 20 mm": trimesh.creation.box((20, 20, 20)),
        "sphere 82k": trimesh.creation.icosphere(subdivisions=6, radius=20.0),
        "torus 100k": trimesh.creation.torus(major_radius=30.0, minor_radius=10.0,
                                             major_sections=250, minor_sections=200),
    }
    models.update(_support_models())
    out = {}
    for name, mesh in models.items():
        path = folder / (name.split()[0] + ".stl")
        mesh.export(path)
        out[name] = (path, float(mesh.volume), len(mesh.faces))
    return out


def _support_models() -> dict:
    """The mushroom and, when the corpus is there, the repaired bunny tipped forward."""
    import math

    import numpy as np
    import trimesh
    from manifold3d import Manifold

    mush = Manifold.cylinder(30, 8, 8, 64) + Manifold.cylinder(8, 25, 25, 192).translate(
        [0, 0, 30])
    mesh = mush.to_mesh()
    out = {"mushroom": trimesh.Trimesh(mesh.vert_properties[:, :3], mesh.tri_verts)}
    bunny = ROOT.parent / "shared" / "corpus" / "mikedh_bunny.ply"
    if bunny.is_file():
        from repair.pipeline import repair_mesh

        scan = trimesh.load(bunny)
        v = (np.asarray(scan.vertices) * 400.0)[:, [0, 2, 1]] * [1.0, -1.0, 1.0]
        tip = trimesh.transformations.rotation_matrix(math.radians(-20), [0, 1, 0])[:3, :3]
        fixed = repair_mesh(v @ tip.T, np.asarray(scan.faces))
        out["bunny chin"] = trimesh.Trimesh(fixed.vertices, fixed.faces)
    return out


def support_cm3(gcode: Path, filament_diameter: float) -> float:
    """Filament (cm³) extruded under PrusaSlicer-style ``;TYPE:Support material*`` labels."""
    import math

    from printer.gcode import lex

    total, in_support, absolute, last_e = 0.0, False, False, 0.0
    with open(gcode, errors="replace") as fh:
        for raw in fh:
            if raw.startswith(";TYPE:"):
                in_support = raw.startswith(";TYPE:Support material")
                continue
            line = lex(raw)
            if line.word in ("M82", "M83"):
                absolute = line.word == "M82"
            elif line.word == "G92":
                last_e = line.value("E", last_e)
            elif line.word in ("G0", "G1") and line.value("E") is not None:
                e = line.value("E")
                de = e - last_e if absolute else e
                last_e = e if absolute else last_e
                if in_support and de > 0 and (line.value("X") is not None
                                              or line.value("Y") is not None):
                    total += de
    return total * math.pi * (filament_diameter / 2) ** 2 / 1000.0


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_child(cmd: list[str], env: dict | None = None
              ) -> tuple[float, float, int, str, str, float]:
    """(wall seconds, peak RSS MB, exit code, stdout, stderr, CPU seconds) of one child."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        cpu0 = _children_cpu()
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        cpu = _children_cpu() - cpu0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return (wall, usage.ru_maxrss / 1024.0, proc.returncode,
                out.read().decode(errors="replace"), err.read().decode(errors="replace"), cpu)


def _installed_env() -> dict:
    """The environment for an embedded run, as an installed preflight runs: its modules'
    byte code cached (``pip install`` compiles it; PYTHONDONTWRITEBYTECODE, set in some shells
    and CI images, would make every run compile ~40 modules from source, ~40 ms of CPU)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return env | {"PYTHONPATH": str(ROOT)}


def embedded(stl: Path, gcode: Path, overrides: dict) -> dict:
    """``preflight slice`` as a whole process (the console script's module, this venv)."""
    sets = [arg for k, v in overrides.items() for arg in ("--set", f"{k}={v}")]
    wall, mb, code, out, err, cpu = run_child(
        [sys.executable, "-m", "daemon.cli", "slice", str(stl), "-o", str(gcode), "--json",
         *sets], env=_installed_env())
    if code != 0:
        return {"error": err.strip().splitlines()[-1] if err.strip() else f"exit {code}"}
    summary = json.loads(out)
    return {"slice_s": summary["wall_seconds"], "wall_s": wall, "cpu_s": cpu, "peak_mb": mb,
            "main_cpu_s": cpu - summary.get("child_cpu_seconds",
                                            summary.get("worker_cpu_seconds", 0.0)),
            "summary": summary}


def floor() -> dict:
    """The start-up no slice can avoid: this interpreter importing numpy and manifold3d, as
    a whole process in the same environment as ``embedded``'s."""
    wall, mb, code, _, err, cpu = run_child([sys.executable, "-c", "import numpy, manifold3d"],
                                            env=_installed_env())
    if code != 0:
        return {"error": err.strip().splitlines()[-1] if err.strip() else f"exit {code}"}
    return {"wall_s": wall, "cpu_s": cpu, "peak_mb": mb}


def external(name: str, stl: Path, gcode: Path, overrides: dict, summarise: bool = True
             ) -> dict:
    from slicer import adapters
    from slicer.profile import Profile

    profile = Profile.for_printer().with_overrides(overrides)
    exe = adapters.find_binary(name)
    if name == "cura":
        defs = adapters.cura_definitions()
        cmd = adapters.cura_command(profile, stl, gcode, exe, defs)
        env = dict(os.environ, CURA_ENGINE_SEARCH_PATH=str(defs))
    else:
        cmd = [exe, "--export-gcode", *adapters.prusa_args(profile), "--output", str(gcode),
               str(stl)]
        env = dict(os.environ)
    wall, mb, code, out, err, cpu = run_child(cmd, env=env)
    if code != 0 or not gcode.exists():
        return {"error": adapters._error_line(err + out, name, code)}
    if not summarise:
        return {"slice_s": None, "wall_s": wall, "cpu_s": cpu, "peak_mb": mb, "summary": None}
    summary = _summary_in_child(gcode, overrides)
    if name == "cura":
        summary["estimated_seconds"] = adapters.cura_print_time(err)
    return {"slice_s": None, "wall_s": wall, "cpu_s": cpu, "peak_mb": mb, "summary": summary}


def _summary_in_child(gcode: Path, overrides: dict) -> dict:
    code = ("import json, sys; from pathlib import Path; from slicer.adapters import "
            "gcode_summary; from slicer.profile import Profile; p = Profile.for_printer()"
            ".with_overrides(json.loads(sys.argv[2])); print(json.dumps(gcode_summary("
            "Path(sys.argv[1]).read_text(errors='replace'), p) | {'support_cm3': "
            "__import__('bench_slice').support_cm3(Path(sys.argv[1]), p.filament_diameter)}))")
    _, _, rc, out, err, _ = run_child([sys.executable, "-c", code, str(gcode),
                                      json.dumps(overrides)],
                                   env=dict(os.environ, PYTHONPATH=f"{ROOT}:{ROOT / 'bench'}"))
    if rc != 0:
        raise SystemExit(f"cannot read {gcode}: {err.strip()}")
    return json.loads(out.strip().splitlines()[-1])


def clip_comparison() -> str:
    """Infill clipping on the 82k sphere's 200 layers, 45° lines at bead spacing: the
    slicer's numpy scanline clip against manifold3d booleans with thin rectangles."""
    import math

    import numpy as np
    import trimesh
    from manifold3d import CrossSection, Manifold, Mesh

    from slicer.geometry import contours, hatch

    mesh = trimesh.creation.icosphere(subdivisions=6, radius=20.0)
    man = Manifold(Mesh(vert_properties=mesh.vertices.astype(np.float32),
                        tri_verts=mesh.faces.astype(np.uint32)))
    sections = [man.slice(float(z)).simplify(0.0125) for z in np.arange(-19.9, 20.0, 0.2)]
    polys = [contours(c) for c in sections]
    sp = 0.407
    t0 = time.perf_counter()
    n_np = sum(len(hatch(p, 45.0, sp)) for p in polys)
    t_np = time.perf_counter() - t0
    ys = np.arange(math.ceil(-30 / sp), math.floor(30 / sp) + 1) * sp
    t0 = time.perf_counter()
    n_mf = 0
    for c in sections:
        rects = [np.array([[-30, y - 1e-3], [30, y - 1e-3], [30, y + 1e-3], [-30, y + 1e-3]])
                 for y in ys]
        n_mf += len((c ^ CrossSection(rects).rotate(45.0)).to_polygons())
    t_mf = time.perf_counter() - t0
    return (f"numpy scanlines {t_np * 1000:.1f} ms ({n_np} segments), manifold3d thin-rectangle "
            f"booleans {t_mf * 1000:.1f} ms ({n_mf} pieces, still to be turned into lines): "
            f"numpy {t_mf / t_np:.0f}x faster")


def timed_runs(models: dict, tools: list[str], repeat: int, folder: Path
               ) -> dict[tuple[str, str], list[dict]]:
    """``repeat`` rounds per model, the slicers interleaved within each round; the G-code
    of each slicer's first run is summarised (layers, filament, support)."""
    runs: dict[tuple[str, str], list[dict]] = {}
    for mname, (stl, _vol, _tris) in models.items():
        for r in range(repeat):
            for tool in tools:
                gcode = folder / f"{stl.stem}.{tool}.gcode"
                done = runs.setdefault((mname, tool), [])
                if done and "error" in done[0]:
                    continue
                if tool == "floor":
                    done.append(floor())
                elif tool in EMBEDDED_TOOLS:
                    done.append(embedded(stl, gcode, EMBEDDED_TOOLS[tool]))
                else:
                    done.append(external(tool, stl, gcode, {}, summarise=r == 0))
    return runs


def _median(runs: list[dict], key: str) -> float:
    values = [r[key] for r in runs if r.get(key) is not None]
    return statistics.median(values) if values else float("nan")


def print_table(models: dict, tools: list[str], runs: dict) -> None:
    print(f"{'model':12s} {'tris':>7s} {'slicer':9s} {'slice s':>8s} {'wall s':>8s} "
          f"{'cpu s':>7s} {'main cpu':>8s} {'peak MB':>8s} {'procs':>5s} {'wkr MB':>6s} "
          f"{'layers':>6s} "
          f"{'filament m':>10s} {'est. min':>8s} {'support cm3':>11s}")
    for mname, (_stl, _vol, tris) in models.items():
        for tool in tools:
            rs = runs[(mname, tool)]
            if "error" in rs[0]:
                print(f"{mname:12s} {tris:7d} {tool:9s} error: {rs[0]['error']}")
                continue
            if tool == "floor":
                print(f"{mname:12s} {tris:7d} {tool:9s} {'':8s} {_median(rs, 'wall_s'):8.3f} "
                      f"{_median(rs, 'cpu_s'):7.3f} {'':8s} {max(r['peak_mb'] for r in rs):8.1f}"
                      "  (python -c 'import numpy, manifold3d')")
                continue
            s = rs[0]["summary"]
            est = s.get("estimated_seconds")
            print(f"{mname:12s} {tris:7d} {tool:9s} {_median(rs, 'slice_s'):8.3f} "
                  f"{_median(rs, 'wall_s'):8.3f} {_median(rs, 'cpu_s'):7.3f} "
                  f"{_median(rs, 'main_cpu_s'):8.3f} "
                  f"{max(r['peak_mb'] for r in rs):8.1f} {s.get('workers', 0):5d} "
                  f"{s.get('worker_peak_mb', 0.0):6.1f} {s['layers']:6d} "
                  f"{s['filament_mm'] / 1000:10.3f} {(est / 60 if est else float('nan')):8.1f} "
                  f"{s.get('support_cm3', float('nan')):11.2f}")


def print_ratios(models: dict, runs: dict) -> None:
    """Per back-to-back pair, wall and CPU: embedded ÷ PrusaSlicer, and embedded on the
    machine's cores ÷ on one process."""
    pairs = (("embedded", "prusa", "embedded ÷ prusa-slicer (target ≤ 0.5)"),
             ("emb-1proc", "prusa", "embedded on one process ÷ prusa-slicer"),
             ("embedded", "emb-1proc", "embedded on the cores ÷ on one process"),
             ("floor", "prusa", "start-up floor (numpy + manifold3d imports) ÷ prusa-slicer"))
    print("whole processes, per interleaved pair: median, range (each pair)")
    for mine, theirs, title in pairs:
        shown = False
        for mname in models:
            emb, ext = runs.get((mname, mine)), runs.get((mname, theirs))
            if not emb or not ext or "error" in emb[0] or "error" in ext[0]:
                continue
            if not shown:
                print(f" {title}:")
                shown = True
            for key, label in (("wall_s", "wall"), ("cpu_s", "cpu")):
                ratios = sorted(e[key] / x[key] for e, x in zip(emb, ext, strict=False))
                print(f"  {mname:12s} {label:4s} median {statistics.median(ratios):5.2f}  "
                      f"range {ratios[0]:.2f}-{ratios[-1]:.2f}  "
                      f"({' '.join(f'{r:.2f}' for r in ratios)})")
            if theirs == "prusa" and mine != "floor":
                print(f"  {mname:12s} peak {max(e['peak_mb'] for e in emb):.0f} MB (largest "
                      f"process) vs {max(x['peak_mb'] for x in ext):.0f} MB")


def print_accuracy(models: dict, tools: list[str], folder: Path) -> None:
    print("volume accuracy, sphere at 100 % infill (extruded ÷ mesh volume):")
    stl, vol, _ = models["sphere 82k"]
    over = {"infill_percent": 100, "skirts": 0}
    for tool in [t for t in tools if t != "floor"]:
        gcode = folder / f"acc.{tool}.gcode"
        r = embedded(stl, gcode, over | EMBEDDED_TOOLS[tool]) if tool in EMBEDDED_TOOLS \
            else external(tool, stl, gcode, over)
        if "error" in r:
            print(f"  {tool:9s} error: {r['error']}")
            continue
        print(f"  {tool:9s} {r['summary']['filament_cm3'] * 1000 / vol:6.3f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5,
                    help="interleaved rounds per model (default 5); medians are shown")
    ap.add_argument("--only", metavar="NAMES",
                    help="comma-separated model name prefixes to run (e.g. mushroom,bunny)")
    ap.add_argument("--make-models", metavar="DIR", help=argparse.SUPPRESS)  # helper child
    args = ap.parse_args()
    if args.make_models:
        made = _make_models(Path(args.make_models))
        print(json.dumps({k: [str(v[0]), v[1], v[2]] for k, v in made.items()}))
        return 0
    from slicer import adapters

    have = adapters.available()
    tools = ["embedded", "emb-1proc", "floor"] + [t for t in ("prusa", "cura") if have[t]]
    missing = [t for t in ("prusa", "cura") if not have[t]]
    print(f"slicers: {', '.join(tools)}"
          + (f" (not installed: {', '.join(missing)})" if missing else ""))
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs, repeat {args.repeat}, "
          f"load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        models = make_models(folder)
        if args.only:
            wanted = tuple(w.strip() for w in args.only.split(",") if w.strip())
            models = {k: v for k, v in models.items() if k.startswith(wanted)}
        print()
        runs = timed_runs(models, tools, max(1, args.repeat), folder)
        print_table(models, tools, runs)
        print()
        print_ratios(models, runs)
        print(f"(load average after the runs {os.getloadavg()[0]:.1f})")
        if "sphere 82k" in models:
            print()
            print_accuracy(models, tools, folder)
    if not args.only or "sphere".startswith(tuple(args.only.split(","))):
        print()
        print("infill clipping, sphere 82k, 200 layers (in this process, after the runs above):")
        print("  " + clip_comparison())
    return 0


if __name__ == "__main__":
    sys.exit(main())
