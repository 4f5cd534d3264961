"""A fork server for the per-task children: the heavy imports are paid once, not per task.

Importing ``repair.pipeline`` and ``slicer.engine`` (numpy, trimesh, manifold3d, igl)
takes about a second; a task child forked from a process that already holds them
starts in a few milliseconds. :class:`ForkServer` (in the daemon) starts
``python -m daemon.forkserver`` once and asks it, over a ``SOCK_SEQPACKET`` socket
pair, for one child per task.

The server:

- imports the heavy modules with ``OPENBLAS_NUM_THREADS=1`` and checks that it has
  no other thread, so that every fork copies a single-threaded process;
- forks one child per request: the child gets its own process group (so that a cancel
  or a timeout kills it and everything it forked with one ``killpg``), dies with the
  server (``PR_SET_PDEATHSIG``), gets the request's pipe as stdout (progress lines)
  and the task's log as stderr, and runs :func:`daemon.worker.child_main`;
- reaps its children and reports each exit status back to the daemon;
- exits as soon as the daemon's end of the socket closes, which the kernel does when
  the daemon dies in any way (``kill -9`` included); its children follow it. (Not
  ``PR_SET_PDEATHSIG``: that follows the *thread* that started the server, and the
  server is started by whichever daemon thread needs it first.)

The daemon starts the server again when it has died (``kill -9``, a crash).
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
from dataclasses import dataclass, field

#: Imported once, in the server, so that no task child pays for an import: every module of
#: these packages, and the libraries they import lazily (inside functions).
PRELOAD_PACKAGES = ("repair", "slicer")
PRELOAD = ("numpy", "scipy.sparse", "scipy.sparse.csgraph", "scipy.spatial", "trimesh",
           "trimesh.exchange.ply", "manifold3d", "igl", "igl.copyleft.cgal",
           "xml.etree.ElementTree", "daemon.worker")

#: Thread pools sized by these are kept at one thread in the server (and so its children).
THREAD_POOL_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

MAX_MESSAGE = 65536
CHILD_FDS = 2  # the child's stdout (progress pipe) and stderr (the task's log)


class ForkServerDied(RuntimeError):
    """The fork server ended while a child was being started or awaited."""


@dataclass
class _Pending:
    """What the daemon waits for from the server: a start reply or an exit status."""

    event: threading.Event = field(default_factory=threading.Event)
    value: int | None = None  # the child's pid (start) or its wait status (exit)
    error: str | None = None


class ForkServer:
    """The daemon's handle on the fork server; thread-safe, started on first use."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._proc: subprocess.Popen | None = None
        self._sock: socket.socket | None = None
        self._alive = False
        self._next_id = 0
        self._starts: dict[int, _Pending] = {}
        self._exits: dict[int, _Pending] = {}

    @property
    def pid(self) -> int | None:
        """The server's pid while it runs (for tests and diagnostics)."""
        return self._proc.pid if self._proc is not None and self._alive else None

    def ensure_started(self) -> None:
        """Start the server (and wait until it has imported everything) unless it runs."""
        with self._lock:
            self._ensure_started_locked()

    def start_child(self, task: str, spec_path: str, stdout_fd: int, stderr_fd: int) -> int:
        """Fork a child running ``task`` on ``spec_path``; return its pid.

        The child's exit is awaited with :meth:`wait_child`. If the server has died (since
        the last request, or before answering this one) a new one is started, once; a child
        the dead server may have forked died with it.
        """
        message = {"task": task, "spec": spec_path}
        for attempt in (1, 2):
            pending = self._request(message, [stdout_fd, stderr_fd])
            pending.event.wait()
            if pending.error is None and pending.value is not None:
                return pending.value
            if attempt == 2:
                raise ForkServerDied(pending.error or "the fork server did not answer")
        raise AssertionError("unreachable")

    def _request(self, message: dict, fds: list[int]) -> _Pending:
        """Send one start request (starting the server if needed); its reply comes later."""
        with self._lock:
            self._ensure_started_locked()
            self._next_id += 1
            pending = _Pending()
            self._starts[self._next_id] = pending
            data = json.dumps({"id": self._next_id, **message}).encode()
            try:
                socket.send_fds(self._sock, [data], fds)
            except OSError:
                self._mark_dead_locked()  # tells ``pending`` that the server ended
        return pending

    def wait_child(self, pid: int, timeout: float | None) -> int | None:
        """The child's wait status once it has exited, else None after ``timeout``.

        Raises ForkServerDied if the server ended first (the child died with it).
        """
        with self._lock:
            pending = self._exits.setdefault(pid, _Pending())
        if not pending.event.wait(timeout):
            return None
        with self._lock:
            self._exits.pop(pid, None)
        if pending.error is not None:
            raise ForkServerDied(pending.error)
        return pending.value

    def shutdown(self) -> None:
        """Close the socket: the server exits, and so do any children it still has."""
        with self._lock:
            proc = self._proc
            self._mark_dead_locked()
        if proc is not None:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    # -- internals --------------------------------------------------------------------------
    def _ensure_started_locked(self) -> None:
        if self._alive and self._proc is not None and self._proc.poll() is None:
            return
        self._mark_dead_locked()
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        env = dict(os.environ)
        env.setdefault("MALLOC_ARENA_MAX", "2")
        # no BLAS/OpenMP thread pool in the server: a fork copies only the forking thread
        env.update({name: "1" for name in THREAD_POOL_VARIABLES})
        with theirs:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "daemon.forkserver", str(theirs.fileno()),
                 str(os.getpid())],
                pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, env=env,
                start_new_session=True)
        self._sock = ours
        ready = ours.recv(MAX_MESSAGE)  # the server says so once its imports are done
        if not ready:
            self._proc.wait()
            raise ForkServerDied(f"the fork server did not start (exit status "
                                 f"{self._proc.returncode})")
        self._alive = True
        threading.Thread(target=self._read_replies, args=(ours,), name="forkserver-replies",
                         daemon=True).start()

    def _read_replies(self, sock: socket.socket) -> None:
        while True:
            try:
                raw = sock.recv(MAX_MESSAGE)
            except OSError:
                raw = b""
            if not raw:
                break
            reply = json.loads(raw)
            with self._lock:
                if "exited" in reply:
                    pending = self._exits.setdefault(int(reply["exited"]), _Pending())
                else:
                    pending = self._starts.pop(int(reply["id"]), _Pending())
                    pending.error = reply.get("error")
                    if "pid" in reply:  # awaited from now on: if the server dies, we say so
                        self._exits.setdefault(int(reply["pid"]), _Pending())
                pending.value = reply.get("status", reply.get("pid"))
                pending.event.set()
        with self._lock:
            if self._sock is sock:
                self._mark_dead_locked()

    def _mark_dead_locked(self) -> None:
        """Forget the server; everyone still waiting on it learns that it ended."""
        self._alive = False
        if self._sock is not None:
            try:
                self._sock.shutdown(socket.SHUT_RDWR)  # wakes the reply reader
            except OSError:
                pass
            self._sock.close()
            self._sock = None
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()  # a server that stopped answering
        if self._proc is not None:
            self._proc.wait()
        for pending in [*self._starts.values(), *self._exits.values()]:
            if not pending.event.is_set():
                pending.error = "the fork server ended (it was killed or crashed)"
                pending.event.set()
        self._starts.clear()


# --- the server process -------------------------------------------------------------------

def serve(sock: socket.socket) -> None:
    """Fork a child per request until the daemon's end of ``sock`` closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the daemon's to handle
    _preload()
    threads = len(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task") else 1
    if threads != 1:
        raise SystemExit(f"fork server: {threads} threads after the imports; refusing to fork")
    wake_read, wake_write = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
    signal.set_wakeup_fd(wake_write)
    signal.signal(signal.SIGCHLD, lambda signum, frame: None)
    sock.send(b'{"ready": true}')
    selector = selectors.DefaultSelector()
    selector.register(sock, selectors.EVENT_READ)
    selector.register(wake_read, selectors.EVENT_READ)
    while True:
        for key, _ in selector.select():
            if key.fileobj is sock:
                message, fds, _flags, _addr = socket.recv_fds(sock, MAX_MESSAGE, CHILD_FDS)
                if not message:
                    return  # the daemon is gone
                _fork_child(sock, json.loads(message), fds, (wake_read, wake_write))
            else:
                while _drain(wake_read):
                    pass
        _reap(sock)


def _preload() -> None:
    import importlib
    import pkgutil

    for package in PRELOAD_PACKAGES:
        module = importlib.import_module(package)
        for info in pkgutil.iter_modules(module.__path__, prefix=f"{package}."):
            importlib.import_module(info.name)
    for name in PRELOAD:
        importlib.import_module(name)


def _drain(fd: int) -> bool:
    try:
        return bool(os.read(fd, 512))
    except BlockingIOError:
        return False


def _reap(sock: socket.socket) -> None:
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        sock.send(json.dumps({"exited": pid, "status": status}).encode())


def _fork_child(sock: socket.socket, request: dict, fds: list[int],
                server_fds: tuple[int, int]) -> None:
    if len(fds) != CHILD_FDS:
        for fd in fds:
            os.close(fd)
        sock.send(json.dumps({"id": request["id"], "error": "bad request"}).encode())
        return
    server_pid = os.getpid()
    try:
        pid = os.fork()
    except OSError as e:  # e.g. EAGAIN: too many processes
        for fd in fds:
            os.close(fd)
        sock.send(json.dumps({"id": request["id"], "error": f"cannot fork: {e}"}).encode())
        return
    if pid == 0:
        code = 70
        try:
            code = _child(sock, request, fds, server_fds, server_pid)
        finally:
            os._exit(code)
    try:
        os.setpgid(pid, pid)  # also done in the child: whichever runs first wins the race
    except OSError:
        pass  # the child already did it, or already exited
    for fd in fds:
        os.close(fd)
    sock.send(json.dumps({"id": request["id"], "pid": pid}).encode())


def _child(sock: socket.socket, request: dict, fds: list[int], server_fds: tuple[int, int],
           server_pid: int) -> int:
    """In the forked child: become a plain task process, run the task, return its status."""
    from daemon.worker import child_main
    from repair.workers import die_with_parent

    signal.set_wakeup_fd(-1)
    for signum in (signal.SIGCHLD, signal.SIGINT):
        signal.signal(signum, signal.SIG_DFL)
    os.setpgid(0, 0)
    die_with_parent()
    if os.getppid() != server_pid:
        return 70  # the server died before we could tie our life to it
    sock.close()
    for fd in server_fds:
        os.close(fd)
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    os.dup2(fds[0], 1)
    os.dup2(fds[1], 2)
    for fd in (devnull, *fds):
        os.close(fd)
    try:
        return child_main([str(request["task"]), str(request["spec"])])
    finally:
        sys.stdout.flush()
        sys.stderr.flush()


def main(argv: list[str]) -> int:
    sock = socket.socket(fileno=int(argv[0]))
    daemon_pid = int(argv[1])
    if os.getppid() != daemon_pid:
        return 0  # the daemon died while starting us
    try:
        serve(sock)
    except (BrokenPipeError, ConnectionResetError):
        pass  # the daemon is gone: so are we (and our children, PR_SET_PDEATHSIG)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
