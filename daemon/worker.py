"""Repair and slicing in a child process, with a timeout and a memory cap.

The daemon never runs native geometry code in its own process: a segfault, an
endless loop or an out-of-memory in ``repair`` or ``slicer`` must fail one job,
not the daemon. :func:`run_task` has the fork server (:mod:`daemon.forkserver`,
which has already imported the heavy modules) fork one child per task:

- the child limits its address space with ``resource.setrlimit(RLIMIT_AS)`` before
  running the task, and dies with the fork server, which dies with the daemon, so a
  ``kill -9`` of the daemon leaves no orphan;
- progress comes back as JSON lines on the child's stdout (a pipe to the daemon);
- the result (or a one-line error) is written as JSON to the spec's ``result`` path;
- the daemon kills the child's process group (the child and anything it forked) on
  timeout or cancel, and turns a death by signal into a reason (``crashed with SIGSEGV``).

Test hook (documented, used by the end-to-end tests): the environment variable
``PREFLIGHT_TEST_WORKER_FAULT=TASK:ACTION[:NAME][,...]`` (read by the daemon when it
starts a task) makes the child for TASK (``repair`` or ``slice``) whose job's file
name contains NAME do ACTION: ``abort`` (``os.abort()``, a native crash), ``hang`` (an
endless loop) or ``oom`` (allocate until the memory cap stops it). It is ignored otherwise.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from daemon.forkserver import ForkServer, ForkServerDied

FAULT_ENV = "PREFLIGHT_TEST_WORKER_FAULT"
POLL_SECONDS = 0.1

#: The daemon's one fork server, started on first use (or by :func:`warm_up`).
FORK_SERVER = ForkServer()


class WorkerFailed(Exception):
    """The task failed; ``str()`` is a one-line human reason."""


class WorkerCancelled(Exception):
    """The task was stopped because its job was cancelled or the daemon is stopping."""


def warm_up() -> None:
    """Start the fork server now, so that the first job does not wait for its imports."""
    FORK_SERVER.ensure_started()


def run_task(task: str, spec: dict[str, Any], *, work_dir: Path, timeout: float,
             memory_mb: int, progress: Callable[[str, float], None] | None = None,
             cancel: threading.Event | None = None,
             on_start: Callable[[int], None] | None = None) -> Any:
    """Run ``task`` ("repair" | "slice") in a child; return its result or raise.

    ``timeout`` in seconds, ``memory_mb`` caps the child's address space.
    Raises WorkerFailed (with the reason) or WorkerCancelled.
    """
    work_dir.mkdir(parents=True, exist_ok=True)
    result_path = work_dir / f"{task}.result.json"
    spec_path = work_dir / f"{task}.spec.json"
    log_path = work_dir / f"{task}.log"
    spec = dict(spec, memory_mb=memory_mb, result=str(result_path),
                test_fault=os.environ.get(FAULT_ENV, ""))
    result_path.unlink(missing_ok=True)
    spec_path.write_text(json.dumps(spec))  # read by the child only once it is complete
    progress_read, progress_write = os.pipe()
    try:
        with open(log_path, "ab") as log:
            pid = FORK_SERVER.start_child(task, str(spec_path), progress_write, log.fileno())
    except ForkServerDied as e:
        os.close(progress_read)
        raise WorkerFailed(f"{task} could not be started: {e}") from None
    finally:
        os.close(progress_write)
    if on_start:
        on_start(pid)
    reader = threading.Thread(target=_pump_progress,
                              args=(os.fdopen(progress_read, "rb"), progress),
                              name=f"{task}-progress", daemon=True)
    reader.start()
    status, stopped = _supervise(task, pid, timeout, cancel)
    reader.join(timeout=2)
    if stopped == "cancelled":
        raise WorkerCancelled(f"{task} stopped")
    if stopped:
        raise WorkerFailed(stopped)
    return _outcome(task, status, result_path, log_path, memory_mb)


def _pump_progress(pipe: IO[bytes], progress: Callable[[str, float], None] | None) -> None:
    """Hand the child's JSON progress lines to ``progress`` until the pipe closes."""
    with pipe:
        for raw in pipe:
            try:
                message = json.loads(raw)
            except ValueError:
                continue
            if progress and isinstance(message, dict) and "stage" in message:
                try:
                    progress(str(message["stage"]), float(message.get("fraction", 0.0)))
                except Exception:  # a progress consumer must not break the task
                    pass


def _supervise(task: str, pid: int, timeout: float, cancel: threading.Event | None
               ) -> tuple[int | str | None, str | None]:
    """Wait for the child; kill its group on cancel or timeout.

    Returns (its wait status, or a reason why there is none; why it was stopped:
    "cancelled", a timeout reason, or None).
    """
    deadline = time.monotonic() + timeout
    stopped: str | None = None
    while True:
        try:
            status = FORK_SERVER.wait_child(pid, POLL_SECONDS)
        except ForkServerDied as e:
            return str(e), stopped
        if status is not None:
            return status, stopped
        if stopped:
            continue
        if cancel is not None and cancel.is_set():
            stopped = "cancelled"
        elif time.monotonic() > deadline:
            stopped = f"{task} took longer than the limit of {timeout:g} s and was stopped"
        if stopped:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _outcome(task: str, status: int | str | None, result_path: Path, log_path: Path,
             memory_mb: int) -> Any:
    """The task's result from its result file, else a reason from how the child ended."""
    try:
        result = json.loads(result_path.read_text())
    except (OSError, ValueError):
        result = None
    if isinstance(result, dict) and result.get("ok"):
        return result.get("result")
    if isinstance(result, dict) and result.get("error"):
        raise WorkerFailed(str(result["error"]))
    if isinstance(status, str):
        raise WorkerFailed(f"{task} stopped: {status}; see {log_path}")
    code = os.waitstatus_to_exitcode(status) if status is not None else None
    if code is not None and code < 0:
        hint = ""
        if -code == signal.SIGKILL:
            hint = f" (possibly out of memory; the cap is {memory_mb} MB)"
        raise WorkerFailed(f"{task} crashed with {_signame(-code)}{hint}; see {log_path}")
    tail = _tail(log_path)
    raise WorkerFailed(f"{task} failed (exit status {code}){': ' + tail if tail else ''}")


def _signame(n: int) -> str:
    try:
        return signal.Signals(n).name
    except ValueError:
        return f"signal {n}"


def _tail(path: Path) -> str:
    try:
        lines = [x for x in path.read_text(errors="replace").splitlines() if x.strip()]
    except OSError:
        return ""
    return lines[-1][:200] if lines else ""


# --- the child (forked by the fork server) -----------------------------------------------

def _limit_memory(memory_mb: int) -> None:
    import resource

    limit = int(memory_mb) * 1024 * 1024
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def _apply_test_fault(task: str, in_path: str, faults: str) -> None:
    for spec in faults.split(","):
        parts = spec.strip().split(":", 2)
        if len(parts) < 2 or parts[0] != task:
            continue
        if len(parts) == 3 and parts[2] not in os.path.basename(in_path):
            continue
        _fault(parts[1])


def _fault(action: str) -> None:
    if action == "abort":
        os.abort()
    elif action == "hang":
        while True:
            time.sleep(1)
    elif action == "oom":
        hog = []
        while True:
            hog.append(bytearray(64 * 1024 * 1024))


def _emit(stage: str, fraction: float) -> None:
    sys.stdout.write(json.dumps({"stage": stage, "fraction": round(float(fraction), 4)}) + "\n")
    sys.stdout.flush()


def _task_repair(spec: dict[str, Any]) -> Any:
    from daemon.config import RepairConfig
    from repair.files import repair_file

    # A clean or surface the spec leaves out is the config schema's default (the daemon
    # always sends both), not the library's (whose surface default is "off").
    default = RepairConfig()
    return repair_file(spec["in"], spec["out"], epsilon=float(spec["epsilon"]),
                       report_path=spec.get("report"), max_bytes=spec.get("max_bytes"),
                       max_triangles=spec.get("max_triangles"), progress=_emit,
                       clean=spec.get("clean", default.clean),
                       surface=spec.get("surface", default.surface),
                       time_budget=spec.get("time_budget"))


def _task_slice(spec: dict[str, Any]) -> Any:
    from slicer.engine import slice_file
    from slicer.profile import Profile

    bv = spec.get("build_volume")
    base = Profile.for_printer(
        nozzle_diameter=float(spec["nozzle"]),
        build_volume=tuple(bv) if bv else None,
        filament_diameter=float(spec.get("filament_diameter") or 1.75),
        flavour=spec.get("flavour") or "marlin")
    profile = base.with_overrides(spec.get("overrides") or {})
    summary = slice_file(spec["in"], spec["out"], profile, progress=_emit)
    return {"summary": summary, "profile": profile.to_dict()}


def _task_measure(spec: dict[str, Any]) -> Any:
    """The size (mm) of the model's axis-aligned bounding box, for routing it."""
    from repair.io import load_mesh

    mesh = load_mesh(spec["in"], max_bytes=spec.get("max_bytes"),
                     max_triangles=spec.get("max_triangles"))
    vertices = mesh.vertices
    if not len(vertices):
        return {"size": None}
    return {"size": [float(x) for x in vertices.max(axis=0) - vertices.min(axis=0)]}


TASKS = {"repair": _task_repair, "slice": _task_slice, "measure": _task_measure}


def child_main(argv: list[str]) -> int:
    """Run the task ``argv[0]`` on the spec file ``argv[1]``; return the exit status."""
    task, spec_path = argv[0], argv[1]
    spec = json.loads(Path(spec_path).read_text())
    _limit_memory(int(spec["memory_mb"]))
    result_path = Path(spec["result"])

    from repair.io import write_atomic  # preloaded by the fork server

    def finish(payload: dict[str, Any]) -> None:
        write_atomic(result_path, [json.dumps(payload, default=str).encode()])

    try:
        _apply_test_fault(task, spec.get("job_name") or spec.get("in", ""),
                          str(spec.get("test_fault") or ""))
        result = TASKS[task](spec)
    except MemoryError:
        finish({"ok": False, "error": f"{task} ran out of memory (the cap is "
                                      f"{spec['memory_mb']} MB, [limits] {task}_memory_mb)"})
        return 3
    except Exception as e:  # every failure becomes the job's reason
        import traceback

        traceback.print_exc()
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        known = type(e).__name__ in ("RepairError", "MeshReadError", "SliceError",
                                     "ProfileError")
        finish({"ok": False, "error": msg if known else f"{task} failed: {type(e).__name__}: "
                                                        f"{msg}"})
        return 3
    finish({"ok": True, "result": result})
    return 0
