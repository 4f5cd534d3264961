"""Soak test: the real daemon and the virtual printer through N jobs with random faults.

Drives ``preflight run`` (a subprocess) and ``preflight virtual-printer`` (its own
process, so that killing the daemon leaves the printer and its log of executed
commands alone) through ``--jobs`` dropped files: good and broken small meshes,
G-code, garbage, empty and truncated files, some written slowly. Faults, drawn with
``--seed`` at rate ``--faults`` per dropped file:

- ``kill -9`` of the daemon during intake, repair, slicing or printing, then a restart;
- unplugs: the printer process killed mid-print (its pty vanishes), replugged later;
- printers that reset after N lines, corrupt bytes on the line, or lose ``ok``s.

The last ``--calm-share`` of the files runs without daemon kills (the printer faults go
on), so that one daemon life is long enough to show whether its memory stays flat.

Then it checks that every dropped file ended exactly once as done, failed (with a
reason in its report) or interrupted; that no G-code line ran twice within a print
and every done print ran its whole file once; that no print was re-sent without a
requeue; and that the daemon's memory stayed flat. It prints the figures and exits 1
if a check failed (2 if the run stalled or could not finish in ``--max-minutes``).

Usage: .venv/bin/python bench/soak.py [--jobs 1000] [--seed 1] [--faults 0.1] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import random
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from soak_checks import FINAL, Findings, account_files, check_prints  # noqa: E402
from soak_faults import FaultPlan  # noqa: E402
from soak_files import make_drop, write_drop  # noqa: E402
from soak_memory import memory_figures  # noqa: E402
from soak_procs import PREFLIGHT, Processes, env_ok, write_config  # noqa: E402

from daemon.journal import Journal  # noqa: E402


class Soak:
    """One soak run in ``run`` (spool, state, logs), driven by ``args``."""

    def __init__(self, args: argparse.Namespace, run: Path) -> None:
        self.args = args
        self.run = run
        self.rng = random.Random(args.seed)
        self.spool = run / "spool"
        self.spool.mkdir(parents=True, exist_ok=True)
        self.config = write_config(run, run / "tty")
        self.procs = Processes(run, self.config, run / "tty", run / "executed.log")
        self.plan = FaultPlan(self.procs, self.rng, args.faults)
        self.dropped: dict[str, dict] = {}
        self.writers: list[threading.Thread] = []
        self.problems: list[str] = []
        self.started = time.monotonic()

    # -- the journal, read directly (cheap enough to poll every 0.2 s) ----------------------
    def states(self) -> dict[str, str]:
        path = self.run / "state" / "journal.sqlite"
        if not path.exists():
            return {}
        try:
            db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5)
            try:
                rows = db.execute("SELECT source_name, state FROM jobs ORDER BY id").fetchall()
            finally:
                db.close()
        except sqlite3.Error:
            return {}
        return {name: state for name, state in rows}

    # -- dropping files -------------------------------------------------------------------
    def drop_next(self) -> str:
        index = len(self.dropped) + 1
        drop = make_drop(index, self.rng, self.run / "tmp.stl")
        slow = drop.data and self.rng.random() < self.args.slow
        self.dropped[drop.name] = {"kind": drop.kind, "expect": drop.expect, "slow": bool(slow)}
        if slow:
            chunks, seconds = self.rng.randrange(3, 7), self.rng.uniform(1.0, 2.0)
            writer = threading.Thread(target=write_drop, args=(self.spool, drop),
                                      kwargs={"chunks": chunks, "seconds": seconds}, daemon=True)
            writer.start()
            self.writers.append(writer)
            self.plan.count("slow_write")
        else:
            write_drop(self.spool, drop)
        return drop.name

    def writing(self) -> int:
        self.writers = [w for w in self.writers if w.is_alive()]
        return len(self.writers)

    # -- the main loop --------------------------------------------------------------------
    def loop(self) -> bool:
        """Drop files and inject faults until every file ended; False on timeout."""
        deadline = self.started + 60 * self.args.max_minutes
        next_sample = next_progress = 0.0
        last_ended, last_change = -1, time.monotonic()
        while True:
            now = time.monotonic()
            states = self.states()
            ended = sum(1 for n in self.dropped if states.get(n) in FINAL)
            if len(self.dropped) == self.args.jobs and ended == len(self.dropped):
                return True
            if ended != last_ended:
                last_ended, last_change = ended, now
            if now - last_change > 60 * self.args.stall_minutes:
                busy = {n: s for n, s in states.items() if s not in FINAL}
                self.problems.append(f"stalled: no file ended for {self.args.stall_minutes:g} "
                                     f"min; unfinished: {busy}")
                return False
            if now > deadline:
                return False
            self.keep_daemon_up()
            active = len(self.dropped) - ended
            if len(self.dropped) < self.args.jobs and active < self.args.backlog:
                name = self.drop_next()
                calm = len(self.dropped) > self.args.jobs * (1.0 - self.args.calm_share)
                self.plan.after_drop(name, calm=calm)
            self.plan.tick(states)
            if now >= next_sample:
                next_sample = now + 2.0
                self.procs.sample_rss()
            if now >= next_progress:
                next_progress = now + self.args.progress
                self.progress(states, ended)
            time.sleep(0.1)

    def keep_daemon_up(self) -> None:
        """A daemon that exited without being killed is a finding; restart it anyway."""
        procs = self.procs
        if procs.daemon is not None and procs.daemon.poll() is not None:
            self.problems.append(f"the daemon exited by itself (status "
                                 f"{procs.daemon.returncode}); see {self.run}/daemon.log")
            procs.daemon = None
        if procs.daemon is None and not self.plan.daemon_down_on_purpose():
            procs.start_daemon()

    def progress(self, states: dict[str, str], ended: int) -> None:
        counts: dict[str, int] = {}
        for name in self.dropped:
            state = states.get(name, "waiting")
            counts[state] = counts.get(state, 0) + 1
        rss = self.procs.samples[-1].kb / 1024 if self.procs.samples else 0.0
        minutes = (time.monotonic() - self.started) / 60
        print(f"[{minutes:6.1f} min] dropped {len(self.dropped)}/{self.args.jobs}, ended "
              f"{ended} ({', '.join(f'{v} {k}' for k, v in sorted(counts.items()))}); "
              f"faults {sum(self.plan.injected.values())}; daemon RSS {rss:.1f} MB; "
              f"restarts {self.procs.lives - 1}", flush=True)

    # -- the end --------------------------------------------------------------------------
    def finish(self, complete: bool) -> Findings:
        """Stop everything, then run the checks on what is left on disk."""
        for writer in self.writers:
            writer.join(timeout=10)
        found = Findings(problems=list(self.problems))
        jobs = jobs_list(self.config)
        status = self.procs.stop_all()
        if status not in (0, None):
            found.add(f"the daemon exited with status {status} on SIGTERM")
        if not complete:
            found.add("the soak did not finish (stalled or over --max-minutes)")
        (self.run / "dropped.json").write_text(json.dumps(self.dropped, indent=1))
        check_run(self.run, self.dropped, jobs, found)
        self.figures(found, jobs)
        with open(self.run / "rss.csv", "w") as fh:
            fh.write("seconds,daemon_start,age_seconds,rss_kb\n")
            fh.writelines(f"{x.at:.1f},{x.life},{x.age:.1f},{x.kb}\n"
                          for x in self.procs.samples)
        return found

    def figures(self, found: Findings, jobs: list[dict]) -> None:
        wall = time.monotonic() - self.started
        outcomes: dict[str, int] = {}
        for job in jobs:
            outcomes[job["state"]] = outcomes.get(job["state"], 0) + 1
        found.figures.update(
            jobs=len(self.dropped), outcomes=outcomes, faults=dict(sorted(
                self.plan.injected.items())), missed_faults=dict(sorted(
                    self.plan.missed.items())), daemon_starts=self.procs.lives,
            wall_seconds=round(wall, 1),
            jobs_per_minute=round(60 * len(self.dropped) / wall, 2) if wall else 0.0,
            memory=memory_figures(self.procs.samples, warmup=self.args.warmup))
        if found.figures["memory"].get("flat") is False:
            found.add(f"the daemon's memory grew: {found.figures['memory']}")


def jobs_list(config: Path) -> list[dict]:
    """The jobs as a person sees them: ``preflight jobs list --all --json``."""
    out = subprocess.run([*PREFLIGHT, "jobs", "--config", str(config), "list", "--all",
                          "--json"], capture_output=True, text=True, cwd=ROOT, timeout=120)
    if out.returncode != 0:
        raise RuntimeError(f"preflight jobs list failed: {out.stderr.strip()}")
    return json.loads(out.stdout)


def check_run(run: Path, dropped: dict[str, dict], jobs: list[dict], found: Findings) -> None:
    """The checks on a finished run folder (the daemon and the printer stopped)."""
    journal = Journal(run / "state" / "journal.sqlite", readonly=True)
    histories = {job["id"]: journal.history(job["id"]) for job in jobs}
    journal.close()
    account_files(dropped, jobs, run / "spool", found)
    executed = (run / "executed.log").read_text(errors="replace").splitlines()
    check_prints(jobs, histories, executed, found)


def recheck(run: Path) -> int:
    """Run the checks again on a finished run folder (e.g. after changing a check)."""
    dropped = json.loads((run / "dropped.json").read_text())
    found = Findings()
    jobs = jobs_list(run / "preflight.toml")
    check_run(run, dropped, jobs, found)
    found.figures["jobs"] = len(dropped)
    report(found, run)
    return 1 if found.problems else 0


def report(found: Findings, run: Path) -> None:
    fig = found.figures
    print("\n=== soak result ===")
    print(f"jobs dropped: {fig.get('jobs')}; outcomes: {fig.get('outcomes', '-')}")
    print(f"lost: {fig.get('lost')}; processed twice: {fig.get('duplicated')}; "
          f"stray jobs: {fig.get('stray')}")
    print(f"print attempts: {fig.get('print_attempts')}; G-code lines executed: "
          f"{fig.get('lines_executed')}; interrupted by: {fig.get('interrupted_by')}")
    artefacts = fig.get("noise_artefacts") or []
    print(f"line-noise artefacts the firmware ran (Marlin protocol limits, not host "
          f"errors): {len(artefacts)}" + "".join(f"\n  {a}" for a in artefacts[:20]))
    if fig.get("foreign_segments"):
        print(f"lines another process sent to the printer's pty (not the daemon's): "
              f"{fig['foreign_segments']}")
    if "faults" in fig:  # figures of the run itself (not of a --recheck)
        print(f"faults injected: {fig.get('faults')}")
        if fig.get("missed_faults"):
            print(f"faults that found no moment to fire: {fig.get('missed_faults')}")
        print(f"daemon starts: {fig.get('daemon_starts')}")
        print(f"daemon RSS: {json.dumps(fig.get('memory'))}")
        print(f"wall time: {fig.get('wall_seconds')} s; {fig.get('jobs_per_minute')} jobs/min")
    print(f"run folder: {run}")
    if found.problems:
        print(f"\nFAILED: {len(found.problems)} problem(s):")
        for problem in found.problems[:50]:
            print(f"  - {problem}")
    else:
        print("\nall checks passed")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1000, help="files to drop (default 1000)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--faults", type=float, default=0.1,
                    help="probability per dropped file that a fault is injected (default 0.1)")
    ap.add_argument("--slow", type=float, default=0.1,
                    help="fraction of files written slowly in chunks (default 0.1)")
    ap.add_argument("--backlog", type=int, default=3,
                    help="files in the daemon's hands at once (default 3)")
    ap.add_argument("--max-minutes", type=float, default=180.0,
                    help="give up (and fail) after this long (default 180)")
    ap.add_argument("--stall-minutes", type=float, default=5.0,
                    help="give up (and fail) when no file ends for this long (default 5)")
    ap.add_argument("--calm-share", type=float, default=0.25,
                    help="the last share of the files is dropped without daemon kills, so "
                         "that one long daemon life shows its memory trend (default 0.25)")
    ap.add_argument("--warmup", type=float, default=60.0,
                    help="seconds after each daemon start left out of the memory trend")
    ap.add_argument("--progress", type=float, default=30.0, help="seconds between progress lines")
    ap.add_argument("--out", type=Path, help="run folder (default: a temporary one)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary run folder")
    ap.add_argument("--recheck", type=Path, metavar="DIR",
                    help="only run the checks again on the finished run folder DIR")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    env_ok()
    if args.recheck:
        return recheck(args.recheck)
    run = args.out or Path(tempfile.mkdtemp(prefix="preflight-soak-"))
    if args.out:
        if run.exists():
            shutil.rmtree(run)
        run.mkdir(parents=True)
    soak = Soak(args, run)
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    print(f"soak: {args.jobs} jobs, seed {args.seed}, fault rate {args.faults:g}, in {run}",
          flush=True)
    try:
        soak.procs.start_printer([], seed=args.seed)
        soak.procs.start_daemon()
        complete = soak.loop()
        found = soak.finish(complete)
    except KeyboardInterrupt:
        print("soak: interrupted; cleaning up", flush=True)
        return 130
    finally:
        soak.plan.cancel()
        soak.procs.stop_all()
    report(found, run)
    keep = args.out or args.keep or found.problems
    if not keep:
        shutil.rmtree(run, ignore_errors=True)
    if not complete:
        return 2
    return 1 if found.problems else 0


if __name__ == "__main__":
    sys.exit(main())
