"""Waiting on several stop signals at once (a job's own cancel and the daemon's stop)."""

from __future__ import annotations

import threading
import time


class AnyEvent:
    """Duck-typed ``threading.Event`` that is set when any of the given events is."""

    def __init__(self, *events: threading.Event) -> None:
        self.events = events

    def is_set(self) -> bool:
        return any(e.is_set() for e in self.events)

    def wait(self, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.monotonic() + timeout
        while not self.is_set():
            if end is not None and time.monotonic() >= end:
                return False
            time.sleep(0.05)
        return True
