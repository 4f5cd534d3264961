"""Repair and slicing in a child process, with a timeout and a memory cap.

The daemon never runs native geometry code in its own process: a segfault, an
endless loop or an out-of-memory in ``repair`` or ``slicer`` must fail one job,
not the daemon. :func:`run_task` starts ``python -m daemon.worker TASK SPEC``:

- the child limits its address space with ``resource.setrlimit(RLIMIT_AS)``
  before importing anything heavy, and asks the kernel to kill it when the
  daemon dies (``PR_SET_PDEATHSIG``), so a ``kill -9`` of the daemon leaves no
  orphan;
- progress comes back as JSON lines on the child's stdout;
- the result (or a one-line error) is written as JSON to the spec's ``result`` path;
- the parent kills the child's process group on timeout or cancel, and turns a
  death by signal into a reason (``crashed with SIGSEGV``).

Test hook (documented, used by the end-to-end tests): the environment variable
``PREFLIGHT_TEST_WORKER_FAULT=TASK:ACTION[:NAME][,...]`` makes the child for TASK
(``repair`` or ``slice``) whose job's file name contains NAME do ACTION:
``abort`` (``os.abort()``, a native crash), ``hang`` (an endless loop) or
``oom`` (allocate until the memory cap stops it). It is ignored otherwise.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

FAULT_ENV = "PREFLIGHT_TEST_WORKER_FAULT"


class WorkerFailed(Exception):
    """The task failed; ``str()`` is a one-line human reason."""


class WorkerCancelled(Exception):
    """The task was stopped because its job was cancelled or the daemon is stopping."""


def run_task(task: str, spec: dict[str, Any], *, work_dir: Path, timeout: float,
             memory_mb: int, progress: Callable[[str, float], None] | None = None,
             cancel: threading.Event | None = None,
             on_start: Callable[[int], None] | None = None) -> Any:
    """Run ``task`` ("repair" | "slice") in a child; return its result or raise.

    ``timeout`` in seconds, ``memory_mb`` caps the child's address space.
    Raises WorkerFailed (with the reason) or WorkerCancelled.
    """
    work_dir.mkdir(parents=True, exist_ok=True)
    spec = dict(spec, memory_mb=memory_mb, parent_pid=os.getpid())
    spec_path = work_dir / f"{task}.spec.json"
    result_path = work_dir / f"{task}.result.json"
    spec["result"] = str(result_path)
    result_path.unlink(missing_ok=True)
    spec_path.write_text(json.dumps(spec))
    env = dict(os.environ)
    env.setdefault("MALLOC_ARENA_MAX", "2")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    log_path = work_dir / f"{task}.log"
    with open(log_path, "ab") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "daemon.worker", task, str(spec_path)],
            stdout=subprocess.PIPE, stderr=log, stdin=subprocess.DEVNULL, env=env,
            start_new_session=True, close_fds=True)
    if on_start:
        on_start(proc.pid)

    def pump() -> None:
        assert proc.stdout is not None
        for raw in proc.stdout:
            try:
                msg = json.loads(raw)
            except ValueError:
                continue
            if progress and isinstance(msg, dict) and "stage" in msg:
                try:
                    progress(str(msg["stage"]), float(msg.get("fraction", 0.0)))
                except Exception:  # a progress consumer must not break the task
                    pass

    reader = threading.Thread(target=pump, name=f"{task}-progress", daemon=True)
    reader.start()
    deadline = time.monotonic() + timeout
    why: str | None = None
    cancelled = False
    while True:
        try:
            proc.wait(timeout=0.1)
            break
        except subprocess.TimeoutExpired:
            pass
        if cancel is not None and cancel.is_set():
            cancelled = True
        elif time.monotonic() > deadline:
            why = f"{task} took longer than the limit of {timeout:g} s and was stopped"
        if cancelled or why:
            _kill_group(proc)
            break
    reader.join(timeout=2)
    if proc.stdout:
        proc.stdout.close()
    rc = proc.returncode
    if cancelled:
        raise WorkerCancelled(f"{task} stopped")
    if why:
        raise WorkerFailed(why)
    result: dict[str, Any] | None = None
    try:
        result = json.loads(result_path.read_text())
    except (OSError, ValueError):
        result = None
    if result is not None and result.get("ok"):
        return result.get("result")
    if result is not None and result.get("error"):
        raise WorkerFailed(str(result["error"]))
    if rc is not None and rc < 0:
        sig = _signame(-rc)
        hint = ""
        if -rc in (signal.SIGKILL,):
            hint = f" (possibly out of memory; the cap is {memory_mb} MB)"
        raise WorkerFailed(f"{task} crashed with {sig}{hint}; see {log_path}")
    tail = _tail(log_path)
    raise WorkerFailed(f"{task} failed (exit status {rc}){': ' + tail if tail else ''}")


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        pass


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


# --- the child ---------------------------------------------------------------------------

def _die_with_parent(parent_pid: int) -> None:
    """Ask Linux to SIGKILL us when the daemon dies; exit if it already has."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:
        os._exit(70)


def _limit_memory(memory_mb: int) -> None:
    import resource

    limit = int(memory_mb) * 1024 * 1024
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def _apply_test_fault(task: str, in_path: str) -> None:
    for spec in os.environ.get(FAULT_ENV, "").split(","):
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
    from repair.pipeline import repair_file

    return repair_file(spec["in"], spec["out"], epsilon=float(spec["epsilon"]),
                       report_path=spec.get("report"), max_bytes=spec.get("max_bytes"),
                       max_triangles=spec.get("max_triangles"), progress=_emit)


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


TASKS = {"repair": _task_repair, "slice": _task_slice}


def child_main(argv: list[str]) -> int:
    task, spec_path = argv[0], argv[1]
    spec = json.loads(Path(spec_path).read_text())
    _die_with_parent(int(spec["parent_pid"]))
    _limit_memory(int(spec["memory_mb"]))
    result_path = Path(spec["result"])

    def finish(payload: dict[str, Any]) -> None:
        tmp = result_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(payload, default=str))
        os.replace(tmp, result_path)

    try:
        _apply_test_fault(task, spec.get("job_name") or spec.get("in", ""))
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


if __name__ == "__main__":
    sys.exit(child_main(sys.argv[1:]))
