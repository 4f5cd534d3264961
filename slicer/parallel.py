"""Forked worker processes for the embedded slicer's independent per-layer work.

manifold3d's Python calls hold the GIL and run on one thread, so the slicer uses the
machine's cores by forking: a :class:`Worker` is a child process that inherits everything
the parent has planned (CrossSections included, copy-on-write: nothing is pickled on the
way in), runs one function and sends its picklable result back through a pipe, in one
write once it is complete. A worker that raises, is killed or crashes gives the parent a
:class:`WorkerError` naming it, never a hang: the parent reads until the pipe's end, which
comes when the child exits however it exits. Workers die with the parent (Linux
``PR_SET_PDEATHSIG``) and are always reaped, so none outlives the slice as a zombie.
"""

from __future__ import annotations

import gc
import os
import pickle
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["MAX_WORKERS", "Worker", "WorkerError", "available_cpus", "forked",
           "parse_workers"]

#: At most this many processes (the parent included) work on one slice.
MAX_WORKERS = 8


class WorkerError(RuntimeError):
    """A worker process failed: it raised, was killed, or died without an answer."""


def available_cpus() -> int:
    """CPUs this process may run on; 1 where there is no ``fork``."""
    if not hasattr(os, "fork"):
        return 1
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def parse_workers(value: str) -> int | None:
    """The profile's ``workers``: None for "auto", else a count 1..MAX_WORKERS;
    ValueError with a one-line reason otherwise."""
    text = str(value).strip().lower()
    if text == "auto":
        return None
    if not text.isdigit() or not 1 <= int(text) <= MAX_WORKERS:
        raise ValueError(f'workers must be "auto" or a whole number 1..{MAX_WORKERS}, '
                         f"got {value!r}")
    return int(text)


def _die_with_parent() -> None:
    """Linux: the kernel SIGKILLs this forked process when its parent (thread) dies."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        pass


class Worker:
    """``fn()`` run in a forked child; :meth:`result` waits for its value."""

    def __init__(self, fn: Callable[[], Any], name: str) -> None:
        self.name = name
        read_end, write_end = os.pipe()
        pid = os.fork()
        if pid == 0:  # the child: never returns into the parent's code
            code = 1
            try:
                os.close(read_end)
                _die_with_parent()
                try:
                    payload = pickle.dumps((True, fn()), protocol=pickle.HIGHEST_PROTOCOL)
                except BaseException as exc:  # noqa: BLE001 - reported to the parent
                    payload = pickle.dumps((False, f"{type(exc).__name__}: {exc}"))
                with os.fdopen(write_end, "wb") as pipe:
                    pipe.write(payload)
                code = 0
            finally:
                os._exit(code)
        os.close(write_end)
        self.pid = pid
        self._pipe = os.fdopen(read_end, "rb")
        self._status: int | None = None
        #: the child's CPU seconds and peak resident memory (MB), once it is reaped
        self.cpu_seconds = 0.0
        self.peak_mb = 0.0

    def result(self) -> Any:
        """The child's return value; WorkerError if it raised or died without one."""
        try:
            data = self._pipe.read()
        finally:
            self._pipe.close()
            self._reap()
        try:
            ok, value = pickle.loads(data)
        except Exception:  # noqa: BLE001 - cut off: the child died while writing, or before
            raise WorkerError(f"slicing worker {self.name} (pid {self.pid}) "
                              f"{self._death()} before it finished") from None
        if not ok:
            raise WorkerError(f"slicing worker {self.name} failed: {value}")
        return value

    def stop(self) -> None:
        """Kill the child (if it still runs) and reap it."""
        if self._status is None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if not self._pipe.closed:
            self._pipe.close()
        self._reap()

    def _reap(self) -> None:
        if self._status is None:
            try:
                _, self._status, usage = os.wait4(self.pid, 0)
            except ChildProcessError:
                self._status = 0
                return
            self.cpu_seconds = usage.ru_utime + usage.ru_stime
            self.peak_mb = usage.ru_maxrss / 1024.0

    def _death(self) -> str:
        status = self._status or 0
        if os.WIFSIGNALED(status):
            sig = os.WTERMSIG(status)
            try:
                name = signal.Signals(sig).name
            except ValueError:
                name = str(sig)
            return f"was killed by {name}"
        return f"exited with status {os.WEXITSTATUS(status)}"


@contextmanager
def forked(jobs: list[tuple[Callable[[], Any], str]]) -> Iterator[list[Worker]]:
    """A :class:`Worker` for each ``(fn, name)`` of ``jobs`` in order, as many as can be
    forked (none after a fork fails: no memory, process limit; the caller does the rest
    itself). A WorkerError becomes a SliceError; on the way out every worker is stopped.
    While they run, the objects that exist now are left out of garbage collection: a
    collection would touch every one of them, copying the pages the workers share. They are
    let back in on the way out unless the caller had frozen objects itself (the CLI freezes
    its start-up's): unfreezing would let those back in too, and every later collection, the
    interpreter's teardown included, walk them all again (~20 ms of CPU on a small model)."""
    from slicer.errors import SliceError

    workers: list[Worker] = []
    thaw = bool(jobs) and gc.get_freeze_count() == 0
    if jobs:
        gc.freeze()
    try:
        for fn, name in jobs:
            try:
                workers.append(Worker(fn, name))
            except OSError:
                break
        yield workers
    except WorkerError as exc:
        raise SliceError(str(exc)) from None
    finally:
        for worker in workers:
            worker.stop()
        if thaw:
            gc.unfreeze()
