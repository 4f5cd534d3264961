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
from daemon.journal import Journal
from daemon.notify import notify, watchdog_interval
from daemon.pipeline import Processor, Spool
from daemon.printlink import HALF_PRINTED, PrinterLink
from daemon.states import JobState, TransitionError
from daemon.watcher import SpoolWatcher

log = logging.getLogger("preflight.daemon")
S = JobState


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
        self.printer = PrinterLink(cfg, self.journal, self.spool, self.stop)
        self._claim = threading.Lock()
        self._active: dict[int, threading.Event] = {}
        self.started = time.time()
        self.web = None
        if cfg.web.listen:
            from daemon.web.server import WebServer

            self.web = WebServer(self)

    # -- start-up recovery ----------------------------------------------------------------
    def recover(self) -> None:
        """Make the journal consistent after a crash, a kill -9 or a power cut."""
        j = self.journal
        for job in j.jobs({S.REPAIRING, S.SLICING}):
            j.transition(job.id, S.QUEUED, progress=None,
                         note=f"the daemon stopped while {job.state}; redoing it")
            log.info("job %d: was %s when the daemon stopped; redoing it", job.id, job.state)
        for job in j.jobs({S.PRINTING}):
            reason = ("print interrupted: the daemon or the machine stopped during the print "
                      f"(about {100 * (job.progress or 0):.0f}% acknowledged); "
                      + HALF_PRINTED.format(id=job.id))
            j.transition(job.id, S.INTERRUPTED, reason=reason, note=reason, progress=None)
            self.spool.archive(job.id)
            log.warning("job %d: %s", job.id, reason)
        for name in self.spool.recover_orphans():
            log.warning("gave %s back to the spool (the daemon stopped while taking it)", name)

    # -- requests from the CLI ------------------------------------------------------------
    def handle_requests(self) -> None:
        for req in self.journal.pending_requests():
            try:
                try:
                    ok, msg = self._handle(req["action"], int(req["job_id"]))
                except TransitionError:  # the job moved on meanwhile: look again, once
                    ok, msg = self._handle(req["action"], int(req["job_id"]))
            except (TransitionError, KeyError, ValueError, OSError) as e:
                ok, msg = False, str(e).strip("'\"")
            except Exception as e:  # a bad request must not take the daemon down
                log.exception("request %r", req)
                ok, msg = False, f"internal error: {e}"
            self.journal.finish_request(req["id"], ok, msg)
            log.info("request %s job %s: %s", req["action"], req["job_id"], msg)
        self.printer.wake.set()

    def _handle(self, action: str, job_id: int) -> tuple[bool, str]:
        j = self.journal
        job = j.get(job_id)
        if job is None:
            return False, f"there is no job {job_id}"
        if action == "print":
            if job.state == S.INTERRUPTED:
                return False, (f"job {job_id} was interrupted mid-print; make sure the bed is "
                               f"clear, then use `preflight jobs requeue {job_id}`")
            if job.state not in (S.READY, S.QUEUED, S.REPAIRING, S.SLICING):
                return False, f"job {job_id} is {job.state}; only a ready job can be printed"
            if job.print_requested:
                return True, f"job {job_id} is already going to print"
            j.update(job_id, print_requested=True)
            return True, f"job {job_id} will print" + (" when it is ready"
                                                         if job.state != S.READY else "")
        if action == "requeue":
            if job.state == S.INTERRUPTED:
                self.spool.drop_reports(job)
                j.transition(job_id, S.READY, expect=S.INTERRUPTED, print_requested=True,
                             reason=None, progress=None, note="requeued by the user")
                return True, f"job {job_id} will be printed again from the start"
            if job.state in (S.FAILED, S.CANCELLED):
                work, inp = self.spool.restore_input(job)
                j.transition(job_id, S.QUEUED, expect={S.FAILED, S.CANCELLED}, work_dir=work,
                             input_path=inp, reason=None, attempts=0, progress=None,
                             repaired_path=None, gcode_path=None, repair_report=None,
                             slice_summary=None, print_result=None, outputs={},
                             print_requested=self.cfg.daemon.auto_print,
                             note="requeued by the user")
                return True, f"job {job_id} is queued again"
            return False, f"job {job_id} is {job.state}; only failed, cancelled or interrupted " \
                          "jobs can be requeued"
        if action == "cancel":
            if job.state in (S.QUEUED, S.READY, S.INTERRUPTED):
                with self._claim:
                    if job_id in self._active:  # a worker just took it
                        self._active[job_id].set()
                        return True, f"job {job_id} is being cancelled"
                    # expect: the printer thread may have started it since we looked
                    j.transition(job_id, S.CANCELLED, expect=job.state,
                                 reason="cancelled by user", note="cancelled by the user",
                                 progress=None)
                self.spool.archive(job_id)
                return True, f"job {job_id} cancelled"
            if job.state in (S.REPAIRING, S.SLICING):
                with self._claim:
                    ev = self._active.get(job_id)
                if ev is None:
                    return False, f"job {job_id} is {job.state} but no worker holds it; try again"
                ev.set()
                return True, f"job {job_id} is being cancelled"
            if job.state == S.PRINTING:
                if self.printer.cancel_job(job_id):
                    return True, (f"job {job_id}: stopping the print (cooldown and motors off "
                                  "will be sent)")
                return False, f"job {job_id} is printing but the printer thread does not hold it"
            return False, f"job {job_id} is {job.state}; nothing to cancel"
        return False, f"unknown request {action!r}"

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
            "printer": self.printer.status(),
            "jobs": self.journal.counts(),
            "waiting_files": self.watcher.pending(),
            "web": self.web.status() if self.web else None,
        }

    @staticmethod
    def status_line(st: dict[str, Any]) -> str:
        p = st.get("printer") or {}
        jobs = st.get("jobs") or {}
        active = ", ".join(f"{jobs[k]} {k}" for k in ("queued", "repairing", "slicing", "ready",
                                                      "printing") if jobs.get(k))
        if p.get("state") == "printing":
            pr = f"printing job {p.get('job')} {100 * (p.get('progress') or 0):.0f}%"
        elif p.get("state") == "connected":
            info = p.get("info") or {}
            pr = f"printer ready ({info.get('firmware') or '?'}, nozzle " \
                 f"{info.get('nozzle_diameter')} mm)"
        else:
            pr = f"printer {p.get('state')}" + (f": {p['message']}" if p.get("message") else "")
        return f"{pr}; jobs: {active or 'none active'}"

    # -- the main loop --------------------------------------------------------------------
    def run(self) -> int:
        def on_signal(signum, frame):  # noqa: ARG001
            log.info("received %s; stopping", signal.Signals(signum).name)
            self.stop.set()

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        self.recover()
        self.watcher.start()
        self.printer.start()
        if self.web:
            self.web.start()
        workers = []
        for i in range(self.cfg.daemon.workers):
            proc = Processor(self.cfg, self.journal, self.spool, self.printer.last_info,
                             stop=self.stop, claim_lock=self._claim, active=self._active)
            t = threading.Thread(target=proc.run_forever, name=f"worker-{i}", daemon=True)
            t.start()
            workers.append(t)
        log.info("preflight %s watching %s (state in %s, printer %s)", __version__,
                 self.cfg.spool.path, self.cfg.daemon.state_dir, self.cfg.printer.port)
        st = self.status()
        self.journal.set_meta("status", st)
        notify(f"READY=1\nSTATUS={self.status_line(st)}\nMAINPID={os.getpid()}")
        wd = watchdog_interval()
        last_status = last_wd = 0.0
        while not self.stop.is_set():
            try:
                for path in self.watcher.due():
                    try:
                        self.spool.intake(path)
                    except Exception:
                        log.exception("intake of %s", path)
                self.handle_requests()
                now = time.monotonic()
                if now - last_status >= 1.0:
                    last_status = now
                    st = self.status()
                    self.journal.set_meta("status", st)
                    notify(f"STATUS={self.status_line(st)}")
            except Exception:  # e.g. the journal locked for too long: log and go on
                log.exception("main loop")
                self.stop.wait(1.0)
                continue
            if wd and now - last_wd >= wd:
                last_wd = now
                if self.printer.is_alive() and all(t.is_alive() for t in workers):
                    notify("WATCHDOG=1")
            # a file that is settling is due within close_grace_seconds: look again sooner
            nap = 0.2 if not self.watcher.pending() else min(
                0.2, max(0.02, self.cfg.spool.close_grace_seconds / 2))
            self.watcher.wakeup.wait(nap)
            self.watcher.wakeup.clear()
        notify("STOPPING=1\nSTATUS=stopping")
        log.info("stopping")
        self.watcher.stop()
        if self.web:
            self.web.stop()
        for t in workers:
            t.join(timeout=30)
        self.printer.join(timeout=60)
        st = self.status()
        st["running"] = False
        self.journal.set_meta("status", st)
        self.journal.close()
        return 0


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

