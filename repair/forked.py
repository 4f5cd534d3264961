"""One call run in a forked child, its result read back when wanted: work started ahead
(e.g. a stage that will follow a printable verdict) on the second CPU while this process
goes on; cancelled (the child killed) when it turns out not to be wanted.

The child computes ``fn()``, pickles the result to a pipe in one write and exits; a
child that fails in any way (a native crash included) has ``fn()`` run again here.
Where fork is missing, ``fn()`` runs when :meth:`Forked.result` is asked.
"""

from __future__ import annotations

import os
import pickle
import signal
from collections.abc import Callable
from typing import Any

from repair.workers import _reap, die_with_parent

__all__ = ["Forked"]


class Forked:
    """``fn()`` started in a forked child now; :meth:`result` waits for its value."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self._fn = fn
        self._child: tuple[int, int] | None = None
        if not hasattr(os, "fork"):
            return
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # child: compute, write the pickle, leave without cleanup
            code = 1
            try:
                die_with_parent()
                os.close(r)
                data = pickle.dumps(fn(), protocol=pickle.HIGHEST_PROTOCOL)
                with os.fdopen(w, "wb") as pipe:
                    pipe.write(data)
                code = 0
            finally:
                os._exit(code)
        os.close(w)
        self._child = (pid, r)

    def result(self) -> Any:
        """``fn()``'s value, from the child if it delivered it, else computed here."""
        if self._child is None:
            return self._fn()
        pid, r = self._child
        self._child = None
        with os.fdopen(r, "rb") as pipe:
            data = pipe.read()
        _reap(pid)  # its exit (unmapping a copy of this process) is not waited for
        try:  # a cut-off pickle (the child died) does not load
            return pickle.loads(data)
        except Exception:  # noqa: BLE001 -- any failure of the child: compute it here
            return self._fn()

    def cancel(self) -> None:
        """The value is not wanted: the child is killed and reaped."""
        if self._child is None:
            return
        pid, r = self._child
        self._child = None
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.close(r)
        _reap(pid)
