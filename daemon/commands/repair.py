"""``preflight repair``: any mesh file in, a printable binary STL out (Attene's AEAP repair)."""

from __future__ import annotations

import json
import os
import sys
import time

from daemon.commands import fail

#: Inputs above this many bytes get a progress line on a terminal.
_PROGRESS_BYTES = 2_000_000


def register(subparsers) -> None:
    """Add the ``repair`` sub-command."""
    p = subparsers.add_parser(
        "repair",
        help="make a mesh printable, as exactly as possible",
        description="Repair a mesh (STL, OBJ, PLY, 3MF; STEP with the cad extra) into a "
        "closed, edge-manifold, self-intersection-free solid. Solid parts are kept exactly; "
        "zero-thickness sheets are thickened and wires inflated by EPSILON (the nozzle "
        "diameter). A STEP is tessellated within min(0.01, EPSILON/40) mm of its surfaces.",
    )
    p.add_argument("input", metavar="IN", help="mesh file to repair")
    p.add_argument("-o", "--output", metavar="OUT.stl", required=True,
                   help="binary STL to write")  # fmt: skip
    p.add_argument("--epsilon", type=float, metavar="MM", default=0.4,
                   help="thickness for sheets and wires, in mm (default 0.4)")  # fmt: skip
    p.add_argument("--clean", choices=("auto", "scan", "none"), default="auto",
                   help="scan cleanup (spikes, specks, ragged holes): auto when the model "
                   "looks like a scan (default), scan always, none never")  # fmt: skip
    p.add_argument("--surface", choices=("off", "holes", "all"), default=None,
                   help="refine curved features to the design surface, chordal error within "
                   "min(0.01, EPSILON/40) mm: holes = cylinders and cones, all = also "
                   "spheres and tori, off = never (default: [repair] surface's default, "
                   "holes, as the daemon)")  # fmt: skip
    p.add_argument("--time-budget", type=float, metavar="S", default=None,
                   help="seconds the exact repair may take before the fallback approximation "
                   "replaces it (reported with its deviation D); 0: no budget (default: "
                   "[repair] time_budget's default)")  # fmt: skip
    p.add_argument("--report", metavar="R.json", help="write the repair report as JSON")
    p.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    # Output and report are written (the STL synced) when run returns, and the forked
    # workers have exited: the interpreter's teardown, freeing every module and the
    # mesh's arrays one by one (~0.08 s of CPU after a 500k-triangle repair), is skipped.
    p.set_defaults(func=run, quick_exit=True)


class _ProgressLine:
    """One self-overwriting status line on stderr."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.shown = False

    def __call__(self, stage: str, fraction: float) -> None:
        dt = time.perf_counter() - self.t0
        sys.stderr.write(f"\rpreflight: repair {fraction * 100:3.0f}% {stage:<18} {dt:6.1f}s")
        sys.stderr.flush()
        self.shown = True

    def done(self) -> None:
        if self.shown:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _time_budget(given: float | None) -> float:
    """The exact repair's budget in seconds: as given, else the config schema's default."""
    if given is not None:
        return given
    from daemon.config import RepairConfig

    return RepairConfig().time_budget


def _surface(given: str | None) -> str:
    """The surface refinement: as given, else the config schema's default (what the
    daemon does unless configured; the library's own default is "off")."""
    if given is not None:
        return given
    from daemon.config import RepairConfig

    return RepairConfig().surface


def run(args) -> int:
    """Run the repair; 0 on a printable result, 1 with a one-line reason otherwise."""
    if not (args.epsilon > 0):
        return fail(f"--epsilon must be a positive number of mm, got {args.epsilon}")
    budget = _time_budget(args.time_budget)
    if budget is not None and not (budget >= 0):
        return fail(f"--time-budget must be 0 or a positive number of seconds, got {budget}")
    if not os.path.isfile(args.input):
        return fail(f"{args.input}: no such file")
    try:
        big = os.path.getsize(args.input) >= _PROGRESS_BYTES
    except OSError as exc:
        return fail(f"{args.input}: {exc.strerror or exc}")
    line = _ProgressLine() if big and sys.stderr.isatty() else None

    from repair.files import RepairError, repair_file
    from repair.io import MeshReadError

    try:
        report = repair_file(args.input, args.output, epsilon=args.epsilon,
                             report_path=args.report, progress=line,
                             clean=args.clean, surface=_surface(args.surface),
                             time_budget=budget or None)  # fmt: skip
    except (MeshReadError, RepairError) as exc:
        if line:
            line.done()
        return fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    except OSError as exc:
        if line:
            line.done()
        return fail(f"{exc.filename or args.output}: {exc.strerror or exc}")
    except MemoryError:
        if line:
            line.done()
        return fail("out of memory while repairing the model")
    if line:
        line.done()
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{args.output}: {report['summary']}")
    return 0
