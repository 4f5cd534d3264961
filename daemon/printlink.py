"""The printer side of the daemon: one thread per printer that keeps the link up
(reconnecting with back-off), queries the printer once per connection, and
streams ready jobs one at a time.

A print that stops part-way (unplugged, reset, halted, the daemon stopping) marks
its job **interrupted** with the reason; it is never re-sent by itself, only by
``preflight jobs requeue ID``. Only a stream that failed before any of the job's
lines was written to the port leaves the job ready (nothing reached the printer);
once a line is on the wire the firmware may have run it, acknowledged or not.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from typing import Any

from daemon.config import Config, PrinterConfig
from daemon.journal import Job, Journal
from daemon.pipeline import AnyEvent, Spool
from daemon.printlog import TemperatureLog, result_dict
from daemon.printport import PortOpener
from daemon.safety import UnsafeEntry, check_gcode, strip_gcode
from daemon.states import ON_PRINTER, JobState, TransitionError

log = logging.getLogger("preflight.printer")

HALF_PRINTED = ("a half-printed part may be on the bed: remove it, then run "
                "`preflight jobs requeue {id}` to print it again from the start")


class PrinterLink(PortOpener, threading.Thread):
    """Owns the printer connection; prints ready jobs with ``print_requested`` set."""

    def __init__(self, cfg: Config, journal: Journal, spool: Spool, stop: threading.Event, *,
                 printer: PrinterConfig | None = None, pool: Any = None) -> None:
        """``printer``: this link's printer (default ``cfg.printer``); ``pool``: the
        :class:`~daemon.printers.PrinterPool` it belongs to (routing, port claims)."""
        self.printer = printer or cfg.printer
        super().__init__(name=self.printer.name, daemon=True)  # link.name: the printer's
        self.pool = pool
        self._info_key = ("printer_info" if self.name == "printer"
                          else f"printer_info:{self.name}")
        self.cfg = cfg
        self.journal = journal
        self.spool = spool
        self.stop_event = stop
        self._lock = threading.Lock()
        self._status: dict[str, Any] = {"state": "starting", "port": self.printer.port}
        self._info: dict[str, Any] | None = None
        self._cancel: dict[int, threading.Event] = {}
        self._controls: dict[int, Any] = {}  # job id -> printer.control.PrintControl
        self.virtual = None
        self.host = None
        self.connections = 0
        self.wake = threading.Event()
        #: Farm mode: ``gate(job) -> bool``, asked just before a job goes to printing;
        #: False: not now (the job is left as the gate decided).
        self.gate = None

    # -- shared state ---------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        with self._lock:
            return dict(self._status)

    def _set_status(self, **kw: Any) -> None:
        with self._lock:
            self._status.update(kw)

    def last_info(self) -> dict[str, Any] | None:
        """The info of the current connection, else the last one seen (journal)."""
        with self._lock:
            if self._info is not None:
                return self._info
        return self.journal.get_meta(self._info_key)

    def idle(self) -> bool:
        """Connected and not printing."""
        with self._lock:
            return self._status.get("state") == "connected" and not self._status.get("job")

    def cancel_job(self, job_id: int) -> bool:
        with self._lock:
            cancel = self._cancel.get(job_id)
        if cancel is None:
            return False
        cancel.set()
        return True

    def control_job(self, job_id: int, action: str) -> bool:
        """Ask the running print of ``job_id`` to pause, resume or stop (M112); False
        when this thread is not printing it."""
        with self._lock:
            control = self._controls.get(job_id)
        if control is None:
            return False
        control.ask(action)
        return True

    def control_state(self, job_id: int) -> str | None:
        """``printing``, ``pausing``, ``paused`` or ``paused_by_printer``; None if not printing."""
        with self._lock:
            control = self._controls.get(job_id)
        return None if control is None else control.state

    # -- the thread -----------------------------------------------------------------------
    def run(self) -> None:
        while not self.stop_event.is_set():
            try:
                self._serve()
            except Exception:  # e.g. the journal locked for too long: log, pause, go on
                log.exception("printer thread")
                self._disconnect()
                self.stop_event.wait(1.0)
        self._disconnect()
        if self.virtual is not None:
            try:
                self.virtual.stop()
            except Exception:
                log.exception("stopping the virtual printer")

    def _serve(self) -> None:
        delay = self.printer.reconnect_min_seconds
        while not self.stop_event.is_set():
            if self.host is None:
                err = self._connect()
                if err:
                    self._set_status(state="waiting", message=err,
                                     retry_in=round(delay, 1), since=time.time())
                    log.warning("printer: %s; retrying in %.0f s", err, delay)
                    self.stop_event.wait(delay)
                    delay = min(delay * 2, self.printer.reconnect_max_seconds)
                    continue
                delay = self.printer.reconnect_min_seconds
            job = self._next_job()
            if job is None:
                if self._unplugged():
                    continue
                self.wake.wait(0.3)
                self.wake.clear()
                continue
            try:
                self._print(job)
            except Exception as e:  # never let the printer thread die
                log.exception("job %d: print failed", job.id)
                self._finish_broken(job.id, f"internal error while printing: "
                                            f"{type(e).__name__}: {e}", sent=None)
                self._disconnect()
                self.journal.release_printer(job.id, self.name)  # if it never started

    def _unplugged(self) -> bool:
        """An idle printer whose port went away (USB unplugged): drop the connection, so
        the status says so and the next connect finds it again (``port = "auto"``: on
        whatever port it comes back)."""
        port = getattr(self.host, "port", None)
        if port is None or os.path.exists(port):
            return False
        log.warning("printer: %s disappeared (unplugged?)", port)
        self._disconnect()
        self._set_status(state="waiting", message=f"{port} disappeared (unplugged?)", info=None)
        return True

    def _connect(self) -> str | None:
        """Open and handshake, query the info. Returns an error message or None."""
        from printer.errors import PrinterError
        from printer.identify import query_info

        self._set_status(state="connecting", message=None)
        host = None
        try:
            host, port = self._open_host()
            info = query_info(host, klipper_socket=self.printer.klipper_api_socket,
                              klipper_config=self.printer.klipper_config).to_dict()
        except Exception as e:  # PrinterError, OSError, or a bug: never kill the thread
            if not isinstance(e, (PrinterError, OSError)):
                log.exception("connecting to the printer")
            if host is not None:
                try:
                    host.close()
                except Exception:
                    pass
            return str(e) or type(e).__name__
        self.host = host
        self.connections += 1
        with self._lock:
            self._info = info
        self.journal.set_meta(self._info_key, info)
        self._set_status(state="connected", message=None, info=info, connected_since=time.time(),
                         connections=self.connections, retry_in=None)
        log.info("printer connected on %s: %s, nozzle %s mm (%s)", port, info.get("firmware"),
                 info.get("nozzle_diameter"), info.get("nozzle_source"))
        return None

    def _disconnect(self) -> None:
        if self.host is not None:
            try:
                self.host.close()
            except Exception:
                log.exception("closing the printer")
            self.host = None
        with self._lock:
            self._info = None
        if self.pool is not None:
            self.pool.release_ports(self.name)

    def _next_job(self) -> Job | None:
        """The oldest ready job for this printer, claimed for it in the journal (so no
        other printer takes it)."""
        for job in self.journal.jobs({JobState.READY}):
            if not job.print_requested or job.printer not in (None, self.name):
                continue
            if self.pool is not None and not self.pool.may_print(self, job):
                continue
            if job.printer == self.name or self.journal.claim_for_printer(job.id, self.name):
                return self.journal.get(job.id)
        return None

    # -- printing -------------------------------------------------------------------------
    def _print(self, job: Job) -> None:
        info = self.last_info() or {}
        if self._stale(job, info):
            return
        lines = self._checked_lines(job, info)
        if lines is None:
            return
        if self.gate is not None and not self.gate(job):
            self.wake.wait(0.5)
            return
        cancel = threading.Event()
        with self._lock:
            self._cancel[job.id] = cancel
        try:
            self.journal.transition(job.id, JobState.PRINTING, expect=JobState.READY,
                                    note=f"{len(lines)} lines on printer {self.name}",
                                    printer_info=info, progress=0.0)
        except TransitionError:
            return  # cancelled in the meantime
        self._stream(job, lines, cancel)

    def _checked_lines(self, job: Job, info: dict[str, Any]) -> list[str] | None:
        """The job's G-code lines, or None once the job has failed (unreadable, or a
        dropped G-code file the policy refuses for this printer)."""
        try:
            with open(job.gcode_path or "", encoding="utf-8", errors="replace") as f:
                lines = strip_gcode(f)
        except OSError as e:
            self.journal.transition(job.id, JobState.FAILED,
                                    reason=f"cannot read the G-code: {e.strerror}")
            self.spool.archive(job.id)
            return None
        if job.kind == "gcode":  # checked at intake, maybe before this printer was known
            try:
                check_gcode(lines, forbidden=self.cfg.safety.forbidden_gcodes,
                            allow_firmware=self.cfg.safety.allow_firmware_commands,
                            build_volume=info.get("build_volume"))
            except UnsafeEntry as e:
                self.journal.transition(job.id, JobState.FAILED, reason=str(e), note=str(e))
                self.spool.archive(job.id)
                return None
        return lines

    def _print_control(self, job: Job) -> Any:
        """The job's PrintControl: pauses and resumes are journalled as they happen."""
        from printer.control import ParkSettings, PrintControl

        def on_state(state: str, why: str) -> None:
            try:
                journal_state(state, why)
            except TransitionError as e:  # e.g. the job was ended meanwhile: keep printing
                log.warning("job %d: %s (%s)", job.id, e, why)

        def journal_state(state: str, why: str) -> None:
            if state == "paused":
                self.journal.transition(job.id, JobState.PAUSED, expect=JobState.PRINTING,
                                        note=why)
                self._set_status(state="paused", message=why)
                log.info("job %d: %s", job.id, why)
            elif state == "printing":
                current = self.journal.get(job.id)
                if current is not None and current.state == JobState.PAUSED:
                    self.journal.transition(job.id, JobState.PRINTING, expect=JobState.PAUSED,
                                            note=why)
                    log.info("job %d: %s", job.id, why)
                self._set_status(state="printing", message=None)
            else:  # waiting: M600 waits for the user at the printer
                self._set_status(message=why)
                log.info("job %d: %s", job.id, why)

        volume = (self.last_info() or {}).get("build_volume")
        control = PrintControl(ParkSettings(build_volume=volume), on_state=on_state)
        with self._lock:
            self._controls[job.id] = control
        return control

    def _stream(self, job: Job, lines: list[str], cancel: threading.Event) -> None:
        """Stream a printing job's lines; the job ends done, cancelled, failed (a firmware
        halt, an emergency stop), interrupted or broken off."""
        from printer.errors import EmergencyStopped, PrinterError, PrinterHalted, StreamCancelled

        acked = [0]
        last = [0.0]
        started = time.monotonic()
        total = len(lines)
        self._set_status(state="printing", job=job.id, progress=0.0)

        def progress(done: int, of: int) -> None:
            acked[0] = done
            now = time.monotonic()
            if now - last[0] >= 0.5 or done >= of:
                last[0] = now
                fraction = done / of if of else 1.0
                self._set_status(progress=round(fraction, 4), lines_done=done, lines_total=of)
                self.journal.update(job.id, progress=fraction, durable=False)

        temperatures = TemperatureLog(self, job.id)

        def outcome(acked_lines: int, **more: Any) -> dict[str, Any]:
            return {"acked_lines": acked_lines, "total_lines": total,
                    "seconds": time.monotonic() - started,
                    "temperatures": temperatures.summary(), **more}

        log.info("job %d: printing %d lines", job.id, total)
        control = self._print_control(job)
        try:
            result = self.host.stream(lines, progress=progress,
                                      cancel=AnyEvent(cancel, self.stop_event), control=control,
                                      temperatures=temperatures)
        except StreamCancelled as e:
            by = control.cancelled_by or ("the user" if cancel.is_set() else None)
            if by is not None:
                who = "user" if by == "the user" else by
                self._end(job.id, JobState.CANCELLED, f"cancelled by {who} during the print "
                          "(parked, cooled down, motors off); " + HALF_PRINTED.format(id=job.id),
                          outcome(acked[0], error=str(e)))
            else:
                self._end(job.id, JobState.INTERRUPTED, "the daemon was stopped during the "
                          "print (cooled down, motors off); " + HALF_PRINTED.format(id=job.id),
                          outcome(acked[0], error=str(e)))
            return
        except (PrinterHalted, EmergencyStopped) as e:
            # The firmware stopped (kill(), thermal runaway, M112): failed with its words,
            # never retried by itself; the board needs a reset, so reconnect.
            self._disconnect()
            reason = (f"{e}" + ("" if "after" in str(e) else f" after {acked[0]} of {total} "
                      "lines") + "; check the printer, then clear the bed: `preflight jobs "
                      f"requeue {job.id}` prints it again from the start")
            self._end(job.id, JobState.FAILED, reason, outcome(acked[0], error=str(e)))
            log.error("job %d: %s", job.id, reason)
            return
        except PrinterError as e:
            print_result = outcome(acked[0], error=str(e))
            self._disconnect()
            self._finish_broken(job.id, f"{e} after {acked[0]} of {total} lines",
                                sent=e.lines_sent, print_result=print_result)
            return
        finally:
            with self._lock:
                self._cancel.pop(job.id, None)
                self._controls.pop(job.id, None)
            self._set_status(state="connected" if self.host else "waiting", job=None,
                             progress=None, lines_done=None, lines_total=None, message=None,
                             temperatures=None)
        print_result = outcome(total, result=result_dict(result))
        self._end(job.id, JobState.DONE, None, print_result)
        log.info("job %d: printed %d lines in %.1f s", job.id, total, print_result["seconds"])

    def _stale(self, job: Job, info: dict[str, Any]) -> bool:
        """A mesh job sliced for another nozzle / bed than the connected printer: redo it."""
        if job.kind != "mesh" or not info:
            return False
        old = job.printer_info or {}
        why = None
        nozzle = info.get("nozzle_diameter")
        if (job.epsilon is not None and isinstance(nozzle, (int, float))
                and abs(nozzle - job.epsilon) > 1e-6):
            why = f"the printer now reports a {nozzle:g} mm nozzle (sliced for {job.epsilon:g} mm)"
        elif old and old.get("build_volume") != info.get("build_volume"):
            why = "the printer reports another build volume than the job was sliced for"
        if why is None:
            return False
        self.journal.transition(job.id, JobState.QUEUED, expect=JobState.READY, printer=None,
                                note=why + "; re-processing")
        log.info("job %d: %s; re-processing", job.id, why)
        return True

    def _end(self, job_id: int, state: JobState, reason: str | None,
             print_result: dict[str, Any]) -> None:
        self.journal.transition(job_id, state, note=reason, reason=reason,
                                print_result=print_result,
                                progress=1.0 if state == JobState.DONE else None)
        self.spool.archive(job_id)

    def _finish_broken(self, job_id: int, why: str, *, sent: int | None,
                       print_result: dict[str, Any] | None = None) -> None:
        """End a print that broke off. ``sent`` is how many of its lines reached the
        port (None: unknown, so assume the print started)."""
        job = self.journal.get(job_id)
        if job is None or job.state not in ON_PRINTER:
            return
        if sent == 0 and job.state == JobState.PRINTING:
            self.journal.transition(job_id, JobState.READY, note=f"not started: {why}",
                                    progress=None, printer=None)
            log.warning("job %d: the print did not start (%s); it stays ready", job_id, why)
            return
        reason = f"print interrupted: {why}; " + HALF_PRINTED.format(id=job_id)
        self._end(job_id, JobState.INTERRUPTED, reason, print_result or {})
        log.warning("job %d: %s", job_id, reason)
