"""What the status page shows, read from the daemon: the printer, the queue and the
history (:func:`snapshot`, pushed on every change), and one job's report (:func:`job_detail`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from daemon import __version__
from daemon.journal import Job
from daemon.report import report_text
from daemon.states import ACTIVE, JobState
from daemon.web import control
from daemon.web.common import temperatures

#: How many finished jobs the page lists.
HISTORY = 50

PRINTER_FIELDS = ("state", "message", "job", "progress", "lines_done", "lines_total",
                  "connected_since")


def printer_view(backend: Any, link: Any = None) -> dict[str, Any]:
    """A printer link's status (``link``; default the first printer) with what is known
    of the printer (firmware, nozzle, build volume) and its temperatures: the live ones
    when the link reports them, else those read at connection."""
    if link is None and not backend.printers.links:
        return no_printer_view(backend)
    link = link or backend.printer
    st = link.status() or {}
    info = st.get("info") or link.last_info() or {}
    view = {"name": link.name, **{k: st.get(k) for k in PRINTER_FIELDS}}
    view.update(firmware=info.get("firmware"), machine=info.get("machine_type"),
                nozzle=info.get("nozzle_diameter"), nozzle_source=info.get("nozzle_source"),
                build_volume=info.get("build_volume"), port=str(link.printer.port))
    live = st.get("temperatures")
    view["temperatures"] = temperatures(live if live else info.get("temperatures"))
    view["temperatures_live"] = bool(live)
    return view


def no_printer_view(backend: Any) -> dict[str, Any]:
    """The printer part of the page on a node without a printer (a compute-only node of
    a farm): what the node does instead."""
    view: dict[str, Any] = {k: None for k in PRINTER_FIELDS}
    view.update(name=None, state="none", firmware=None, machine=None, nozzle=None,
                nozzle_source=None, build_volume=None, port=None, temperatures={},
                temperatures_live=False)
    farm = backend.cfg.farm
    if farm.broker:
        view["message"] = (f"compute-only node of farm {farm.name!r}: files to print go to "
                           "the farm's queue")
    return view


def job_row(backend: Any, job: Job) -> dict[str, Any]:
    """One line of the queue or the history."""
    elapsed, left = control.print_times(backend.journal, job)
    repair = job.repair_report or {}
    sliced = job.slice_summary or {}
    return {"id": job.id, "name": job.name, "source_name": job.source_name, "kind": job.kind,
            "state": str(job.state), "progress": job.progress, "reason": job.reason,
            "created": job.created, "updated": job.updated,
            "print_requested": job.print_requested, "elapsed": elapsed, "left": left,
            "repair": repair.get("summary"), "estimated_seconds": sliced.get("estimated_seconds"),
            "has_repair": bool(job.repair_report), "has_gcode": bool(_gcode_path(job)),
            # it reached the printer: something may be on the bed
            "reached_printer": bool((job.print_result or {}).get("acked_lines")),
            "printer": job.printer, "nozzle": job.nozzle, "pinned": job.pinned}


def snapshot(backend: Any) -> dict[str, Any]:
    """Everything the page's main view shows; equal snapshots mean nothing changed."""
    journal = backend.journal
    active = journal.jobs(set(ACTIVE))
    finished = [j for j in journal.jobs(limit=HISTORY + len(active)) if j.state not in ACTIVE]
    return {
        "daemon": {"version": __version__, "auto_print": backend.cfg.daemon.auto_print,
                   "spool": str(backend.cfg.spool.path)},
        "printer": printer_view(backend),  # the first printer (as before several printers)
        "printers": [printer_view(backend, link) for link in backend.printers.links],
        "queue": [job_row(backend, j) for j in active],
        "history": [job_row(backend, j) for j in reversed(finished[-HISTORY:])],
        "counts": journal.counts(),
    }


def _gcode_path(job: Job) -> str | None:
    outputs = job.outputs or {}
    for path in (outputs.get("gcode"), job.gcode_path,
                 outputs.get("input") if job.kind == "gcode" else None):
        if path and Path(path).is_file():
            return path
    return None


def job_detail(backend: Any, job: Job) -> dict[str, Any]:
    """One job's report: the row, the words of its report, the repair and slicing
    figures, its history, and which pictures exist."""
    history = backend.journal.history(job.id)
    repair = job.repair_report or {}
    return {
        **job_row(backend, job),
        "text": report_text(job, history),
        "epsilon": job.epsilon, "epsilon_source": job.epsilon_source,
        "repair_report": {k: repair.get(k) for k in ("summary", "before", "after",
                                                     "holes_closed", "path", "deviation",
                                                     "volume", "epsilon")} if repair else None,
        "slice_summary": job.slice_summary, "print_result": job.print_result,
        "history": history,
        "printer_info": job.printer_info,
        "now": time.time(),
        "views": {"mesh": job.kind == "mesh" and job.state != JobState.QUEUED
                  and bool(job.repair_report), "layers": bool(_gcode_path(job))},
    }
