"""The long fuzz run over every fuzz area: ``tests/fuzz/targets_*.py``, all their TARGETS.

    python bench/fuzz.py                       # every target, 20000 examples each
    python bench/fuzz.py --area mesh --seconds 60
    python bench/fuzz.py --target mesh-3mf --examples 5000

Each target runs in its own child process (its peak memory is its own, and a crash or a
kill of one target does not end the run) and is driven by hypothesis, not derandomized,
through ``harness.check_one``: the same property as the bounded CI run, with a budget
100x larger. Guidance: every input's score is the number of distinct product lines it
executed, passed to ``hypothesis.target``, so hypothesis's targeting phase steers
towards inputs that reach deeper into the readers (hypothesis has no coverage-feedback
mode of its own any more; atheris has one but no aarch64 wheel, so the printer's own
board could not run it).

Coverage is line coverage of the target's ``modules``, measured with coverage.py for
the import and with a line tracer (only inside the product's own frames) for the fuzz
inputs; coverage.py's analysis supplies the executable lines. Branch coverage is left
out: the tracer would have to reproduce coverage.py's arc rules.

Every failure is recorded (the shrunk input and the error) and the run goes on: the
budget is spent in batches of fresh hypothesis runs, so a failure ends only its batch.
The table at the end: target, executions, failures, coverage per module, peak RSS
(flagged above 1 GB). Exit status 1 if anything failed or went over the memory limit.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import resource
import subprocess
import sys
import time
import traceback
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
FUZZ_DIR = REPO / "tests" / "fuzz"
MEMORY_FLAG_MB = 1024
#: Examples per hypothesis run; the budget is spent in such batches.
BATCH = 2000


# --------------------------------------------------------------------------- parent


def discover(area: str | None) -> list[tuple[str, str]]:
    """(module name, target name) for every target of every ``targets_<area>.py``."""
    sys.path[:0] = [str(FUZZ_DIR), str(REPO)]
    found = []
    for path in sorted(FUZZ_DIR.glob("targets_*.py")):
        if area and path.stem != f"targets_{area}":
            continue
        try:
            module = importlib.import_module(path.stem)
        except Exception as exc:  # noqa: BLE001 - one broken area must not stop the others
            print(f"skipping {path.name}: {type(exc).__name__}: {exc}", file=sys.stderr)
            continue
        found += [(path.stem, target.name) for target in module.TARGETS]
    return found


def run_child(module: str, target: str, args: argparse.Namespace) -> dict[str, Any]:
    """Fuzz one target in a child process; its JSON summary (or the way it died)."""
    cmd = [sys.executable, __file__, "--child", module, target, "--examples",
           str(args.examples)]
    if args.seconds:
        cmd += ["--seconds", str(args.seconds)]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    started = time.monotonic()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if res.returncode == 0 and lines:
        summary = json.loads(lines[-1])
    else:
        tail = (res.stderr.strip().splitlines() or ["(no output)"])[-1]
        summary = {"target": target, "executions": 0, "coverage": {}, "missing": {},
                   "peak_rss_mb": 0,
                   "failures": [{"error": f"child exited with {res.returncode}: {tail}",
                                 "input": ""}]}
    summary["seconds"] = time.monotonic() - started
    return summary


def print_table(results: list[dict[str, Any]], show_missing: bool) -> None:
    print()
    print(f"{'target':<24} {'execs':>8} {'fail':>5} {'secs':>6} {'RSS MB':>8}  coverage")
    for r in results:
        flag = " !" if r["peak_rss_mb"] > MEMORY_FLAG_MB else ""
        cover = ", ".join(f"{mod.rsplit('.', 1)[-1]} {pct:.0f}%"
                          for mod, pct in r["coverage"].items())
        print(f"{r['target']:<24} {r['executions']:>8} {len(r['failures']):>5} "
              f"{r['seconds']:>6.0f} {r['peak_rss_mb']:>6.0f}{flag:<2}  {cover}")
    for r in results if show_missing else []:
        for module, lines in r["missing"].items():
            print(f"{r['target']}: {module} lines not reached: {lines or '-'}")
    for r in results:
        for failure in r["failures"]:
            print(f"\nFAILURE in {r['target']}: {failure['error']}\n  input: {failure['input']}")


def parent_main(args: argparse.Namespace) -> int:
    targets = discover(args.area)
    if args.target:
        targets = [(m, t) for m, t in targets if t in args.target]
    if not targets:
        print("no fuzz targets matched", file=sys.stderr)
        return 2
    results = []
    for module, target in targets:
        print(f"fuzzing {target} ({module}) ...", flush=True)
        results.append(run_child(module, target, args))
        r = results[-1]
        print(f"  {r['executions']} executions, {len(r['failures'])} failures, "
              f"{r['seconds']:.0f} s", flush=True)
    print_table(results, args.show_missing)
    bad = any(r["failures"] or r["peak_rss_mb"] > MEMORY_FLAG_MB for r in results)
    return 1 if bad else 0


# --------------------------------------------------------------------------- child


class LineTracer:
    """Records (file, line) executed in the product files, only while ``active``; the
    lines of the current input are kept apart for the hypothesis score."""

    def __init__(self, files: set[str]) -> None:
        self.files = files
        self.all_lines: dict[str, set[int]] = {f: set() for f in files}
        self.current: set[tuple[str, int]] = set()

    def _global(self, frame, event, arg):  # noqa: ARG002 - sys.settrace signature
        if frame.f_code.co_filename in self.files:
            return self._local
        return None

    def _local(self, frame, event, arg):  # noqa: ARG002
        if event == "line":
            self.current.add((frame.f_code.co_filename, frame.f_lineno))
        return self._local

    def run(self, function, value) -> object:
        self.current = set()
        sys.settrace(self._global)
        try:
            return function(value)
        finally:
            sys.settrace(None)
            for filename, line in self.current:
                self.all_lines[filename].add(line)


def module_files(modules: tuple[str, ...]) -> dict[str, str]:
    files = {}
    for name in modules:
        spec = importlib.util.find_spec(name)
        if spec and spec.origin:
            files[name] = str(Path(spec.origin).resolve())
    return files


def fuzz_target(target, tracer: LineTracer, args: argparse.Namespace) -> tuple[int, list]:
    """Spend the budget on ``target`` in batches; (executions, failures)."""
    from harness import check_one
    from hypothesis import HealthCheck, Phase, given, settings, strategies
    from hypothesis import target as hypothesis_target

    executions = 0
    failures: dict[tuple[str, str], dict[str, str]] = {}
    traced = type(target)(target.name, target.strategy,
                          lambda value: tracer.run(target.run, value),
                          target.expected, target.modules)
    end = time.monotonic() + args.seconds if args.seconds else None
    done = 0
    while done < args.examples and (end is None or time.monotonic() < end):
        batch = min(BATCH, args.examples - done)

        @settings(max_examples=batch, deadline=None, database=None, derandomize=False,
                  report_multiple_bugs=True, phases=list(Phase),
                  suppress_health_check=list(HealthCheck))
        @given(strategies.data())
        def one(data):
            nonlocal executions
            if end is not None and time.monotonic() > end:
                return  # out of time: finish the batch without drawing anything
            value = data.draw(target.strategy)
            executions += 1
            try:
                check_one(traced, value)
            except BaseException as exc:
                where = traceback.extract_tb(exc.__traceback__)[-1]
                key = (type(exc).__name__, f"{where.filename}:{where.lineno}")
                failures[key] = {"error": f"{type(exc).__name__}: {exc} (at {key[1]})"[:600],
                                 "input": repr(value)[:2000]}  # the last one is the shrunk one
                raise
            hypothesis_target(float(len(tracer.current)), label="lines executed")

        try:
            one()
        except BaseException as exc:  # noqa: BLE001 - recorded above; the run goes on
            if isinstance(exc, KeyboardInterrupt):
                raise
        done += batch
    return executions, list(failures.values())


def child_main(module_name: str, target_name: str, args: argparse.Namespace) -> int:
    import coverage

    sys.path[:0] = [str(FUZZ_DIR), str(REPO)]
    cov = coverage.Coverage(data_file=None, include=[str(REPO / "*")])
    cov.start()  # module-level lines run at import: measured by coverage.py itself
    module = importlib.import_module(module_name)
    cov.stop()
    target = next(t for t in module.TARGETS if t.name == target_name)
    files = module_files(target.modules)
    tracer = LineTracer(set(files.values()))
    executions, failures = fuzz_target(target, tracer, args)
    data = cov.get_data()
    data.add_lines({f: lines for f, lines in tracer.all_lines.items() if lines})
    percent, missed = {}, {}
    for name, filename in files.items():
        _, statements, _, missing, missing_text = cov.analysis2(filename)
        percent[name] = 100.0 * (len(statements) - len(missing)) / max(len(statements), 1)
        missed[name] = missing_text
    rss_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"target": target_name, "executions": executions, "failures": failures,
                      "coverage": percent, "missing": missed, "peak_rss_mb": rss_kb / 1024}))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=20000,
                        help="examples per target (default 20000)")
    parser.add_argument("--seconds", type=float, default=0,
                        help="stop each target after this many seconds")
    parser.add_argument("--area", help="only tests/fuzz/targets_<AREA>.py")
    parser.add_argument("--target", action="append", help="only this target (repeatable)")
    parser.add_argument("--show-missing", action="store_true",
                        help="list the product lines each target never reached")
    parser.add_argument("--child", nargs=2, metavar=("MODULE", "TARGET"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        return child_main(*args.child, args)
    return parent_main(args)


if __name__ == "__main__":
    sys.exit(main())
