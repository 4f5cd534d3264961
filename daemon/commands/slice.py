"""``preflight slice``: turn a closed mesh into G-code with the embedded slicer (or an adapter)."""

from __future__ import annotations

import argparse
import gc
import os
import resource
import sys
import time

from daemon.commands import fail


def register(subparsers) -> None:
    """Add the ``slice`` sub-command."""
    p = subparsers.add_parser(
        "slice",
        help="slice a closed mesh into G-code",
        description="Slice a closed (repaired) mesh into G-code. Settings come from the "
        "printer-derived defaults, then --profile FILE (TOML), then the flags below.",
    )
    p.add_argument("input", metavar="IN", help="mesh file (STL, OBJ, PLY, 3MF)")
    p.add_argument("-o", "--output", metavar="OUT.gcode", required=True, help="G-code to write")
    p.add_argument("--nozzle", type=float, metavar="MM", default=0.4,
                   help="nozzle diameter (default 0.4); line width and layer height follow it")
    p.add_argument("--layer-height", type=float, metavar="MM")
    p.add_argument("--infill", type=float, metavar="PERCENT")
    p.add_argument("--filament-diameter", type=float, metavar="MM", default=1.75)
    p.add_argument("--bed", metavar="X,Y,Z", help="build volume in mm (default 220,220,250)")
    p.add_argument("--profile", metavar="FILE", help="TOML profile with overrides")
    p.add_argument("--workers", metavar="N",
                   help='processes that write the layers: "auto" (default: the CPUs, one '
                   "for a small model) or 1..8; the G-code is the same either way")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="override any profile setting (repeatable)")
    p.add_argument("--slicer", choices=("embedded", "cura", "prusa"), default="embedded",
                   help="slicing engine (cura/prusa need CuraEngine/prusa-slicer installed)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run, quick_exit=True)


def _parse_bed(text: str) -> tuple[float, float, float]:
    parts = [x for x in text.replace("x", ",").split(",") if x.strip()]
    vals = tuple(float(x) for x in parts)
    if len(vals) != 3 or min(vals) <= 0:
        raise ValueError(text)
    return vals  # type: ignore[return-value]


def build_profile(args: argparse.Namespace):
    """Printer-derived defaults, then the TOML profile, then explicit flags."""
    from slicer.profile import Profile, load_profile

    bed = _parse_bed(args.bed) if args.bed else None
    profile = Profile.for_printer(nozzle_diameter=args.nozzle, build_volume=bed,
                                  filament_diameter=args.filament_diameter)
    if args.profile:
        profile = load_profile(args.profile, profile)
    over: dict[str, object] = {}
    if args.layer_height is not None:
        over["layer_height"] = args.layer_height
        # a thin first layer is kept (adhesion); a thicker layer height raises it too
        over["first_layer_height"] = max(args.layer_height, profile.first_layer_height)
    if args.infill is not None:
        over["infill_percent"] = args.infill
    if getattr(args, "workers", None) is not None:
        over["workers"] = args.workers
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        over[key.strip()] = value
    if bed is not None:
        over["build_volume"] = bed
    return profile.with_overrides(over)


def _load(path: str, nozzle: float):
    try:
        from repair.io import load_mesh
        from repair.io.base import STEP_SUFFIXES
    except ImportError:  # repair area not present: fall back to trimesh
        import trimesh

        m = trimesh.load(path, force="mesh")
        return m.vertices, m.faces
    deflection = None
    if os.path.splitext(path)[1].lower() in STEP_SUFFIXES:  # a STEP's tessellation
        from repair.io.step import chordal_deflection

        deflection = chordal_deflection(nozzle)
    mesh = load_mesh(path, deflection=deflection)
    return mesh.vertices, mesh.faces


def run(args: argparse.Namespace) -> int:
    """Slice ``args.input`` into ``args.output``; one-line error and exit 1 on failure."""
    # importing numpy, manifold3d and the slicer set off ~40 garbage collections that free
    # nothing (~15 ms of CPU, a tenth of a small model's start-up): none until the slicing,
    # whose own cycles are collected as usual (_collect_from_here)
    gc.disable()
    try:
        return _run(args)
    finally:
        gc.enable()


def _collect_from_here() -> None:
    """Garbage collection back on, for objects made from now on only: those that exist (the
    imported modules', kept to the end anyway) are frozen out of it, else the first
    collections would walk them all and cost what disabling it during the imports saved."""
    gc.freeze()
    gc.enable()


def _run(args: argparse.Namespace) -> int:
    # the slicer's matrix products are small: OpenBLAS's worker threads only burn CPU on
    # them (3x the CPU of one thread on a busy machine). Read when numpy loads, so here.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from pathlib import Path

    from slicer.errors import SliceError
    from slicer.profile import ProfileError

    try:
        profile = build_profile(args)
    except ProfileError as exc:
        return fail(str(exc))
    except ValueError as exc:
        return fail(f"bad setting: {exc}")
    except OSError as exc:
        return fail(f"cannot read profile: {exc}")

    src = Path(args.input)
    if not src.is_file():
        return fail(f"no such file: {src}")
    tty = sys.stderr.isatty()
    last = [0.0]

    def progress(stage: str, fraction: float) -> None:
        now = time.monotonic()
        if tty and (now - last[0] > 0.2 or fraction >= 1.0):
            last[0] = now
            print(f"\rslicing {src.name}: {stage} {fraction * 100:3.0f}%", end="",
                  file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    try:
        if args.slicer == "embedded":
            from slicer.engine import slice_mesh, write_gcode

            vertices, faces = _load(str(src), profile.nozzle_diameter)
            _collect_from_here()
            result = slice_mesh(vertices, faces, profile, progress=progress)
            write_gcode(args.output, result.gcode)
            summary = dict(result.summary)
        else:
            from slicer.adapters import slice_external

            _collect_from_here()
            summary = slice_external(args.slicer, src, args.output, profile, progress=progress)
    except (SliceError, ValueError) as exc:  # MeshReadError is a ValueError
        if tty:
            print(file=sys.stderr)
        return fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    except OSError as exc:
        if tty:
            print(file=sys.stderr)
        return fail(f"{exc.strerror or exc}: {exc.filename or args.output}")
    if tty:
        print(file=sys.stderr)
    summary["output"] = str(args.output)
    summary["wall_seconds"] = round(time.perf_counter() - t0, 3)
    own = resource.getrusage(resource.RUSAGE_SELF)  # this process alone, start-up included
    forked = resource.getrusage(resource.RUSAGE_CHILDREN)  # its workers, thumbnail child
    summary["main_cpu_seconds"] = round(own.ru_utime + own.ru_stime, 3)
    summary["child_cpu_seconds"] = round(forked.ru_utime + forked.ru_stime, 3)
    if args.json:
        import json  # here: only --json pays for its import

        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        est = summary.get("estimated_seconds") or 0
        print(f"{args.output}: {summary.get('layers', '?')} layers, "
              f"{summary.get('filament_mm', 0) / 1000:.2f} m filament "
              f"({summary.get('filament_g', 0):.1f} g), estimated "
              f"{int(est // 3600)}h{int(est % 3600 // 60):02d}m"
              + (f", support {summary['support_cm3']:.2f} cm3 "
                 f"({summary.get('support_seconds', 0) / 60:.0f} min)"
                 if summary.get("support_cm3") else "")
              + (", brim" if summary.get("brim") else ""))
    return 0
