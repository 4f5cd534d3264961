"""A time budget for the exact repair: run it in a forked child, and past the budget
pause it and try the fallback instead.

The child computes exactly what the same call computes in-process (its result comes
back through a pipe as arrays and the JSON report), so a repair that finishes within
its budget is unchanged. Past the budget the child's process group is stopped
(``SIGSTOP``: it and the workers it forked stop using the CPU) and ``fallback`` runs
here; if the fallback gives a result the child is killed, else it is resumed and its
exact result awaited -- a model the exact repair can make printable is never refused
because the fallback could not. A child that dies of a signal (a native crash) is
treated like one that ran out of time. Where ``fork`` is missing the call just runs.
"""

from __future__ import annotations

import io
import json
import os
import select
import signal
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from repair.errors import RepairError
from repair.workers import die_with_parent, write_arrays

__all__ = ["Meshed", "run_within_budget"]

#: What a repair returns here: vertices, faces and its report.
Meshed = tuple[np.ndarray, np.ndarray, dict[str, Any]]


def run_within_budget(
    exact: Callable[[], Meshed],
    budget: float,
    fallback: Callable[[str], Meshed],
) -> Meshed:
    """``exact()`` if it finishes within ``budget`` seconds; otherwise ``fallback(reason)``
    (which raises :class:`RepairError` when it cannot print the model: then ``exact()``
    is let finish after all). Errors of ``exact`` are raised here as they were there."""
    if not hasattr(os, "fork") or budget <= 0 or not np.isfinite(budget):
        return exact()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child leaves by os._exit
        os.close(r)
        _child(exact, w)
    os.close(w)
    try:
        os.setpgid(pid, pid)  # also here: a signal sent before the child ran must reach it
    except OSError:
        pass
    try:
        return _supervise(pid, r, budget, fallback)
    finally:
        _kill(pid)
        os.close(r)


def _child(exact: Callable[[], Meshed], w: int) -> None:
    """Run ``exact`` in its own process group; write its result (or error) and leave."""
    code = 1
    try:
        os.setpgid(0, 0)
        die_with_parent()
        try:
            v, f, report = exact()
            payload = {"vertices": v, "faces": f, "report": _text(json.dumps(report))}
        except BaseException as e:  # noqa: BLE001 - every error goes back to the parent
            kind = ("RepairError" if isinstance(e, RepairError)  # subclasses too
                    else "MemoryError" if isinstance(e, MemoryError) else "other")
            message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            payload = {"error": _text(json.dumps({"kind": kind, "message": message}))}
        write_arrays(w, payload)
        code = 0
    finally:
        os._exit(code)


def _text(s: str) -> np.ndarray:
    return np.frombuffer(s.encode(), dtype=np.uint8)


def _supervise(pid: int, r: int, budget: float, fallback: Callable[[str], Meshed]) -> Meshed:
    t0 = time.monotonic()
    chunks: list[bytes] = []
    done = _read_until(r, chunks, t0 + budget)
    if not done:
        _signal_group(pid, signal.SIGSTOP)
        reason = f"exact repair exceeded {budget:g} s"
        try:
            return _noted(fallback(reason), budget, None)
        except RepairError as e:
            failed = str(e)
        _signal_group(pid, signal.SIGCONT)
        _read_until(r, chunks, None)
        v, f, report = _decoded(pid, b"".join(chunks), fallback)
        return _noted((v, f, report), budget, failed)
    return _decoded(pid, b"".join(chunks), fallback)


def _read_until(r: int, chunks: list[bytes], deadline: float | None) -> bool:
    """Read the child's pipe into ``chunks`` until it closes (True) or ``deadline``
    (monotonic seconds) passes (False)."""
    while True:
        wait = None if deadline is None else deadline - time.monotonic()
        if wait is not None and wait <= 0:
            return False
        ready, _, _ = select.select([r], [], [], wait)
        if not ready:
            continue
        data = os.read(r, 1 << 20)
        if not data:
            return True
        chunks.append(data)


def _decoded(pid: int, data: bytes, fallback: Callable[[str], Meshed]) -> Meshed:
    """The child's result, or its error raised here; a child that died without one
    (a native crash) gets the fallback."""
    try:
        z = np.load(io.BytesIO(data))
        files = set(z.files)
    except (OSError, ValueError, EOFError):
        status = _reap(pid)
        return fallback(f"exact repair {status}")
    if "error" in files:
        err = json.loads(z["error"].tobytes().decode())
        if err["kind"] == "RepairError":
            raise RepairError(err["message"])
        if err["kind"] == "MemoryError":
            raise MemoryError(err["message"])
        raise RuntimeError(f"exact repair failed: {err['message']}")
    report = json.loads(z["report"].tobytes().decode())
    return z["vertices"], z["faces"], report


def _noted(result: Meshed, budget: float, fallback_failed: str | None) -> Meshed:
    """The result with its report's ``time_budget`` note."""
    v, f, report = result
    report = dict(report)
    report["time_budget"] = {"seconds": budget, "exceeded": True}
    if fallback_failed is not None:
        report["time_budget"]["fallback_failed"] = fallback_failed
        report["summary"] = (f"exact repair exceeded {budget:g} s, the fallback could not "
                             f"print it, the exact repair was let finish: {report['summary']}")
    return v, f, report


def _signal_group(pid: int, sig: int) -> None:
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _reap(pid: int) -> str:
    """Wait for the child; how it ended, in words."""
    try:
        _, status = os.waitpid(pid, 0)
    except ChildProcessError:
        return "ended"
    code = os.waitstatus_to_exitcode(status)
    if code < 0:
        try:
            return f"crashed with {signal.Signals(-code).name}"
        except ValueError:
            return f"died of signal {-code}"
    return f"ended with exit status {code} without a result"


def _kill(pid: int) -> None:
    """Kill the child's group (if still there) and reap the child."""
    _signal_group(pid, signal.SIGKILL)
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
