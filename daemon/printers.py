"""Several printers per daemon: the pool of printer links, their classes, and routing.

A daemon drives every printer of its config (``[[printers]]`` tables, or the one
``[printer]``) with one :class:`~daemon.printlink.PrinterLink` thread each; they
print in parallel, and each job prints on exactly one printer.

Printer **classes**: printers with the same nozzle and build volume (from what each
printer reports, else its config: ``nozzle_diameter``, build volume unknown). A mesh
job is repaired and sliced for one class (ε = that class's nozzle); only printers of
that class print it.

**Routing** (:meth:`PrinterPool.route`), when a worker takes a queued mesh job:
the model's size is the axis-aligned bounding box of the *input* mesh (before repair
and orientation: thickening grows it by at most ε). A job is offered only to classes
whose build volume holds that box (an unknown build volume holds anything; the slicer
checks again). A job pinned to a nozzle (sidecar ``<name>.toml`` with ``nozzle = 0.6``,
or the spool subfolder ``nozzle-0.6/``) goes only to classes with that nozzle. Among
the rest: the first class (config order) with a free printer (connected, idle, and
more idle printers than jobs already routed to the class), else the class with the
least queued work per printer. A job that fits no printer fails with a reason naming
the sizes.

Stable interfaces (the farm builds on them):

* ``PrinterPool(cfg, journal, spool, stop)``: ``links``, ``link(name)``, ``first``,
  ``start()``, ``join(timeout)``, ``all_alive()``, ``wake_all()``;
  ``classes() -> list[PrinterClass]``, ``have_info()``, ``route(job, size) -> dict``
  (the printer info the job is processed for; raises :class:`NoPrinterFits`),
  ``may_print(link, job)``, ``status() -> list[dict]``, ``cancel_job``,
  ``control_job``, ``control_state`` (whichever link holds the job);
  ``claim_port(path, name)`` / ``release_ports(name, keep)`` (``port = "auto"``).
* Journal: ``jobs.nozzle`` (class nozzle, mm), ``jobs.pinned``, ``jobs.printer``
  (the printer that claimed it); ``Journal.claim_for_printer(job_id, name) -> bool``
  (atomic, ``UPDATE ... WHERE printer IS NULL``), ``release_printer``,
  ``queued_work()``.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import Any

from daemon.config import Config
from daemon.journal import Job, Journal
from daemon.pipeline import Spool
from daemon.printlink import PrinterLink

#: Two nozzles closer than this (mm) are the same class.
NOZZLE_TOLERANCE = 1e-6


class NoPrinterFits(ValueError):
    """No printer can take the job; the message says why (sizes, nozzles)."""


@dataclass(frozen=True)
class PrinterClass:
    """Printers that take the same sliced G-code: one nozzle, one build volume."""

    nozzle: float
    build_volume: tuple[float, float, float] | None
    printers: tuple[str, ...]
    info: dict[str, Any]          # what the class's jobs are repaired and sliced for
    known: bool                   # False: from the config only (never connected yet)

    def fits(self, size: tuple[float, float, float] | None) -> bool:
        if size is None or self.build_volume is None:
            return True
        return all(s <= v + 1e-9 for s, v in zip(size, self.build_volume, strict=True))

    def describe(self) -> str:
        volume = (" x ".join(f"{v:g}" for v in self.build_volume) + " mm"
                  if self.build_volume else "build volume unknown")
        return f"{', '.join(self.printers)}: {self.nozzle:g} mm nozzle, {volume}"


def same_nozzle(a: float | None, b: float | None) -> bool:
    return a is not None and b is not None and abs(a - b) <= NOZZLE_TOLERANCE


def _volume(info: dict[str, Any]) -> tuple[float, float, float] | None:
    volume = info.get("build_volume")
    return tuple(float(v) for v in volume) if volume else None  # type: ignore[return-value]


def format_size(size: tuple[float, float, float]) -> str:
    return " x ".join(f"{v:.1f}" for v in size) + " mm"


def describe_printer(entry: dict[str, Any]) -> str:
    """One line of ``preflight status`` for one entry of the status's ``printers``:
    name, port, firmware, nozzle, build volume, state and current job."""
    info = entry.get("info") or {}
    volume = info.get("build_volume")
    what = (f"{info.get('firmware') or '?'}, nozzle {info.get('nozzle_diameter')} mm, build "
            f"volume {' x '.join(f'{v:g}' for v in volume) + ' mm' if volume else 'unknown'}"
            if info else "not connected yet")
    state = str(entry.get("state"))
    if entry.get("job"):
        state += f" job {entry['job']} {100 * (entry.get('progress') or 0):.0f}%"
    if entry.get("message"):
        state += f" ({entry['message']})"
    return f"printer {entry.get('name')}: {entry.get('port')} - {what}; {state}"


class PrinterPool:
    """The printer links of one daemon, their classes, and which job goes where."""

    def __init__(self, cfg: Config, journal: Journal, spool: Spool,
                 stop: threading.Event) -> None:
        self.cfg = cfg
        self.journal = journal
        self._ports: dict[str, str] = {}     # real path of a port -> the printer using it
        self._ports_lock = threading.Lock()
        self._route_lock = threading.Lock()  # one routing decision at a time
        self.links = [PrinterLink(cfg, journal, spool, stop, printer=pc, pool=self)
                      for pc in cfg.all_printers]

    # -- the links ------------------------------------------------------------------------
    @property
    def first(self) -> PrinterLink:
        return self.links[0]

    def link(self, name: str) -> PrinterLink | None:
        return next((link for link in self.links if link.name == name), None)

    def start(self) -> None:
        for link in self.links:
            link.start()

    def join(self, timeout: float) -> None:
        for link in self.links:
            link.join(timeout=timeout)

    def all_alive(self) -> bool:
        return all(link.is_alive() for link in self.links)

    def wake_all(self) -> None:
        for link in self.links:
            link.wake.set()

    def status(self) -> list[dict[str, Any]]:
        return [{"name": link.name, **link.status()} for link in self.links]

    def cancel_job(self, job_id: int) -> bool:
        return any(link.cancel_job(job_id) for link in self.links)

    def control_job(self, job_id: int, action: str) -> bool:
        return any(link.control_job(job_id, action) for link in self.links)

    def control_state(self, job_id: int) -> str | None:
        for link in self.links:
            state = link.control_state(job_id)
            if state is not None:
                return state
        return None

    # -- ports (port = "auto") ------------------------------------------------------------
    def claim_port(self, path: str, name: str) -> str | None:
        """Reserve ``path`` for printer ``name``; the other printer's name if it has it."""
        real = os.path.realpath(path)
        with self._ports_lock:
            owner = self._ports.setdefault(real, name)
        return None if owner == name else owner

    def release_ports(self, name: str, keep: str | None = None) -> None:
        """Give back the ports ``name`` reserved, except ``keep`` (the one it uses)."""
        kept = os.path.realpath(keep) if keep else None
        with self._ports_lock:
            for real, owner in list(self._ports.items()):
                if owner == name and real != kept:
                    del self._ports[real]

    # -- classes and routing --------------------------------------------------------------
    def needs_size(self) -> bool:
        """Whether routing looks at the model's size (only with several printers)."""
        return len(self.links) > 1

    def have_info(self) -> bool:
        """Whether any printer's info is known (mesh jobs wait for one)."""
        return any(link.last_info() for link in self.links)

    def classes(self) -> list[PrinterClass]:
        """The printer classes in config order (of each class's first printer)."""
        grouped: dict[tuple[Any, ...], list[Any]] = {}
        for link in self.links:
            info = link.last_info()
            known = bool(info)
            if not info:
                info = {"nozzle_diameter": link.printer.nozzle_diameter,
                        "nozzle_source": "config", "build_volume": None}
            nozzle = float(info.get("nozzle_diameter") or link.printer.nozzle_diameter)
            key = (round(nozzle, 6), _volume(info), known)
            grouped.setdefault(key, [info, []])[1].append(link.name)
        return [PrinterClass(nozzle=key[0], build_volume=key[1], printers=tuple(names),
                             info=info, known=key[2])
                for key, (info, names) in grouped.items()]

    def route(self, job: Job, size: tuple[float, float, float] | None) -> dict[str, Any]:
        """The printer info (a class's) to repair and slice ``job`` for, recorded as the
        job's nozzle class; NoPrinterFits when no printer can take it. ``size``: the
        model's bounding box (mm)."""
        classes = self.classes()
        if job.pinned:
            pinned = [c for c in classes if same_nozzle(c.nozzle, job.nozzle)]
            if not pinned:
                raise NoPrinterFits(
                    f"pinned to a {job.nozzle:g} mm nozzle, but no printer has one ("
                    + "; ".join(c.describe() for c in classes) + ")")
            classes = pinned
        fitting = [c for c in classes if c.fits(size)]
        if not fitting:
            assert size is not None
            what = f" with a {job.nozzle:g} mm nozzle" if job.pinned else ""
            raise NoPrinterFits(f"the model is {format_size(size)}; it fits no printer{what} ("
                                + "; ".join(c.describe() for c in classes) + ")")
        known = [c for c in fitting if c.known] or fitting
        with self._route_lock:  # the choice counts as queued work before the next one
            chosen = self._least_busy(known, job.id)
            self.journal.update(job.id, nozzle=chosen.nozzle)
        return chosen.info

    def _least_busy(self, classes: list[PrinterClass], job_id: int) -> PrinterClass:
        work = self.journal.queued_work(exclude=job_id)
        idle = {link.name for link in self.links if link.idle()}

        def queued(c: PrinterClass) -> int:
            return sum(n for nozzle, n in work.items() if same_nozzle(nozzle, c.nozzle))

        for c in classes:
            if sum(name in idle for name in c.printers) > queued(c):
                return c
        return min(classes, key=lambda c: queued(c) / len(c.printers))

    def may_print(self, link: PrinterLink, job: Job) -> bool:
        """Whether ``link``'s printer may take ``job``: its class's; any printer for a
        job routed to no class (G-code not pinned; a job from an older journal), or a
        mesh job of a class no printer has any more (a nozzle was changed: the printer
        taking it finds it stale and has it processed again, routed anew)."""
        if len(self.links) == 1 or job.nozzle is None:
            return True
        return self._of_class(link, job) or (job.kind == "mesh" and not any(
            self._of_class(other, job) for other in self.links))

    @staticmethod
    def _of_class(link: PrinterLink, job: Job) -> bool:
        info = link.last_info() or {}
        nozzle = info.get("nozzle_diameter") or link.printer.nozzle_diameter
        if not same_nozzle(float(nozzle), job.nozzle):
            return False
        if job.kind != "mesh":
            return True
        sliced_for = _volume(job.printer_info or {})
        return sliced_for is None or sliced_for == _volume(info)
