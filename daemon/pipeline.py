"""The job pipeline: intake from the spool, repair and slicing (in child processes),
and archiving the outcome into ``done/`` or ``failed/``.

Never lose a file: a file is moved (``rename``, same file system) into its job's
work folder inside the same journal transaction that records the job, and a work
folder that no job owns (the daemon died between the two) is given back to the
spool at start-up (:meth:`Spool.recover_orphans`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from daemon.config import Config
from daemon.events import AnyEvent
from daemon.journal import Job, Journal
from daemon.pins import BadSidecar, find_sidecar, folder_nozzle, is_sidecar, read_sidecar
from daemon.report import report_paths, write_reports
from daemon.safety import (
    ACCEPTED_SUFFIXES,
    GCODE_SUFFIXES,
    UnsafeEntry,
    check_gcode,
    check_spool_entry,
    display_name,
    safe_output_path,
    sanitise_name,
)
from daemon.states import JobState
from daemon.worker import WorkerCancelled, WorkerFailed, run_task

log = logging.getLogger("preflight.pipeline")


def epsilon_from(info: dict[str, Any], cfg: Config) -> tuple[float, str]:
    """ε (mm) and where it came from: the printer's nozzle, else the configured fallback."""
    nozzle = info.get("nozzle_diameter") if info else None
    source = (info or {}).get("nozzle_source") or ""
    if isinstance(nozzle, (int, float)) and nozzle > 0:
        if source == "config":
            return float(nozzle), ("the configured nozzle, [printer] nozzle_diameter (the "
                                   "printer does not report its nozzle)")
        if source == "default":
            return float(nozzle), "the default nozzle (the printer does not report its nozzle)"
        return float(nozzle), f"the printer's nozzle, reported by {source or 'the printer'}"
    return cfg.printer.nozzle_diameter, "[printer] nozzle_diameter in the config (fallback)"


def flavour_from(info: dict[str, Any]) -> str:
    """The G-code flavour the slicer writes for the printer ``info`` describes."""
    from printer.firmware import slicer_flavour_for_firmware

    return slicer_flavour_for_firmware(str((info or {}).get("firmware") or ""))



def repair_budget(cfg: Config) -> float | None:
    """The exact repair's time budget (s) for a job, or None: ``[repair] time_budget``,
    but at most half of ``[limits] repair_timeout``, so that the fallback has the other
    half (a job whose fallback cannot finish either fails with the timeout's reason)."""
    budget = cfg.repair.time_budget
    return min(budget, 0.5 * cfg.limits.repair_timeout) if budget > 0 else None


def slice_overrides(cfg: Config) -> dict[str, Any]:
    """The profile overrides a job is sliced with: ``[profile]`` over the daemon's own
    defaults (orient if-needed: turn a model only when that avoids support entirely); with
    several jobs at once, ``workers = auto`` becomes this job's share of the CPUs."""
    overrides = {"orient": "if-needed", **cfg.profile}
    if cfg.daemon.workers > 1 and str(overrides.get("workers", "auto")) == "auto":
        from slicer.parallel import available_cpus

        share = available_cpus() // cfg.daemon.workers
        if share < available_cpus():
            overrides["workers"] = str(max(1, share))
    return overrides


def _take(model: Path, dest: Path, sidecar: Path | None, work: Path) -> None:
    """Move a dropped model (and its sidecar, if any) into its work folder."""
    os.rename(model, dest)
    if sidecar is not None:
        _move_quietly(sidecar, work / SIDECAR_NAME)


def _move_quietly(source: Path, dest: Path) -> None:
    """Move a sidecar; one that vanished meanwhile is no loss (its model is taken)."""
    try:
        os.rename(source, dest)
    except OSError as e:
        log.warning("could not move %s: %s", source.name, e)


#: A job's sidecar in its work folder.
SIDECAR_NAME = "sidecar.toml"


class Spool:
    """File moves between the spool, the work folders, ``done/`` and ``failed/``."""

    def __init__(self, cfg: Config, journal: Journal) -> None:
        self.cfg = cfg
        self.journal = journal
        self.root = cfg.spool.path
        for folder in (self.root, cfg.done_dir, cfg.failed_dir, cfg.work_dir):
            folder.mkdir(parents=True, exist_ok=True)

    # -- intake ---------------------------------------------------------------------------
    def intake(self, path: Path, print_requested: bool | None = None) -> int | None:
        """Take one complete spool entry: a queued job, or a failed one with the reason.

        ``print_requested``: whether the job prints when ready; ``None`` means
        ``[daemon] auto_print``. An upload passes its uploader's choice, so that it is
        recorded in the same transaction as the job and a crash cannot change it.
        Returns the job id, or None if the entry vanished.
        """
        name = path.name
        folder_pin = folder_nozzle(self.root, path.parent) if path.parent != self.root else None
        if is_sidecar(path):
            return None  # a sidecar: taken with its model, never a job by itself
        try:
            entry = check_spool_entry(self.root if folder_pin is None else path.parent, path)
        except FileNotFoundError:
            return None
        except UnsafeEntry as e:
            return self._refuse(path, str(e))
        suffix = Path(name).suffix.lower()
        if suffix not in ACCEPTED_SUFFIXES:
            return self._refuse(path, f"refused: {name} is not a model or G-code file (accepted: "
                                      f"{' '.join(sorted(ACCEPTED_SUFFIXES))})")
        limit = self.cfg.limits.max_file_mb * 1024 * 1024
        if entry.st_size > limit:
            return self._refuse(path, f"refused: {name} is {entry.st_size / 1048576:.1f} MB, "
                                      "over the "
                                      f"limit of {self.cfg.limits.max_file_mb:g} MB "
                                      "([limits] max_file_mb)")
        if entry.st_size == 0:
            return self._refuse(path, f"refused: {name} is empty")
        sidecar = find_sidecar(path)
        try:
            nozzle = read_sidecar(sidecar) if sidecar else folder_pin
        except BadSidecar as e:
            assert sidecar is not None
            job_id = self._refuse(path, f"refused: {e}")
            _move_quietly(sidecar, safe_output_path(self.cfg.failed_dir, sidecar.name, job_id))
            return job_id
        safe = sanitise_name(name)
        work = self.cfg.work_dir / uuid.uuid4().hex
        work.mkdir(parents=True)
        dest = work / safe
        kind = "gcode" if suffix in GCODE_SUFFIXES else "mesh"
        try:
            job_id = self.journal.add_job(
                name=safe, source_name=name, kind=kind, work_dir=str(work), input_path=str(dest),
                print_requested=(self.cfg.daemon.auto_print if print_requested is None
                                 else print_requested),
                note="taken from the spool" + (f", pinned to a {nozzle:g} mm nozzle"
                                               if nozzle else ""),
                nozzle=nozzle, while_recording=lambda: _take(path, dest, sidecar, work))
        except FileNotFoundError:
            shutil.rmtree(work, ignore_errors=True)
            return None
        log.info("job %d: took %s (%s)", job_id, name, kind)
        return job_id

    def _refuse(self, path: Path, reason: str) -> int:
        """Record a failed job for an entry refused at the door, move it to failed/."""
        safe = sanitise_name(path.name)
        dest = safe_output_path(self.cfg.failed_dir, safe, 0)
        job_id = self.journal.add_job(name=safe, source_name=display_name(path.name),
                                      kind="refused", work_dir="", input_path="",
                                      state=JobState.FAILED, reason=reason)
        if dest.name != safe:
            dest = safe_output_path(self.cfg.failed_dir, safe, job_id)
        try:
            os.rename(path, dest)  # a symlink is moved as a link, never followed
            outputs = {"input": str(dest)}
        except OSError as e:
            log.warning("job %d: could not move %s to failed/: %s", job_id, path.name, e)
            outputs = {}
        self.journal.update(job_id, outputs=outputs)
        self._write_reports(job_id, self.cfg.failed_dir, Path(dest.name).stem)
        log.warning("job %d: %s", job_id, reason)
        return job_id

    def recover_orphans(self) -> list[str]:
        """Work folders no job owns (the daemon died mid-intake): give files back to the spool."""
        owned = {Path(d).name for d in self.journal.work_dirs()}
        given_back = []
        for folder in self.cfg.work_dir.iterdir():
            if not folder.is_dir() or folder.name in owned:
                continue
            for entry in folder.iterdir():
                if entry.is_file() and not entry.name.endswith((".json", ".log")):
                    target = safe_output_path(self.root, entry.name, 0)
                    os.rename(entry, target)
                    given_back.append(target.name)
            shutil.rmtree(folder, ignore_errors=True)
        return given_back

    # -- outcome --------------------------------------------------------------------------
    def _write_reports(self, job_id: int, folder: Path, stem: str) -> None:
        """Write the job's reports, listing their own paths, then record those paths: a
        job whose outputs name its reports has them complete on disk (written once, so no
        half-written temporary file sits in the folder after that)."""
        job = self.journal.get(job_id)
        assert job is not None
        json_path, text_path = report_paths(folder, stem)
        outputs = dict(job.outputs or {})
        outputs.update(report_json=str(json_path), report_txt=str(text_path))
        write_reports(folder, stem, dataclasses.replace(job, outputs=outputs),
                      self.journal.history(job_id))
        self.journal.update(job_id, outputs=outputs)

    def archive(self, job_id: int) -> None:
        """Move a finished job's files to done/ (done) or failed/ (failed, cancelled)
        and write its reports. Interrupted jobs keep their work folder (for a requeue)
        and only get reports in failed/."""
        job = self.journal.get(job_id)
        assert job is not None
        folder = self.cfg.done_dir if job.state == JobState.DONE else self.cfg.failed_dir
        stem = Path(job.name).stem
        outputs = dict(job.outputs or {})
        if job.state != JobState.INTERRUPTED and job.work_dir and Path(job.work_dir).is_dir():
            moves = [("input", job.input_path, job.name)]
            if job.kind == "mesh":
                moves += [("repaired", job.repaired_path, f"{stem}.repaired.stl"),
                          ("gcode", job.gcode_path, f"{stem}.gcode")]
            moves.append(("sidecar", str(Path(job.work_dir) / SIDECAR_NAME), f"{stem}.toml"))
            for key, source, name in moves:
                if source and Path(source).is_file():
                    dest = safe_output_path(folder, name, job.id)
                    os.rename(source, dest)
                    outputs[key] = str(dest)
            shutil.rmtree(job.work_dir, ignore_errors=True)
        # the report stem follows the archived input's name, unique per job
        archived_input = outputs.get("input")
        if archived_input:
            stem = Path(archived_input).stem
        elif (folder / f"{stem}.report.json").exists():
            stem = f"{stem}-{job.id}"
        self.journal.update(job_id, outputs=outputs)
        self._write_reports(job_id, folder, stem)

    def drop_reports(self, job: Job) -> None:
        """Delete a job's reports (it is redone) and forget their paths."""
        outputs = dict(job.outputs or {})
        for key in ("report_json", "report_txt"):
            report = outputs.pop(key, None)
            if report:
                Path(report).unlink(missing_ok=True)
        self.journal.update(job.id, outputs=outputs)

    def restore_input(self, job: Job) -> tuple[str, str]:
        """For a requeue of a failed/cancelled job: bring its input back into a work folder."""
        archived = (job.outputs or {}).get("input")
        if (job.kind == "refused" or not archived or not Path(archived).is_file()
                or Path(archived).is_symlink()):
            raise ValueError(f"job {job.id} was refused at intake ({job.reason}); fix the file "
                             "and drop it into the spool again")
        work = self.cfg.work_dir / uuid.uuid4().hex
        work.mkdir(parents=True)
        dest = work / job.name
        os.rename(archived, dest)
        self.drop_reports(job)
        return str(work), str(dest)


class Processor:
    """Takes queued jobs and runs them to ``ready``: repair and slicing for meshes,
    checks for G-code. One instance per worker thread."""

    def __init__(self, cfg: Config, journal: Journal, spool: Spool, printer_info, *,
                 stop: threading.Event, claim_lock: threading.Lock, active: dict[int, Any],
                 router: Any = None):
        """``router``: the :class:`~daemon.printers.PrinterPool` that says which printer
        class (nozzle, build volume) each job is processed for; None: ``printer_info``."""
        self.cfg = cfg
        self.journal = journal
        self.spool = spool
        self.printer_info = printer_info    # callable() -> dict | None (last known info)
        self.stop = stop
        self.claim_lock = claim_lock
        self.active = active                # job id -> cancel Event (shared)
        self.router = router

    def next_job(self, have_printer: bool) -> tuple[Job, threading.Event] | None:
        """Claim the oldest queued job; without printer info only G-code (its command
        policy needs no printer; the build volume is checked again before printing)."""
        with self.claim_lock:
            for job in self.journal.jobs({JobState.QUEUED}):
                if job.id not in self.active and (have_printer or job.kind == "gcode"):
                    cancel = threading.Event()
                    self.active[job.id] = cancel
                    return job, cancel
        return None

    def run_forever(self) -> None:
        while not self.stop.is_set():
            try:
                info = self.printer_info()
                claimed = self.next_job(self.router.have_info() if self.router is not None
                                        else info is not None)
            except Exception:  # e.g. the journal locked for too long: log, pause, go on
                log.exception("worker")
                self.stop.wait(1.0)
                continue
            if claimed is None:
                self.stop.wait(0.3)
                continue
            job, cancel = claimed
            try:
                self.process(job, info, cancel)
            except Exception as e:  # one job must never take the daemon down
                log.exception("job %d: internal error", job.id)
                self._fail(job.id, f"internal error: {type(e).__name__}: {e}")
            finally:
                with self.claim_lock:
                    self.active.pop(job.id, None)

    # -- steps ----------------------------------------------------------------------------
    def _fail(self, job_id: int, reason: str) -> None:
        job = self.journal.get(job_id)
        if job is None or job.state not in (JobState.QUEUED, JobState.REPAIRING,
                                            JobState.SLICING, JobState.READY):
            return
        self.journal.transition(job_id, JobState.FAILED, note=reason, reason=reason,
                                progress=None)
        self.spool.archive(job_id)
        log.warning("job %d failed: %s", job_id, reason)

    def _stopped(self, job_id: int) -> None:
        """The child was stopped: cancelled by the user, or the daemon is shutting down."""
        if self.stop.is_set():
            self.journal.transition(job_id, JobState.QUEUED,
                                    note="daemon stopping; will be redone", progress=None)
        else:
            self.journal.transition(job_id, JobState.CANCELLED, note="cancelled",
                                    reason="cancelled by user", progress=None)
            self.spool.archive(job_id)

    def _progress(self, job_id: int) -> Callable[[str, float], None]:
        """A progress callback that records the job's progress at most twice a second."""
        last = [0.0]

        def record(stage: str, fraction: float) -> None:  # noqa: ARG001
            now = time.monotonic()
            if now - last[0] >= 0.5 or fraction >= 1.0:
                last[0] = now
                self.journal.update(job_id, progress=float(fraction))
        return record

    def _run_child(self, job: Job, task: str, spec: dict[str, Any], cancel: threading.Event,
                   failed: str) -> tuple[bool, Any]:
        """Run ``task`` for ``job`` in a child: (True, its result), or (False, None) once
        the job has been failed (``failed``: the reason's start) or stopped."""
        limits = self.cfg.limits
        timeout, memory_mb = {"repair": (limits.repair_timeout, limits.repair_memory_mb),
                              "slice": (limits.slice_timeout, limits.slice_memory_mb)}[task]
        try:
            return True, run_task(task, spec, work_dir=Path(job.work_dir or ""),
                                  timeout=timeout, memory_mb=memory_mb,
                                  progress=self._progress(job.id),
                                  cancel=AnyEvent(cancel, self.stop))
        except WorkerCancelled:
            self._stopped(job.id)
        except WorkerFailed as e:
            self._fail(job.id, f"{failed}: {e}")
        return False, None

    def process(self, job: Job, info: dict[str, Any] | None, cancel: threading.Event) -> None:
        if self.router is not None:
            routed, info = self._route(job, info, cancel)
            if not routed:
                return
        if job.kind == "gcode":
            self._check_gcode(job, info)
            return
        assert info is not None
        if job.attempts >= self.cfg.limits.max_attempts:
            self._fail(job.id, f"processing was interrupted {job.attempts} times (the daemon "
                               "stopped or died while working on it); giving up")
            return
        repaired = self._repair(job, info, cancel)
        if repaired is not None:
            self._slice(job, info, repaired, cancel)

    def _route(self, job: Job, info: dict[str, Any] | None,
               cancel: threading.Event) -> tuple[bool, dict[str, Any] | None]:
        """(True, the info of the printer class the job goes to), or (False, None) once
        the job has failed (it fits no printer), been cancelled, or the daemon stops.
        A G-code job not pinned to a nozzle goes to any printer: (True, ``info`` with
        one printer, else None: its build volume is checked by the printer taking it)."""
        from daemon.printers import NoPrinterFits

        size = None
        if job.kind == "mesh" and self.router.needs_size():
            try:
                out = run_task("measure", {
                    "in": job.input_path, "job_name": job.name,
                    "max_bytes": int(self.cfg.limits.max_file_mb * 1024 * 1024),
                    "max_triangles": self.cfg.limits.max_triangles,
                }, work_dir=Path(job.work_dir or ""), timeout=self.cfg.limits.repair_timeout,
                    memory_mb=self.cfg.limits.repair_memory_mb, cancel=AnyEvent(cancel, self.stop))
            except WorkerCancelled:
                if not self.stop.is_set():
                    self._stopped(job.id)
                return False, None
            except WorkerFailed as e:
                self._fail(job.id, f"cannot measure the model: {e}")
                return False, None
            size = tuple(out["size"]) if (out or {}).get("size") else None
        elif job.kind != "mesh" and not job.pinned:
            return True, None if self.router.needs_size() else info
        try:
            return True, self.router.route(job, size)
        except NoPrinterFits as e:
            self._fail(job.id, str(e))
            return False, None

    def _repair(self, job: Job, info: dict[str, Any], cancel: threading.Event) -> Path | None:
        """Repair the job's mesh; the repaired STL's path, or None if the job ended."""
        epsilon, epsilon_source = epsilon_from(info, self.cfg)
        work = Path(job.work_dir or "")
        self.journal.transition(job.id, JobState.REPAIRING, expect=JobState.QUEUED,
                                note=f"epsilon {epsilon:g} mm", attempts=job.attempts + 1,
                                nozzle=epsilon,
                                epsilon=epsilon, epsilon_source=epsilon_source,
                                printer_info=info, progress=0.0)
        repaired = work / "repaired.stl"
        ok, report = self._run_child(job, "repair", {
            "in": job.input_path, "out": str(repaired), "job_name": job.name,
            "report": str(work / "repair.report.json"), "epsilon": epsilon,
            "max_bytes": int(self.cfg.limits.max_file_mb * 1024 * 1024),
            "max_triangles": self.cfg.limits.max_triangles,
            "clean": self.cfg.repair.clean, "surface": self.cfg.repair.surface,
            "time_budget": repair_budget(self.cfg),
        }, cancel, "repair failed")
        if not ok:
            return None
        summary = (report or {}).get("summary", "repaired")
        self.journal.transition(job.id, JobState.SLICING, note=summary, repair_report=report,
                                repaired_path=str(repaired), progress=0.0)
        log.info("job %d: repaired (%s)", job.id, summary)
        return repaired

    def _slice(self, job: Job, info: dict[str, Any], repaired: Path,
               cancel: threading.Event) -> None:
        """Slice the repaired mesh and check the G-code; the job ends ready or failed."""
        gcode = Path(job.work_dir or "") / f"{Path(job.name).stem}.gcode"
        build_volume = info.get("build_volume")
        epsilon, _ = epsilon_from(info, self.cfg)
        ok, out = self._run_child(job, "slice", {
            "in": str(repaired), "out": str(gcode), "nozzle": epsilon, "job_name": job.name,
            "build_volume": list(build_volume) if build_volume else None,
            "filament_diameter": info.get("filament_diameter"),
            "flavour": flavour_from(info), "overrides": slice_overrides(self.cfg),
        }, cancel, "slicing failed")
        if not ok:
            return
        summary = (out or {}).get("summary") or {}
        try:
            with open(gcode, encoding="utf-8", errors="replace") as f:
                check_gcode(f, forbidden=self.cfg.safety.forbidden_gcodes,
                            allow_firmware=self.cfg.safety.allow_firmware_commands,
                            build_volume=None)
        except UnsafeEntry as e:
            self._fail(job.id, f"the sliced G-code was {e} (check the [profile] start/end G-code)")
            return
        self.journal.transition(job.id, JobState.READY, note="sliced", slice_summary=summary,
                                gcode_path=str(gcode), progress=None)
        log.info("job %d: sliced: %s", job.id, summary)

    def _check_gcode(self, job: Job, info: dict[str, Any] | None) -> None:
        build_volume = (info or {}).get("build_volume")
        try:
            with open(job.input_path or "", encoding="utf-8", errors="replace") as f:
                checked = check_gcode(f, forbidden=self.cfg.safety.forbidden_gcodes,
                                      allow_firmware=self.cfg.safety.allow_firmware_commands,
                                      build_volume=build_volume)
        except UnsafeEntry as e:
            self._fail(job.id, str(e))
            return
        except OSError as e:
            self._fail(job.id, f"cannot read the G-code: {e.strerror}")
            return
        if checked.lines == 0:
            self._fail(job.id, "the G-code file has no commands")
            return
        self.journal.transition(job.id, JobState.READY, expect=JobState.QUEUED,
                                note="G-code checked", gcode_path=job.input_path,
                                printer_info=info,
                                slice_summary={"gcode_check": checked.to_dict()})
