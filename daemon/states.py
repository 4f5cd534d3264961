"""Job states and the transitions allowed between them.

Happy path: queued -> repairing -> slicing -> ready -> printing -> done.
G-code files skip repair and slicing: queued -> ready.
A print can be paused (by the user, or by the printer: a filament runout) and resumed:
printing <-> paused. A paused print ends like a printing one (cancelled, failed,
interrupted); a daemon restart finds it interrupted (the printer may have reset or
cooled down meanwhile: its position is not to be trusted).
Terminal-ish states: failed, cancelled, interrupted (a print that stopped part-way:
a half-printed part may be on the bed; it is re-sent only by an explicit requeue).
"""

from __future__ import annotations

from enum import StrEnum


class JobState(StrEnum):
    QUEUED = "queued"
    REPAIRING = "repairing"
    SLICING = "slicing"
    READY = "ready"
    PRINTING = "printing"
    PAUSED = "paused"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"


# the table below reads better with the bare state names
QUEUED, REPAIRING, SLICING, READY, PRINTING, PAUSED, DONE, FAILED, CANCELLED, INTERRUPTED = \
    JobState

#: from-state -> the states it may move to.
ALLOWED: dict[JobState, frozenset[JobState]] = {
    QUEUED: frozenset({REPAIRING, READY, FAILED, CANCELLED}),
    # back to queued: redone after a daemon restart or a changed printer
    REPAIRING: frozenset({SLICING, QUEUED, FAILED, CANCELLED}),
    SLICING: frozenset({READY, QUEUED, FAILED, CANCELLED}),
    # ready -> queued: the printer's nozzle/volume changed, re-process
    READY: frozenset({PRINTING, QUEUED, FAILED, CANCELLED}),
    # printing -> ready: the stream never started (no line acknowledged)
    PRINTING: frozenset({DONE, FAILED, CANCELLED, INTERRUPTED, READY, PAUSED}),
    PAUSED: frozenset({PRINTING, FAILED, CANCELLED, INTERRUPTED}),
    DONE: frozenset(),
    # requeue: failed/cancelled start over, interrupted is re-sent from the start
    FAILED: frozenset({QUEUED}),
    CANCELLED: frozenset({QUEUED}),
    INTERRUPTED: frozenset({READY, CANCELLED}),
}

ACTIVE = frozenset({QUEUED, REPAIRING, SLICING, READY, PRINTING, PAUSED})
#: A print under way: its job holds the printer.
ON_PRINTER = frozenset({PRINTING, PAUSED})
FINAL = frozenset({DONE, FAILED, CANCELLED, INTERRUPTED})


class TransitionError(ValueError):
    """A state change that the state machine does not allow."""


def check_transition(old: JobState, new: JobState) -> None:
    """Raise TransitionError unless ``old -> new`` is allowed."""
    if new not in ALLOWED[JobState(old)]:
        raise TransitionError(f"a {old} job cannot become {new}")
