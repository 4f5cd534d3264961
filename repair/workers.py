"""Run independent pieces of exact geometry side by side in forked processes.

libigl's CGAL calls run on one thread (``IGL_NUM_THREADS=1`` keeps them reproducible),
so independent pieces -- slabs of an intersection test, components of an arrangement --
are spread over the CPUs by forking: a child computes its jobs and writes the arrays
to a pipe, the parent computes the first share itself. A child that fails in any way
(a native crash included) has its jobs run again in the parent, and children die with
the parent. Results come back in job order, whatever the number of CPUs.
"""

from __future__ import annotations

import functools
import io
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from threadpoolctl import ThreadpoolController

__all__ = [
    "MAX_WORKERS", "balanced_shares", "blas_controller", "cpu_workers", "die_with_parent",
    "map_forked",
]

#: At most this many processes per call.
MAX_WORKERS = 4


def cpu_workers() -> int:
    """CPUs this process may use (at most :data:`MAX_WORKERS`); 1 where fork is missing."""
    if not hasattr(os, "fork"):
        return 1
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(n, MAX_WORKERS))


def die_with_parent() -> None:
    """Linux: have the kernel SIGKILL this (forked) process when its parent dies, so a
    process that is killed leaves no children behind. The kernel ties this to the parent
    *thread* that forked; elsewhere than Linux it does nothing."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def map_forked(
    fn: Callable[[Any], tuple[np.ndarray, ...]],
    jobs: Sequence[Any],
    shares: Sequence[Sequence[int]],
) -> list[tuple[np.ndarray, ...]]:
    """``[fn(job) for job in jobs]``, the jobs of ``shares[0]`` run here and those of each
    further share in a forked child. ``fn`` returns a tuple of numpy arrays."""
    out: list[tuple[np.ndarray, ...] | None] = [None] * len(jobs)
    children = []
    for share in shares[1:]:
        if not share:
            continue
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # child: run the share, write the arrays, leave without cleanup
            code = 1
            try:
                die_with_parent()
                os.close(r)
                arrays = {}
                for j in share:
                    for k, a in enumerate(fn(jobs[j])):
                        arrays[f"{j}_{k}"] = np.asarray(a)
                write_arrays(w, arrays)
                code = 0
            finally:
                os._exit(code)
        os.close(w)
        children.append((pid, r, share))
    for j in shares[0] if shares else ():
        out[j] = tuple(fn(jobs[j]))
    for pid, r, share in children:
        with os.fdopen(r, "rb") as pipe:
            data = pipe.read()
        # A child writes only once all its results are computed, and a cut-off archive
        # does not load: complete data is the success test. Its exit (unmapping a copy of
        # this process) need not be waited for here: it is reaped in the background.
        _reap(pid)
        got = None
        try:
            z = np.load(io.BytesIO(data))
            got = {j: tuple(z[f"{j}_{k}"] for k in range(_count(z.files, j))) for j in share}
        except (OSError, ValueError, KeyError, EOFError):
            got = None
        for j in share:
            out[j] = got[j] if got is not None else tuple(fn(jobs[j]))
    return [o if o is not None else tuple(fn(jobs[i])) for i, o in enumerate(out)]


def write_arrays(fd: int, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` as one ``.npz`` archive to the pipe ``fd`` and close it: a forked
    child's whole answer, in one write after everything is computed, so a parent that
    reads a cut-off archive (the child died) finds it does not load."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    with os.fdopen(fd, "wb") as pipe:
        pipe.write(buf.getvalue())


def _reap(pid: int) -> None:
    """Collect a finished child's exit status, now or (if it is still exiting) from a
    background thread, so that it leaves no zombie."""
    import threading

    try:
        done, _ = os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return
    if done == 0:
        threading.Thread(target=_wait_quietly, args=(pid,), daemon=True).start()


def _wait_quietly(pid: int) -> None:
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


def _count(names: list[str], j: int) -> int:
    prefix = f"{j}_"
    return sum(1 for n in names if n.startswith(prefix))


def balanced_shares(sizes: Sequence[int], k: int) -> list[list[int]]:
    """Jobs (by index) in ``k`` shares of about equal total size, largest jobs first."""
    shares: list[list[int]] = [[] for _ in range(max(k, 1))]
    load = [0] * len(shares)
    for j in sorted(range(len(sizes)), key=lambda i: -sizes[i]):
        s = load.index(min(load))
        shares[s].append(j)
        load[s] += sizes[j]
    return [sorted(s) for s in shares]


@functools.cache
def blas_controller() -> ThreadpoolController:
    """The process's BLAS libraries, found once: finding them walks every loaded shared
    library (2-3 ms a repair, a tenth of a 1k-triangle model's), while setting their
    thread count takes microseconds. Found after SciPy's own OpenBLAS is loaded next to
    NumPy's (:func:`_load_scipy_blas`), so both are limited."""
    _load_scipy_blas()
    return ThreadpoolController()


def _load_scipy_blas() -> None:
    """Load the OpenBLAS a SciPy wheel bundles (``scipy.libs/``) as a plain shared
    library, without importing ``scipy.linalg``: that import costs ~0.3 s of CPU (it pulls
    in ``numpy.testing`` and ``numpy.f2py``), a tenth of a command-line repair of a clean
    500k-triangle model, while the repair itself uses SciPy's BLAS only in a scan's
    fairing, if ever. When SciPy later loads the same file, the dynamic loader hands it the
    library already loaded -- the one the controller limits. A SciPy built otherwise (a
    system BLAS) is imported as before."""
    import ctypes
    import glob
    import importlib.util

    if "scipy.linalg" in sys.modules:
        return
    spec = importlib.util.find_spec("scipy")
    found = []
    if spec is not None and spec.origin:
        libs = os.path.join(os.path.dirname(os.path.dirname(spec.origin)), "scipy.libs")
        found = sorted(glob.glob(os.path.join(libs, "libscipy_openblas*.so*")))
    if found:
        try:
            ctypes.CDLL(found[0])
            return
        except OSError:
            pass
    import scipy.linalg  # noqa: F401
