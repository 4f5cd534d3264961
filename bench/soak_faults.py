"""The soak's fault plan: which fault to inject, and the moment it fires.

After each dropped file a fault is drawn with probability ``rate``. Faults wait for
their moment, one at a time: a daemon kill during intake fires just after the next
file lands; one during repair, slicing or printing once a job is in that state; an
unplug once a print runs. A fault whose moment does not come within ``PATIENCE``
seconds is counted as missed. Printer faults (a board reset after N lines, line
noise, lost ``ok``s) swap the printer for one that misbehaves that way (only between
prints, so that the swap itself is not an unplug). In the calm tail of a run the daemon
is no longer killed, so that one daemon life is long enough to judge its memory.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass

from soak_procs import Processes

PATIENCE = 60.0

#: kind -> weight
KINDS = {
    "kill_daemon_intake": 2,
    "kill_daemon_repairing": 3,
    "kill_daemon_slicing": 3,
    "kill_daemon_printing": 3,
    "unplug_printing": 3,
    "printer_reset": 2,
    "printer_noise": 2,
    "printer_lost_oks": 1,
}
_PHASE = {"kill_daemon_repairing": "repairing", "kill_daemon_slicing": "slicing",
          "kill_daemon_printing": "printing", "unplug_printing": "printing"}


@dataclass
class _Pending:
    kind: str
    since: float
    fire_at: float | None = None


class FaultPlan:
    """Draws faults and fires them on ``procs`` at the right moment."""

    def __init__(self, procs: Processes, rng: random.Random, rate: float) -> None:
        self.procs = procs
        self.rng = rng
        self.rate = rate
        self.pending: list[_Pending] = []
        self.injected: dict[str, int] = {}
        self.missed: dict[str, int] = {}
        self.restart_daemon_at: float | None = None
        self.replug_at: float | None = None
        self.printers = 0

    def count(self, kind: str) -> None:
        self.injected[kind] = self.injected.get(kind, 0) + 1

    def daemon_down_on_purpose(self) -> bool:
        return self.restart_daemon_at is not None

    def after_drop(self, name: str, *, calm: bool = False) -> None:  # noqa: ARG002
        """A file was dropped: arm a pending intake kill, maybe draw a new fault.
        ``calm``: the daemon is no longer killed (its memory is being watched)."""
        now = time.monotonic()
        for pending in self.pending:
            if pending.kind == "kill_daemon_intake" and pending.fire_at is None:
                pending.fire_at = now + self.rng.uniform(0.0, 0.6)
        if calm:
            self.pending = [p for p in self.pending if not p.kind.startswith("kill_daemon")]
        if len(self.pending) < 3 and self.rng.random() < self.rate:
            kinds = [k for k in KINDS if not (calm and k.startswith("kill_daemon"))]
            kind = self.rng.choices(kinds, weights=[KINDS[k] for k in kinds])[0]
            self.pending.append(_Pending(kind, now))

    def tick(self, states: dict[str, str]) -> None:
        now = time.monotonic()
        if self.restart_daemon_at is not None and now >= self.restart_daemon_at:
            self.restart_daemon_at = None
            self.procs.start_daemon()
        if self.replug_at is not None and now >= self.replug_at:
            self.replug_at = None
            self._plug([])
        if not self.pending:
            return
        head = self.pending[0]
        busy = set(states.values())
        if head.fire_at is None:
            self._arm(head, busy, now)
        if head.fire_at is not None and now >= head.fire_at:
            self.pending.pop(0)
            if self._fire(head.kind, busy):
                self.count(head.kind)
            else:
                self.missed[head.kind] = self.missed.get(head.kind, 0) + 1
        elif now - head.since > PATIENCE:
            self.pending.pop(0)
            self.missed[head.kind] = self.missed.get(head.kind, 0) + 1

    def _arm(self, head: _Pending, busy: set[str], now: float) -> None:
        phase = _PHASE.get(head.kind)
        if phase is not None:
            if phase in busy:
                head.fire_at = now + self.rng.uniform(0.0, 0.8)
        elif head.kind.startswith("printer_"):
            if "printing" not in busy and self.replug_at is None:
                head.fire_at = now

    def _fire(self, kind: str, busy: set[str]) -> bool:
        """Inject the fault; False if its moment passed (nothing to hit)."""
        procs = self.procs
        if kind.startswith("kill_daemon"):
            if not procs.daemon_alive():
                return False
            procs.kill_daemon()
            self.restart_daemon_at = time.monotonic() + self.rng.uniform(0.3, 2.0)
            return True
        if kind == "unplug_printing":
            if procs.printer is None:
                return False
            procs.unplug_printer()
            self.replug_at = time.monotonic() + self.rng.uniform(1.0, 4.0)
            return True
        if "printing" in busy or self.replug_at is not None:
            return False
        procs.unplug_printer()
        self._plug(self._printer_options(kind))
        return True

    def _printer_options(self, kind: str) -> list[str]:
        if kind == "printer_reset":
            return ["--reset-after", str(self.rng.randrange(30, 600))]
        if kind == "printer_noise":
            return ["--corrupt", f"{self.rng.uniform(0.0002, 0.002):.5f}"]
        return ["--drop-ok", f"{self.rng.uniform(0.001, 0.004):.4f}"]

    def _plug(self, options: list[str]) -> None:
        self.printers += 1
        self.procs.start_printer(options, seed=self.rng.randrange(1 << 30))

    def cancel(self) -> None:
        """Forget what is still pending (the run is over)."""
        self.pending.clear()
        self.restart_daemon_at = None
        self.replug_at = None
