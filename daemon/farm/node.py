"""One daemon's part in the farm: intake to the outbox, publishing, dispatch to its
free printers, the print gate, outcomes, leases, the reaper and the heartbeat.

One thread (:meth:`FarmNode.run`) does the short steps twice a second; each claimed
job waits for its repair+slice in a thread of its own (:meth:`FarmNode._prepare`).
Every broker call may fail (an outage): the step is retried on the next round and
nothing is lost, since what must survive is in the journal first.
"""

from __future__ import annotations

import logging
import os
import shutil
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import redis

from daemon.farm import node_name
from daemon.farm.artefacts import ArtefactStore, prepared_key
from daemon.farm.compute import ComputeWorker
from daemon.farm.ledger import FarmLedger
from daemon.farm.queue import FarmQueue
from daemon.farm.routing import measure, pin_of, printer_fits
from daemon.journal import Job
from daemon.pins import find_sidecar
from daemon.pipeline import epsilon_from, flavour_from, slice_overrides
from daemon.safety import (
    ACCEPTED_SUFFIXES,
    GCODE_SUFFIXES,
    UnsafeEntry,
    check_spool_entry,
    sanitise_name,
)
from daemon.states import ACTIVE, FINAL, JobState, TransitionError

log = logging.getLogger("preflight.farm")

ROUND_SECONDS = 0.5
HEARTBEAT_SECONDS = 2.0
#: A broker call that failed is tried again after this long.
RETRY_SECONDS = 1.0
#: A spool file the artefact store could not take is tried again this often (s).
RETRY_INTAKE = 5.0
LOST_CLAIM = ("the farm gave this job to another printer: this node lost its claim "
              "(it was down or cut off from the broker for longer than [farm] claim_timeout) "
              "before the print started; nothing was sent to the printer")


class NotForFarm(Exception):
    """A spool file the farm does not take: the local spool refuses it with the reason."""


def farm_work_dir(cfg: Any) -> Path:
    return cfg.spool.path / ".preflight" / "farm"


class FarmNode:
    def __init__(self, daemon: Any) -> None:
        cfg = daemon.cfg
        self.daemon = daemon
        self.cfg = cfg
        self.journal = daemon.journal
        self.spool = daemon.spool
        self.stop = daemon.stop
        self.node = node_name(cfg)
        self.queue = FarmQueue(cfg.farm.broker, cfg.farm.name)
        assert cfg.farm.artefacts is not None
        self.store = ArtefactStore(cfg.farm.artefacts)
        self.ledger = FarmLedger(self.journal)
        self.compute = ComputeWorker(cfg, self.stop) if cfg.farm.compute else None
        self.broker_up: bool | None = None
        self._lock = threading.Lock()
        self._held: dict[str, str] = {}        # farm id -> printer, claimed, not printing
        self._preparing: dict[str, str] = {}   # printer -> farm id being prepared for it
        self._lost: set[str] = set()
        self._retry: set[Path] = set()         # spool files the artefact store refused
        self._sizes: dict[str, list[float] | None] = {}  # farm id -> measured, unpublished
        self._next: dict[str, float] = {}
        self.thread = threading.Thread(target=self.run, name="farm", daemon=True)
        self.celery = None

    # -- printers -------------------------------------------------------------------------
    def links(self) -> list[Any]:
        return list(self.daemon.printers.links)

    @property
    def compute_only(self) -> bool:
        """A node with no printer: it takes files in and repairs and slices for the farm."""
        return not self.links()

    @staticmethod
    def link_name(link: Any) -> str:
        return link.name

    def _busy_printers(self) -> set[str]:
        """Printers holding a farm job not yet ended here (or one being prepared)."""
        busy = {c["printer"] for c in self.ledger.claims() if JobState(c["state"]) in ACTIVE}
        with self._lock:
            return busy | set(self._preparing)

    # -- intake ---------------------------------------------------------------------------
    def intake(self, path: Path) -> bool:
        """Take a spool file for the farm; False leaves it to the local spool (which
        refuses it with the reason: not a model, too big, unsafe...)."""
        try:
            self.take(path)
        except NotForFarm:
            return False
        return True

    def take(self, path: Path) -> str | None:
        """Take a spool file (dropped, or uploaded through the HTTP API) into the outbox:
        its farm job id; None if it vanished or waits for the artefact store (retried).
        Raises :class:`NotForFarm` for a file the local spool must refuse with the reason."""
        root = self.cfg.spool.path
        try:
            entry = check_spool_entry(root if path.parent == root else path.parent, path)
        except FileNotFoundError:
            return None
        except UnsafeEntry:
            raise NotForFarm(path.name) from None
        suffix = path.suffix.lower()
        limit = self.cfg.limits.max_file_mb * 1024 * 1024
        if suffix not in ACCEPTED_SUFFIXES or entry.st_size == 0 or entry.st_size > limit:
            raise NotForFarm(path.name)
        try:
            pin = pin_of(self.cfg.spool.path, path)
        except ValueError:  # a bad sidecar: the local spool fails the job with the reason
            raise NotForFarm(path.name) from None
        kind = "gcode" if suffix in GCODE_SUFFIXES else "mesh"
        try:
            input_key = self.store.put_input(path)
        except OSError as e:  # the artefact server is away: the file waits in the spool
            with self._lock:
                if path not in self._retry:
                    log.warning("farm: cannot store %s in %s (%s); trying again every %g s",
                                path.name, self.store.root, e.strerror or e, RETRY_INTAKE)
                self._retry.add(path)
            return None
        with self._lock:
            self._retry.discard(path)
        fields = {"name": sanitise_name(path.name), "source_name": path.name, "kind": kind,
                  "input": input_key, "origin": self.node,
                  "pin": "" if pin is None else f"{pin:g}",
                  "extents": None,  # measured before publishing, off the main loop
                  "taken_at": time.time()}
        fid = uuid.uuid4().hex
        sidecar = find_sidecar(path)

        def take() -> None:
            os.unlink(path)
            if sidecar is not None:  # it travelled as the pin
                sidecar.unlink(missing_ok=True)

        try:
            self.ledger.add_outbox(fid, fields, while_recording=take)
        except FileNotFoundError:
            return None
        log.info("farm: took %s as farm job %s%s", path.name, fid,
                 f" (pinned to {pin:g} mm)" if pin else "")
        return fid

    # -- the loop -------------------------------------------------------------------------
    def start(self) -> None:
        from daemon.farm.tasks import configure

        self.celery = configure(self.cfg)
        owned = set()
        for claim in self.ledger.claims():  # ready here before a restart: still ours?
            owned.add(Path(claim["work_dir"]).name)
            if JobState(claim["state"]) == JobState.READY:
                self._held[claim["fid"]] = claim["printer"]
        farm_work_dir(self.cfg).mkdir(parents=True, exist_ok=True)
        for folder in farm_work_dir(self.cfg).iterdir():  # a claim prepared, never recorded
            if folder.name not in owned:
                shutil.rmtree(folder, ignore_errors=True)
        self.thread.start()

    def join(self, timeout: float) -> None:
        self.thread.join(timeout)

    def _due(self, what: str, every: float) -> bool:
        now = time.monotonic()
        if now < self._next.get(what, 0.0):
            return False
        self._next[what] = now + every
        return True

    def run(self) -> None:
        while not self.stop.is_set():
            if self._retry and self._due("retry-intake", RETRY_INTAKE):
                with self._lock:
                    retry = list(self._retry)
                for path in retry:
                    self.intake(path)
            if self.compute is not None:
                try:
                    self.compute.check()
                except OSError:
                    log.exception("farm: starting the compute worker")
            try:
                self._round()
                if self.broker_up is False:
                    log.warning("farm: the broker is back")
                if self.broker_up is None:
                    self._check_persistence()
                self.broker_up = True
            except redis.RedisError as e:
                if self.broker_up is not False:
                    log.warning("farm: the broker is unreachable (%s); new dispatch paused, "
                                "prints under way go on", e)
                self.broker_up = False
                self.stop.wait(RETRY_SECONDS)
                continue
            except Exception:
                log.exception("farm")
            self.stop.wait(ROUND_SECONDS)
        if self.compute is not None:
            # from this thread: the worker's parent-death signal follows the thread that
            # started it, so it must be stopped (gently) before the thread ends
            self.compute.close()

    def _round(self) -> None:
        for fid, fields in self.ledger.unpublished():
            if fields["kind"] == "mesh" and fields.get("extents") is None:
                fields["extents"] = self._extents(fid, fields["input"])
            self.queue.publish(fid, fields)
            self._sizes.pop(fid, None)
            self.ledger.mark_published(fid)
            log.info("farm: published %s (%s)", fid, fields.get("name"))
        self._report_outcomes()
        ttl = self.cfg.farm.claim_timeout
        if self._due("renew", ttl / 4):
            self._renew(ttl)
        if self._due("reap", min(2.0, ttl / 4)):
            for fid in self.queue.reap():
                log.warning("farm: job %s lost its claim (its node stopped renewing it); "
                            "back on the queue", fid)
        self._dispatch()
        if self._due("heartbeat", HEARTBEAT_SECONDS):
            self.queue.heartbeat(self.node, self.status(), ttl=5 * HEARTBEAT_SECONDS)

    def _check_persistence(self) -> None:
        """Once, when the broker first answers: warn if it would lose the queue on a
        restart (published jobs would vanish from it; see docs/farm.md)."""
        if self.queue.appendonly() == "no":
            log.warning("farm: the broker (Redis) runs with appendonly no: a restart of "
                        "Redis loses the farm's queue and claims; set appendonly yes in "
                        "its redis.conf")

    def _extents(self, fid: str, input_key: str) -> list[float] | None:
        """The model's size, measured once (publishing may be retried through an outage)."""
        if fid not in self._sizes:
            work = farm_work_dir(self.cfg) / f"measure-{fid}"
            self._sizes[fid] = measure(self.store.input_path(input_key), work, self.cfg)
            shutil.rmtree(work, ignore_errors=True)
        return self._sizes[fid]

    def _renew(self, ttl: float) -> None:
        with self._lock:
            held = dict(self._held)
        for fid, printer in held.items():
            if not self.queue.renew(fid, self.node, printer, ttl):
                log.warning("farm: lost the claim of job %s (printer %s)", fid, printer)
                with self._lock:
                    self._held.pop(fid, None)
                    self._lost.add(fid)

    def _report_outcomes(self) -> None:
        for claim in self.ledger.claims():
            state = JobState(claim["state"])
            if claim["reported"] or state not in FINAL:
                continue
            self.queue.finish(claim["fid"], self.node, claim["printer"], str(state),
                              claim["reason"] or "", claim["epsilon"])
            self.ledger.set_reported(claim["work_dir"], True)
            with self._lock:
                self._held.pop(claim["fid"], None)

    # -- dispatch -------------------------------------------------------------------------
    def _dispatch(self) -> None:
        busy = self._busy_printers()
        free = [link for link in self.links() if self.link_name(link) not in busy
                and link.status().get("state") == "connected" and link.last_info()]
        if not free:
            return
        waiting = self.queue.waiting()
        if not waiting:
            return
        jobs = dict(zip(waiting, self.queue.jobs(waiting), strict=True))
        for link in free:
            info = link.last_info() or {}
            for fid, job in jobs.items():
                if not job or job.get("state") != "queued" or not printer_fits(job, info):
                    continue
                name = self.link_name(link)
                if self.queue.claim(fid, self.node, name, self.cfg.farm.claim_timeout):
                    jobs[fid] = {}
                    with self._lock:
                        self._held[fid] = name
                        self._preparing[name] = fid
                    log.info("farm: printer %s claimed job %s (%s)", name, fid, job.get("name"))
                    threading.Thread(target=self._prepare_safely, args=(fid, job, link),
                                     name=f"farm-{fid[:8]}", daemon=True).start()
                    break

    def _prepare_safely(self, fid: str, job: dict[str, str], link: Any) -> None:
        name = self.link_name(link)
        try:
            self._prepare(fid, job, link)
        except Exception:
            log.exception("farm: job %s", fid)
            with self._lock:
                self._lost.add(fid)  # the lease lapses; another printer takes it
                self._held.pop(fid, None)
        finally:
            with self._lock:
                self._preparing.pop(name, None)

    def _prepare(self, fid: str, job: dict[str, str], link: Any) -> None:
        """Have the job repaired and sliced for ``link``'s printer, then record it in
        the journal as ready for that printer (or failed with the reason)."""
        info = dict(link.last_info() or {})
        epsilon, epsilon_source = epsilon_from(info, self.cfg)
        result: dict[str, Any] = {"ok": True}
        if job.get("kind") == "mesh":
            result = self._compute(fid, job, info, epsilon)
            if result is None:
                return  # the claim was lost or the daemon is stopping
        # not under the spool's work folder: a folder no job owns there is given back to
        # the spool at start-up, which would make a second farm job of this input
        work = farm_work_dir(self.cfg) / uuid.uuid4().hex
        work.mkdir(parents=True)
        name = job.get("name") or "model"
        input_path = work / name
        shutil.copyfile(self.store.input_path(job["input"]), input_path)
        gcode = input_path
        if job.get("kind") == "mesh" and result.get("ok"):
            gcode = work / f"{Path(name).stem}.gcode"
            shutil.copyfile(self.store.prepared_paths(result["key"])[0], gcode)
        printer = self.link_name(link)
        state = JobState.READY if result.get("ok") else JobState.FAILED
        job_id = self.journal.add_job(
            name=name, source_name=job.get("source_name") or name, kind=job["kind"],
            work_dir=str(work), input_path=str(input_path), state=state,
            reason=result.get("reason"), nozzle=self._class_nozzle(job, epsilon),
            note=f"farm job {fid} from node {job.get('origin')}, claimed by printer {printer}",
            while_recording=lambda: self.ledger.record_claim_in_tx(fid, str(work), printer))
        fields: dict[str, Any] = {"epsilon": epsilon if job["kind"] == "mesh" else None,
                                  "epsilon_source": epsilon_source, "printer_info": info,
                                  "repair_report": result.get("repair_report"),
                                  "slice_summary": result.get("slice_summary")}
        if state == JobState.FAILED:
            self.journal.update(job_id, **fields)
            self.spool.archive(job_id)
            log.warning("farm: job %s (local %d) failed: %s", fid, job_id, result.get("reason"))
            return
        fields.update(gcode_path=str(gcode), **self._assign(printer))
        self.journal.update(job_id, print_requested=True, **fields)
        log.info("farm: job %s is ready for printer %s (local job %d, ε %g mm)", fid, printer,
                 job_id, epsilon)
        for each in self.links():
            getattr(each, "wake", threading.Event()).set()

    @staticmethod
    def _class_nozzle(job: dict[str, str], epsilon: float) -> float | None:
        """The nozzle class the local job is held to: if its printer gives it back (the
        print did not start), only a printer of that class may take it."""
        if job.get("kind") == "mesh":
            return epsilon
        return float(job["pin"]) if job.get("pin") else None

    @staticmethod
    def _assign(printer: str) -> dict[str, Any]:
        """The journal fields that give a ready job to one printer of this node (its
        claim in the journal: no other printer of the node takes it)."""
        return {"printer": printer}

    def _compute(self, fid: str, job: dict[str, str], info: dict[str, Any],
                 epsilon: float) -> dict[str, Any] | None:
        """Send the repair+slice to the compute queue and wait for its result (None if
        the claim was lost or the daemon is stopping)."""
        from daemon.farm.tasks import PREPARE

        volume = info.get("build_volume")
        spec = {"input": job["input"], "name": job.get("name") or "model", "epsilon": epsilon,
                "profile": slice_overrides(self.cfg),
                "build_volume": list(volume) if volume else None,
                "flavour": flavour_from(info),
                "filament_diameter": info.get("filament_diameter"), "for": fid}
        printer = {k: spec[k] for k in ("build_volume", "flavour", "filament_diameter")}
        key = prepared_key(spec["input"], epsilon, spec["profile"], printer)
        pending = None
        while not self.stop.is_set():
            with self._lock:
                if fid in self._lost:
                    return None
            done = self.store.get_prepared(key)  # done here or before, whatever the broker
            if done is not None:
                return done
            try:
                if pending is None:
                    pending = self.celery.send_task(PREPARE, args=[spec])
                    log.info("farm: job %s sent to the compute queue (ε %g mm, task %s)", fid,
                             epsilon, pending.id)
                if pending.ready():
                    return pending.get(timeout=5, propagate=False) or {
                        "ok": False, "reason": "the compute task returned nothing"}
            except Exception as e:  # the broker is down: keep the claim, try again
                log.debug("farm: job %s waiting for the broker: %s", fid, e)
                self.stop.wait(RETRY_SECONDS)
                continue
            self.stop.wait(0.2)
        return None

    # -- the print gate -------------------------------------------------------------------
    def may_print(self, job: Job) -> bool:
        """Called by the printer thread just before a job goes to printing: True once
        the farm has it as printing (the claim still held, atomically); False to wait
        (the broker is down) or when the claim was lost (the job is then cancelled here)."""
        claim = self.ledger.claim_of(job.work_dir)
        if claim is None:
            return True
        fid, printer = claim
        try:
            started = self.queue.start_print(fid, self.node, printer)
        except redis.RedisError:
            return False
        if started:
            with self._lock:
                self._held.pop(fid, None)
            self.ledger.set_reported(job.work_dir or "", False)
            return True
        try:
            self.journal.transition(job.id, JobState.CANCELLED, expect=JobState.READY,
                                    reason=LOST_CLAIM, note=LOST_CLAIM)
        except TransitionError:
            return False
        self.ledger.set_reported(job.work_dir or "", True)
        self.spool.archive(job.id)
        log.warning("farm: job %s (local %d): %s", fid, job.id, LOST_CLAIM)
        return False

    # -- status ---------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        claims = {c["printer"]: c for c in self.ledger.claims()
                  if JobState(c["state"]) in ACTIVE}
        with self._lock:
            preparing = dict(self._preparing)
        printers = []
        for link in self.links():
            name = self.link_name(link)
            info = link.last_info() or {}
            status = link.status()
            claim = claims.get(name)
            printers.append({
                "name": name, "nozzle": info.get("nozzle_diameter"),
                "build_volume": info.get("build_volume"), "state": status.get("state"),
                "job": claim["fid"] if claim else preparing.get(name),
                "job_state": str(claim["state"]) if claim else (
                    "preparing" if name in preparing else None)})
        return {"node": self.node, "farm": self.cfg.farm.name, "pid": os.getpid(),
                "compute": self.cfg.farm.compute, "compute_only": self.compute_only,
                "printers": printers, "outbox": self.ledger.outbox_counts(),
                "broker_up": self.broker_up, "heartbeat": time.time()}
