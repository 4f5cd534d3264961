"""Job states and the transitions allowed between them.

Happy path: queued -> repairing -> slicing -> ready -> printing -> done.
G-code files skip repair and slicing: queued -> ready.
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
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"


S = JobState

#: from-state -> the states it may move to.
ALLOWED: dict[JobState, frozenset[JobState]] = {
    S.QUEUED: frozenset({S.REPAIRING, S.READY, S.FAILED, S.CANCELLED}),
    # back to queued: redone after a daemon restart or a changed printer
    S.REPAIRING: frozenset({S.SLICING, S.QUEUED, S.FAILED, S.CANCELLED}),
    S.SLICING: frozenset({S.READY, S.QUEUED, S.FAILED, S.CANCELLED}),
    # ready -> queued: the printer's nozzle/volume changed, re-process
    S.READY: frozenset({S.PRINTING, S.QUEUED, S.FAILED, S.CANCELLED}),
    # printing -> ready: the stream never started (no line acknowledged)
    S.PRINTING: frozenset({S.DONE, S.FAILED, S.CANCELLED, S.INTERRUPTED, S.READY}),
    S.DONE: frozenset(),
    # requeue: failed/cancelled start over, interrupted is re-sent from the start
    S.FAILED: frozenset({S.QUEUED}),
    S.CANCELLED: frozenset({S.QUEUED}),
    S.INTERRUPTED: frozenset({S.READY, S.CANCELLED}),
}

ACTIVE = frozenset({S.QUEUED, S.REPAIRING, S.SLICING, S.READY, S.PRINTING})
FINAL = frozenset({S.DONE, S.FAILED, S.CANCELLED, S.INTERRUPTED})


class TransitionError(ValueError):
    """A state change that the state machine does not allow."""


def check_transition(old: JobState, new: JobState) -> None:
    """Raise TransitionError unless ``old -> new`` is allowed."""
    if new not in ALLOWED[JobState(old)]:
        raise TransitionError(f"a {old} job cannot become {new}")
