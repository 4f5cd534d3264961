"""Fault injection for the virtual printer."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Faults:
    """Fault injection for the virtual printer.

    corrupt: probability that a host->printer byte is replaced by another random
    byte (never by a line terminator: a noise-made newline defeats the Marlin line
    protocol itself, not the host). drop_ok: probability that the ``ok`` of an
    executed command is lost. busy_seconds: G28/G29 block for this many real seconds,
    sending ``echo:busy: processing`` every ``keepalive`` seconds. reset_after /
    disconnect_after: after this many executed numbered lines the board resets
    (prints ``start``) / the port hangs up. reconnect_after: seconds after a
    disconnect the printer comes back on a new pty (the link is re-pointed).
    garbage: every byte sent to the host is noise (what a wrong baud rate looks like).
    events: (N, what) pairs: after N executed numbered lines the firmware does ``what``:
    ``kill`` (a kill() halt), ``thermal_runaway`` (Marlin's runaway error, then the halt),
    ``runout:S`` (a filament runout: it pauses itself with ``//action:paused``, waits S
    real seconds for the user with busy keep-alives, then ``//action:resumed``), or a line
    starting with ``//`` sent as it is (``//action:cancel``, ``//action:pause``).
    drop_ok_at: line numbers whose ``ok`` is lost after they ran (a deterministic
    lost ``ok``, e.g. next to a heat-up).
    """

    corrupt: float = 0.0
    drop_ok: float = 0.0
    busy_seconds: float = 0.0
    reset_after: int | None = None
    disconnect_after: int | None = None
    reconnect_after: float | None = None
    garbage: bool = False
    seed: int = 1
    events: tuple[tuple[int, str], ...] = ()
    drop_ok_at: frozenset[int] = frozenset()

