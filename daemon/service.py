"""The daemon: recovery at start-up, the main loop, requests from the CLI, shutdown.

Threads: the main loop (spool intake, CLI requests, status/heartbeat, systemd
notifications), ``workers`` processor threads (repair and slicing run in child
processes they supervise), one printer thread, and watchdog's observer.

SIGTERM/SIGINT stop it gracefully: children are killed and their jobs go back to
``queued`` (redone at the next start); a running print is cancelled (cooldown and
motors off are sent) and its job marked ``interrupted``.
"""

from __future__ import annotations

import fcntl
import logging
import os
import signal
import threading
import time
from typing import Any

from daemon import __version__
from daemon.config import Config
from daemon.journal import Job, Journal
from daemon.notify import notify, watchdog_interval
from daemon.pins import PinnedFolders
from daemon.pipeline import Processor, Spool
from daemon.printers import PrinterPool
from daemon.printlink import HALF_PRINTED
from daemon.states import FINAL, ON_PRINTER, JobState, TransitionError
from daemon.watcher import SpoolWatcher
from daemon.worker import FORK_SERVER, warm_up

log = logging.getLogger("preflight.daemon")


class AlreadyRunning(RuntimeError):
    pass


class Daemon:
    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg
        cfg.daemon.state_dir.mkdir(parents=True, exist_ok=True)
        self._lockfile = open(cfg.daemon.state_dir / "daemon.lock", "a+")  # noqa: SIM115
        try:
            fcntl.flock(self._lockfile, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lockfile.seek(0)
            pid = self._lockfile.read().strip() or "?"
            raise AlreadyRunning(f"another preflight daemon (pid {pid}) is using "
                                 f"{cfg.daemon.state_dir}") from None
        self._lockfile.seek(0)
        self._lockfile.truncate()
        self._lockfile.write(str(os.getpid()))
        self._lockfile.flush()
        self.journal = Journal(cfg.journal_path)
        self.spool = Spool(cfg, self.journal)
        self.stop = threading.Event()
        self.watcher = SpoolWatcher(cfg.spool.path, settle_seconds=cfg.spool.settle_seconds,
                                    close_grace_seconds=cfg.spool.close_grace_seconds,
                                    poll=cfg.spool.poll)
        self.pinned = PinnedFolders(cfg.spool.path, settle_seconds=cfg.spool.settle_seconds,
                                    close_grace_seconds=cfg.spool.close_grace_seconds,
                                    poll=cfg.spool.poll)
        self.printers = PrinterPool(cfg, self.journal, self.spool, self.stop)
        self.printer = self.printers.first  # the one printer, or the first of several
        self._claim = threading.Lock()
        self._active: dict[int, threading.Event] = {}
        self.started = time.time()
        self.farm = None
        if cfg.farm.broker:
            self.farm = self._join_farm()
        self.web = None
        if cfg.web.listen:
            from daemon.web.server import WebServer

            self.web = WebServer(self)

    def _join_farm(self):
        """Farm mode: the node's part in the farm, and the gate of its printers."""
        from daemon.farm import check_farm_config
        from daemon.farm.node import FarmNode

        check_farm_config(self.cfg)
        if self.cfg.farm.compute and not self.cfg.printer_tables:
            self.printers.links = []  # a compute-only node: no printer to drive
        farm = FarmNode(self)
        for link in farm.links():
            link.gate = farm.may_print
        return farm

    # -- start-up recovery ----------------------------------------------------------------
    def recover(self) -> None:
        """Make the journal consistent after a crash, a kill -9 or a power cut."""
        journal = self.journal
        for job in journal.jobs({JobState.REPAIRING, JobState.SLICING}):
            journal.transition(job.id, JobState.QUEUED, progress=None,
                               note=f"the daemon stopped while {job.state}; redoing it")
            log.info("job %d: was %s when the daemon stopped; redoing it", job.id, job.state)
        for job in journal.jobs({JobState.PRINTING, JobState.PAUSED}):
            when = "while the print was paused" if job.state == JobState.PAUSED else \
                "during the print"
            reason = (f"print interrupted: the daemon or the machine stopped {when} "
                      f"(about {100 * (job.progress or 0):.0f}% acknowledged); a paused print "
                      "cannot be resumed after that (the printer may have reset, cooled down "
                      "or lost its position); " + HALF_PRINTED.format(id=job.id))
            journal.transition(job.id, JobState.INTERRUPTED, reason=reason, note=reason,
                               progress=None)
            self.spool.archive(job.id)
            log.warning("job %d: %s", job.id, reason)
        for job_id in journal.unreported(set(FINAL)):
            self.spool.archive(job_id)
            log.warning("job %d: archived its files and reports (the daemon stopped while "
                        "archiving it)", job_id)
        released = self.journal.release_unstarted_claims()
        if released:
            log.info("%d ready job(s) claimed by a printer but not started: any printer may "
                     "take them again", released)
        for name in self.spool.recover_orphans():
            log.warning("gave %s back to the spool (the daemon stopped while taking it)", name)

    # -- requests from the CLI ------------------------------------------------------------
    def handle_requests(self) -> None:
        for req in self.journal.pending_requests():
            try:
                try:
                    ok, answer = self._handle(req["action"], int(req["job_id"]))
                except TransitionError:  # the job moved on meanwhile: look again, once
                    ok, answer = self._handle(req["action"], int(req["job_id"]))
            except (TransitionError, KeyError, ValueError, OSError) as e:
                ok, answer = False, str(e).strip("'\"")
            except Exception as e:  # a bad request must not take the daemon down
                log.exception("request %r", req)
                ok, answer = False, f"internal error: {e}"
            self.journal.finish_request(req["id"], ok, answer)
            log.info("request %s job %s: %s", req["action"], req["job_id"], answer)
        self.printers.wake_all()

    def _handle(self, action: str, job_id: int) -> tuple[bool, str]:
        job = self.journal.get(job_id)
        if job is None:
            return False, f"there is no job {job_id}"
        handlers = {"print": self._print, "requeue": self._requeue, "cancel": self._cancel,
                    "pause": self._pause, "resume": self._resume, "stop": self._stop}
        if action not in handlers:
            return False, f"unknown request {action!r}"
        return handlers[action](job)

    def _print(self, job: Job) -> tuple[bool, str]:
        if job.state == JobState.INTERRUPTED:
            return False, (f"job {job.id} was interrupted mid-print; make sure the bed is "
                           f"clear, then use `preflight jobs requeue {job.id}`")
        if job.state not in (JobState.READY, JobState.QUEUED, JobState.REPAIRING,
                             JobState.SLICING):
            return False, f"job {job.id} is {job.state}; only a ready job can be printed"
        if job.print_requested:
            return True, f"job {job.id} is already going to print"
        self.journal.update(job.id, print_requested=True)
        return True, f"job {job.id} will print" + (" when it is ready"
                                                    if job.state != JobState.READY else "")

    def _requeue(self, job: Job) -> tuple[bool, str]:
        if job.state == JobState.INTERRUPTED:
            self.spool.drop_reports(job)
            self.journal.transition(job.id, JobState.READY, expect=JobState.INTERRUPTED,
                                    print_requested=True, reason=None, progress=None,
                                    printer=None,
                                    note="requeued by the user")
            return True, f"job {job.id} will be printed again from the start"
        if job.state in (JobState.FAILED, JobState.CANCELLED):
            work_dir, input_path = self.spool.restore_input(job)
            self.journal.transition(
                job.id, JobState.QUEUED, expect={JobState.FAILED, JobState.CANCELLED},
                work_dir=work_dir, input_path=input_path, reason=None, attempts=0, progress=None,
                repaired_path=None, gcode_path=None, repair_report=None, slice_summary=None,
                print_result=None, outputs={}, print_requested=self.cfg.daemon.auto_print,
                printer=None, nozzle=job.nozzle if job.pinned else None,
                note="requeued by the user")
            return True, f"job {job.id} is queued again"
        return False, (f"job {job.id} is {job.state}; only failed, cancelled or interrupted "
                       "jobs can be requeued")

    def _cancel(self, job: Job) -> tuple[bool, str]:
        if job.state in (JobState.QUEUED, JobState.READY, JobState.INTERRUPTED):
            with self._claim:
                if job.id in self._active:  # a worker just took it
                    self._active[job.id].set()
                    return True, f"job {job.id} is being cancelled"
                # expect: the printer thread may have started it since we looked
                self.journal.transition(job.id, JobState.CANCELLED, expect=job.state,
                                        reason="cancelled by user", note="cancelled by the user",
                                        progress=None)
            self.spool.archive(job.id)
            return True, f"job {job.id} cancelled"
        if job.state in (JobState.REPAIRING, JobState.SLICING):
            with self._claim:
                cancel = self._active.get(job.id)
            if cancel is None:
                return False, f"job {job.id} is {job.state} but no worker holds it; try again"
            cancel.set()
            return True, f"job {job.id} is being cancelled"
        if job.state in ON_PRINTER:
            if self.printers.cancel_job(job.id):
                return True, (f"job {job.id}: stopping the print (cooldown and motors off "
                              "will be sent)")
            return False, f"job {job.id} is printing but the printer thread does not hold it"
        return False, f"job {job.id} is {job.state}; nothing to cancel"

    def _pause(self, job: Job) -> tuple[bool, str]:
        if job.state == JobState.PAUSED:
            return True, f"job {job.id} is already paused"
        if job.state != JobState.PRINTING:
            return False, f"job {job.id} is {job.state}; only a printing job can be paused"
        if not self.printers.control_job(job.id, "pause"):
            return False, f"job {job.id} is printing but the printer thread does not hold it"
        return True, (f"job {job.id}: pausing (the lines already sent finish, then the head "
                      "retracts and parks; the heaters stay on)")

    def _resume(self, job: Job) -> tuple[bool, str]:
        state = self.printers.control_state(job.id)
        if job.state == JobState.PRINTING and state == "printing":
            return True, f"job {job.id} is printing, not paused"
        if job.state not in ON_PRINTER or state is None:
            return False, f"job {job.id} is {job.state}; only a paused job can be resumed"
        self.printers.control_job(job.id, "resume")
        return True, f"job {job.id}: resuming (back to where it paused, then the next line)"

    def _stop(self, job: Job) -> tuple[bool, str]:
        if job.state not in ON_PRINTER or not self.printers.control_job(job.id, "stop"):
            return False, f"job {job.id} is {job.state}; nothing is printing to stop"
        return True, (f"job {job.id}: emergency stop (M112) sent; the printer must be reset "
                      "before it prints again")

    # -- status ---------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        return {
            "pid": os.getpid(),
            "version": __version__,
            "started": self.started,
            "heartbeat": time.time(),
            "running": not self.stop.is_set(),
            "config": self.cfg.source,
            "spool": str(self.cfg.spool.path),
            "state_dir": str(self.cfg.daemon.state_dir),
            "auto_print": self.cfg.daemon.auto_print,
            "printer": self.printer.status() if self.printers.links else None,
            "printers": self.printers.status(),
            "jobs": self.journal.counts(),
            "waiting_files": self.watcher.pending() + self.pinned.pending(),
            "web": self.web.status() if self.web else None,
            "farm": self.farm.status() if self.farm else None,
        }

    @staticmethod
    def status_line(status: dict[str, Any]) -> str:
        printer = status.get("printer") or {}
        jobs = status.get("jobs") or {}
        farm = status.get("farm") or {}
        active = ", ".join(f"{jobs[k]} {k}" for k in ("queued", "repairing", "slicing", "ready",
                                                      "printing") if jobs.get(k))
        if farm.get("compute_only"):
            doing = f"compute-only node of farm {farm.get('farm')!r} (no printer)"
        elif printer.get("state") in ("printing", "paused"):
            doing = (f"{printer['state']} job {printer.get('job')} "
                     f"{100 * (printer.get('progress') or 0):.0f}%"
                     + (f" ({printer['message']})" if printer.get("message") else ""))
        elif printer.get("state") == "connected":
            info = printer.get("info") or {}
            doing = (f"printer ready ({info.get('firmware') or '?'}, nozzle "
                     f"{info.get('nozzle_diameter')} mm)")
        else:
            doing = f"printer {printer.get('state')}" + (
                f": {printer['message']}" if printer.get("message") else "")
        printers = status.get("printers") or []
        if len(printers) > 1:  # systemd's one line: each printer's state in a word or two
            doing = ", ".join(f"{p.get('name')} {p.get('state')}"
                              + (f" job {p['job']}" if p.get("job") else "") for p in printers)
        return f"{doing}; jobs: {active or 'none active'}"

    # -- the main loop --------------------------------------------------------------------
    @staticmethod
    def _warm_up() -> None:
        """Have the fork server import the heavy modules before the first job needs them."""
        try:
            warm_up()
        except Exception as e:  # the first task will try again and fail with the reason
            log.error("the fork server did not start: %s", e)

    def run(self) -> int:
        def on_signal(signum, frame):  # noqa: ARG001
            log.info("received %s; stopping", signal.Signals(signum).name)
            self.stop.set()

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        self.recover()
        threading.Thread(target=self._warm_up, name="forkserver-start", daemon=True).start()
        self.watcher.start()
        self.pinned.refresh()
        self.printers.start()
        if self.web:
            self.web.start()
        workers = []
        if self.farm is not None:  # spool files go to the farm; uploads stay local
            self.farm.start()
        for i in range(self.cfg.daemon.workers):
            processor = Processor(self.cfg, self.journal, self.spool, self.printer.last_info,
                                  stop=self.stop, claim_lock=self._claim, active=self._active,
                                  router=self.printers)
            thread = threading.Thread(target=processor.run_forever, name=f"worker-{i}",
                                      daemon=True)
            thread.start()
            workers.append(thread)
        log.info("preflight %s watching %s (state in %s, printers: %s)", __version__,
                 self.cfg.spool.path, self.cfg.daemon.state_dir,
                 ", ".join(f"{p.name} on {p.port}" for p in self.cfg.all_printers))
        status = self.status()
        self.journal.set_meta("status", status)
        notify(f"READY=1\nSTATUS={self.status_line(status)}\nMAINPID={os.getpid()}")
        self._main_loop(workers)
        notify("STOPPING=1\nSTATUS=stopping")
        log.info("stopping")
        self.watcher.stop()
        self.pinned.stop()
        if self.web:
            self.web.stop()
        for thread in workers:
            thread.join(timeout=30)
        self.printers.join(timeout=60)
        if self.farm is not None:
            self.farm.join(timeout=30)
        FORK_SERVER.shutdown()
        status = self.status()
        status["running"] = False
        self.journal.set_meta("status", status)
        self.journal.close()
        return 0

    def _main_loop(self, workers: list[threading.Thread]) -> None:
        """Intake, CLI requests, status and the systemd watchdog until asked to stop."""
        watchdog_every = watchdog_interval()
        last_status = last_watchdog = last_pins = 0.0
        while not self.stop.is_set():
            try:
                if time.monotonic() - last_pins >= 2.0:  # new nozzle-X/ folders
                    last_pins = time.monotonic()
                    self.pinned.refresh()
                for path in self.watcher.due() + self.pinned.due():
                    try:
                        if self.farm is None or not self.farm.intake(path):
                            self.spool.intake(path)
                    except Exception:
                        log.exception("intake of %s", path)
                self.handle_requests()
                now = time.monotonic()
                if now - last_status >= 1.0:
                    last_status = now
                    status = self.status()
                    self.journal.set_meta("status", status, durable=False)  # a heartbeat
                    notify(f"STATUS={self.status_line(status)}")
            except Exception:  # e.g. the journal locked for too long: log and go on
                log.exception("main loop")
                self.stop.wait(1.0)
                continue
            if watchdog_every and now - last_watchdog >= watchdog_every:
                last_watchdog = now
                if self.printers.all_alive() and all(t.is_alive() for t in workers):
                    notify("WATCHDOG=1")
            # a file that is settling is due within close_grace_seconds: look again sooner
            nap = 0.2 if not self.watcher.pending() else min(
                0.2, max(0.02, self.cfg.spool.close_grace_seconds / 2))
            self.watcher.wakeup.wait(nap)
            self.watcher.wakeup.clear()


def daemon_alive(status: dict[str, Any] | None, *, max_age: float = 10.0) -> bool:
    """True if the status row was written by a running daemon recently."""
    if not status or not status.get("running"):
        return False
    pid = status.get("pid")
    try:
        os.kill(int(pid), 0)
    except (TypeError, ValueError, ProcessLookupError):
        return False
    except PermissionError:
        pass
    return time.time() - float(status.get("heartbeat", 0)) < max_age

