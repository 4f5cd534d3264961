"""The job pipeline: intake from the spool, repair and slicing (in child processes),
and archiving the outcome into ``done/`` or ``failed/``.

Never lose a file: a file is moved (``rename``, same file system) into its job's
work folder inside the same journal transaction that records the job, and a work
folder that no job owns (the daemon died between the two) is given back to the
spool at start-up (:meth:`Spool.recover_orphans`).
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import os
import shutil
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from daemon.config import Config
from daemon.journal import Job, Journal
from daemon.report import write_reports
from daemon.safety import (
    ACCEPTED_SUFFIXES,
    GCODE_SUFFIXES,
    UnsafeEntry,
    check_gcode,
    check_spool_entry,
    display_name,
    safe_output_path,
    sanitise_name,
    strip_gcode,
)
from daemon.states import JobState
from daemon.worker import WorkerCancelled, WorkerFailed, run_task

log = logging.getLogger("preflight.pipeline")
S = JobState


def epsilon_from(info: dict[str, Any], cfg: Config) -> tuple[float, str]:
    """ε (mm) and where it came from: the printer's nozzle, else the configured fallback."""
    nz = info.get("nozzle_diameter") if info else None
    src = (info or {}).get("nozzle_source") or ""
    if isinstance(nz, (int, float)) and nz > 0:
        if src == "config":
            return float(nz), ("the configured nozzle, [printer] nozzle_diameter (the printer "
                               "does not report its nozzle)")
        if src == "default":
            return float(nz), "the default nozzle (the printer does not report its nozzle)"
        return float(nz), f"the printer's nozzle, reported by {src or 'the printer'}"
    return cfg.printer.nozzle_diameter, "[printer] nozzle_diameter in the config (fallback)"


def flavour_from(info: dict[str, Any]) -> str:
    fw = str((info or {}).get("firmware") or "").lower()
    if "klipper" in fw:
        return "klipper"
    if "reprap" in fw or "rrf" in fw:
        return "reprapfirmware"
    return "marlin"


class Spool:
    """File moves between the spool, the work folders, ``done/`` and ``failed/``."""

    def __init__(self, cfg: Config, journal: Journal) -> None:
        self.cfg = cfg
        self.j = journal
        self.root = cfg.spool.path
        for d in (self.root, cfg.done_dir, cfg.failed_dir, cfg.work_dir):
            d.mkdir(parents=True, exist_ok=True)

    # -- intake ---------------------------------------------------------------------------
    def intake(self, path: Path) -> int | None:
        """Take one complete spool entry: a queued job, or a failed one with the reason.

        Returns the job id, or None if the entry vanished.
        """
        name = path.name
        try:
            st = check_spool_entry(self.root, path)
        except FileNotFoundError:
            return None
        except UnsafeEntry as e:
            return self._refuse(path, str(e))
        suffix = Path(name).suffix.lower()
        if suffix not in ACCEPTED_SUFFIXES:
            return self._refuse(path, f"refused: {name} is not a model or G-code file (accepted: "
                                      f"{' '.join(sorted(ACCEPTED_SUFFIXES))})")
        limit = self.cfg.limits.max_file_mb * 1024 * 1024
        if st.st_size > limit:
            return self._refuse(path, f"refused: {name} is {st.st_size / 1048576:.1f} MB, over the "
                                      f"limit of {self.cfg.limits.max_file_mb:g} MB "
                                      "([limits] max_file_mb)")
        if st.st_size == 0:
            return self._refuse(path, f"refused: {name} is empty")
        safe = sanitise_name(name)
        work = self.cfg.work_dir / uuid.uuid4().hex
        work.mkdir(parents=True)
        dest = work / safe
        kind = "gcode" if suffix in GCODE_SUFFIXES else "mesh"
        try:
            with self.j._tx() as db:
                now = time.time()
                cur = db.execute(
                    "INSERT INTO jobs (name, source_name, kind, state, created, updated, work_dir,"
                    " input_path, print_requested) VALUES (?,?,?,?,?,?,?,?,?)",
                    (safe, name, kind, str(S.QUEUED), now, now, str(work), str(dest),
                     int(self.cfg.daemon.auto_print)))
                job_id = int(cur.lastrowid)
                db.execute("INSERT INTO transitions VALUES (?,?,?,?,?)",
                           (job_id, None, str(S.QUEUED), now, "taken from the spool"))
                os.rename(path, dest)
        except FileNotFoundError:
            shutil.rmtree(work, ignore_errors=True)
            return None
        log.info("job %d: took %s (%s)", job_id, name, kind)
        return job_id

    def intake_upload(self, path: Path, print_requested: bool) -> int | None:
        """:meth:`intake` for a file the web server received into the spool, recording
        the uploader's print choice (not ``[daemon] auto_print``) in the same transaction,
        so that a crash right after it cannot change what becomes of the job."""
        asked = dataclasses.replace(self.cfg.daemon, auto_print=print_requested)
        uploader = copy.copy(self)
        uploader.cfg = dataclasses.replace(self.cfg, daemon=asked)
        return uploader.intake(path)

    def _refuse(self, path: Path, reason: str) -> int:
        """Record a failed job for an entry refused at the door, move it to failed/."""
        safe = sanitise_name(path.name)
        dest = safe_output_path(self.cfg.failed_dir, safe, 0)
        job_id = self.j.add_job(name=safe, source_name=display_name(path.name), kind="refused",
                                work_dir="", input_path="", state=S.FAILED, reason=reason)
        if dest.name != safe:
            dest = safe_output_path(self.cfg.failed_dir, safe, job_id)
        try:
            os.rename(path, dest)  # a symlink is moved as a link, never followed
            outputs = {"input": str(dest)}
        except OSError as e:
            log.warning("job %d: could not move %s to failed/: %s", job_id, path.name, e)
            outputs = {}
        self.j.update(job_id, outputs=outputs)
        self._write_reports(job_id, self.cfg.failed_dir, Path(dest.name).stem)
        log.warning("job %d: %s", job_id, reason)
        return job_id

    def recover_orphans(self) -> list[str]:
        """Work folders no job owns (the daemon died mid-intake): give files back to the spool."""
        owned = {Path(j.work_dir).name for j in self.j.jobs() if j.work_dir}
        given_back = []
        for d in self.cfg.work_dir.iterdir():
            if not d.is_dir() or d.name in owned:
                continue
            for f in d.iterdir():
                if f.is_file() and not f.name.endswith((".json", ".log")):
                    target = safe_output_path(self.root, f.name, 0)
                    os.rename(f, target)
                    given_back.append(target.name)
            shutil.rmtree(d, ignore_errors=True)
        return given_back

    # -- outcome --------------------------------------------------------------------------
    def _write_reports(self, job_id: int, folder: Path, stem: str) -> None:
        job = self.j.get(job_id)
        assert job is not None
        jp, tp = write_reports(folder, stem, job, self.j.history(job_id))
        outs = dict(job.outputs or {})
        outs.update(report_json=str(jp), report_txt=str(tp))
        self.j.update(job_id, outputs=outs)
        # rewrite once more so the JSON report lists its own paths
        job = self.j.get(job_id)
        assert job is not None
        write_reports(folder, stem, job, self.j.history(job_id))

    def archive(self, job_id: int) -> None:
        """Move a finished job's files to done/ (done) or failed/ (failed, cancelled)
        and write its reports. Interrupted jobs keep their work folder (for a requeue)
        and only get reports in failed/."""
        job = self.j.get(job_id)
        assert job is not None
        folder = self.cfg.done_dir if job.state == S.DONE else self.cfg.failed_dir
        stem = Path(job.name).stem
        outs = dict(job.outputs or {})
        if job.state != S.INTERRUPTED and job.work_dir and Path(job.work_dir).is_dir():
            moves = [("input", job.input_path, job.name)]
            if job.kind == "mesh":
                moves += [("repaired", job.repaired_path, f"{stem}.repaired.stl"),
                          ("gcode", job.gcode_path, f"{stem}.gcode")]
            for key, src, name in moves:
                if src and Path(src).is_file():
                    dest = safe_output_path(folder, name, job.id)
                    os.rename(src, dest)
                    outs[key] = str(dest)
            shutil.rmtree(job.work_dir, ignore_errors=True)
        # the report stem follows the archived input's name, unique per job
        in_out = outs.get("input")
        if in_out:
            stem = Path(in_out).stem
        elif (folder / f"{stem}.report.json").exists():
            stem = f"{stem}-{job.id}"
        self.j.update(job_id, outputs=outs)
        self._write_reports(job_id, folder, stem)

    def drop_reports(self, job: Job) -> None:
        for k in ("report_json", "report_txt"):
            p = (job.outputs or {}).get(k)
            if p:
                Path(p).unlink(missing_ok=True)

    def restore_input(self, job: Job) -> tuple[str, str]:
        """For a requeue of a failed/cancelled job: bring its input back into a work folder."""
        src = (job.outputs or {}).get("input")
        if job.kind == "refused" or not src or not Path(src).is_file() or Path(src).is_symlink():
            raise ValueError(f"job {job.id} was refused at intake ({job.reason}); fix the file "
                             "and drop it into the spool again")
        work = self.cfg.work_dir / uuid.uuid4().hex
        work.mkdir(parents=True)
        dest = work / job.name
        os.rename(src, dest)
        self.drop_reports(job)
        return str(work), str(dest)


class Processor:
    """Takes queued jobs and runs them to ``ready``: repair and slicing for meshes,
    checks for G-code. One instance per worker thread."""

    def __init__(self, cfg: Config, journal: Journal, spool: Spool, printer_info, *,
                 stop: threading.Event, claim_lock: threading.Lock, active: dict[int, Any]):
        self.cfg = cfg
        self.j = journal
        self.spool = spool
        self.printer_info = printer_info    # callable() -> dict | None (last known info)
        self.stop = stop
        self.claim_lock = claim_lock
        self.active = active                # job id -> cancel Event (shared)

    def next_job(self, have_printer: bool) -> tuple[Job, threading.Event] | None:
        """Claim the oldest queued job; without printer info only G-code (its command
        policy needs no printer; the build volume is checked again before printing)."""
        with self.claim_lock:
            for job in self.j.jobs({S.QUEUED}):
                if job.id not in self.active and (have_printer or job.kind == "gcode"):
                    ev = threading.Event()
                    self.active[job.id] = ev
                    return job, ev
        return None

    def run_forever(self) -> None:
        while not self.stop.is_set():
            try:
                info = self.printer_info()
                claimed = self.next_job(info is not None)
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
        job = self.j.get(job_id)
        if job is None or job.state not in (S.QUEUED, S.REPAIRING, S.SLICING, S.READY):
            return
        self.j.transition(job_id, S.FAILED, note=reason, reason=reason, progress=None)
        self.spool.archive(job_id)
        log.warning("job %d failed: %s", job_id, reason)

    def _stopped(self, job_id: int, cancel: threading.Event) -> None:
        """The child was stopped: cancelled by the user, or the daemon is shutting down."""
        if self.stop.is_set():
            self.j.transition(job_id, S.QUEUED, note="daemon stopping; will be redone",
                              progress=None)
        else:
            self.j.transition(job_id, S.CANCELLED, note="cancelled", reason="cancelled by user",
                              progress=None)
            self.spool.archive(job_id)

    def _progress(self, job_id: int):
        last = [0.0]

        def cb(stage: str, fraction: float) -> None:
            now = time.monotonic()
            if now - last[0] >= 0.5 or fraction >= 1.0:
                last[0] = now
                self.j.update(job_id, progress=float(fraction))
        return cb

    def process(self, job: Job, info: dict[str, Any] | None, cancel: threading.Event) -> None:
        if job.kind == "gcode":
            self._check_gcode(job, info)
            return
        assert info is not None
        eps, eps_src = epsilon_from(info, self.cfg)
        if job.attempts >= self.cfg.limits.max_attempts:
            self._fail(job.id, f"processing was interrupted {job.attempts} times (the daemon "
                               "stopped or died while working on it); giving up")
            return
        work = Path(job.work_dir or "")
        lim = self.cfg.limits
        self.j.transition(job.id, S.REPAIRING, expect=S.QUEUED, note=f"epsilon {eps:g} mm",
                          attempts=job.attempts + 1, epsilon=eps, epsilon_source=eps_src,
                          printer_info=info, progress=0.0)
        repaired = work / "repaired.stl"
        try:
            report = run_task("repair", {
                "in": job.input_path, "out": str(repaired), "job_name": job.name,
                "report": str(work / "repair.report.json"), "epsilon": eps,
                "max_bytes": int(lim.max_file_mb * 1024 * 1024),
                "max_triangles": lim.max_triangles,
            }, work_dir=work, timeout=lim.repair_timeout, memory_mb=lim.repair_memory_mb,
                progress=self._progress(job.id), cancel=self._either(cancel))
        except WorkerCancelled:
            self._stopped(job.id, cancel)
            return
        except WorkerFailed as e:
            self._fail(job.id, f"repair failed: {e}")
            return
        summary = (report or {}).get("summary", "repaired")
        self.j.transition(job.id, S.SLICING, note=summary, repair_report=report,
                          repaired_path=str(repaired), progress=0.0)
        log.info("job %d: repaired (%s)", job.id, summary)
        gcode = work / f"{Path(job.name).stem}.gcode"
        bv = info.get("build_volume")
        try:
            out = run_task("slice", {
                "in": str(repaired), "out": str(gcode), "nozzle": eps, "job_name": job.name,
                "build_volume": list(bv) if bv else None,
                "filament_diameter": info.get("filament_diameter"),
                "flavour": flavour_from(info), "overrides": self.cfg.profile,
            }, work_dir=work, timeout=lim.slice_timeout, memory_mb=lim.slice_memory_mb,
                progress=self._progress(job.id), cancel=self._either(cancel))
        except WorkerCancelled:
            self._stopped(job.id, cancel)
            return
        except WorkerFailed as e:
            self._fail(job.id, f"slicing failed: {e}")
            return
        summary = (out or {}).get("summary") or {}
        try:
            with open(gcode, encoding="utf-8", errors="replace") as f:
                check_gcode(strip_gcode(f), forbidden=self.cfg.safety.forbidden_gcodes,
                            allow_firmware=self.cfg.safety.allow_firmware_commands,
                            build_volume=None)
        except UnsafeEntry as e:
            self._fail(job.id, f"the sliced G-code was {e} (check the [profile] start/end G-code)")
            return
        self.j.transition(job.id, S.READY, note="sliced", slice_summary=summary,
                          gcode_path=str(gcode), progress=None)
        log.info("job %d: sliced: %s", job.id, summary)

    def _either(self, cancel: threading.Event) -> threading.Event:
        """An event set when the job is cancelled or the daemon stops."""
        return AnyEvent(cancel, self.stop)  # type: ignore[return-value]

    def _check_gcode(self, job: Job, info: dict[str, Any] | None) -> None:
        bv = (info or {}).get("build_volume")
        try:
            with open(job.input_path or "", encoding="utf-8", errors="replace") as f:
                res = check_gcode(strip_gcode(f), forbidden=self.cfg.safety.forbidden_gcodes,
                                  allow_firmware=self.cfg.safety.allow_firmware_commands,
                                  build_volume=bv)
        except UnsafeEntry as e:
            self._fail(job.id, str(e))
            return
        except OSError as e:
            self._fail(job.id, f"cannot read the G-code: {e.strerror}")
            return
        if res.lines == 0:
            self._fail(job.id, "the G-code file has no commands")
            return
        self.j.transition(job.id, S.READY, expect=S.QUEUED, note="G-code checked",
                          gcode_path=job.input_path, printer_info=info,
                          slice_summary={"gcode_check": res.to_dict()})


class AnyEvent:
    """Duck-typed ``threading.Event`` that is set when any of the given events is."""

    def __init__(self, *events: threading.Event) -> None:
        self.events = events

    def is_set(self) -> bool:
        return any(e.is_set() for e in self.events)

    def wait(self, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.monotonic() + timeout
        while not self.is_set():
            if end is not None and time.monotonic() >= end:
                return False
            time.sleep(0.05)
        return True
