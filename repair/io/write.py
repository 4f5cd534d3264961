"""Mesh files out: binary STL, and the project's one atomic file writer."""

from __future__ import annotations

import errno
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from repair.io.base import STL_DTYPE


def face_normals32(vertices32: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals (float32, (m, 3)) of the triangles; zero for degenerate ones."""
    return _triangle_normals32(np.asarray(vertices32)[faces])


def _triangle_normals32(tri: np.ndarray) -> np.ndarray:
    """Unit normals (float32, (m, 3)) of triangles given by corners (m, 3, 3), computed
    in float64; zero for degenerate ones."""
    a = tri[:, 0].astype(np.float64)
    n = np.cross(tri[:, 1] - a, tri[:, 2] - a)
    length = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(length > 0, n / length, 0.0)
    return n.astype(np.float32)


def write_stl(path: str | os.PathLike[str], vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a binary STL (float32 coordinates in mm, per-face unit normals).

    The file is written to a temporary name in the same folder and renamed into place, so
    a reader never sees a half-written file. The 80-byte header never starts with
    ``solid`` (which would confuse ASCII detection in other tools).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("face indices out of range")
    # (m, 3, 3): one gather of 12-byte rows, shared by corners and normals
    v32 = np.ascontiguousarray(v, dtype=np.float32)
    tri = v32.view(np.dtype((np.void, 12))).reshape(-1)[f].view(np.float32).reshape(-1, 3, 3)
    rec = np.empty(len(f), dtype=STL_DTYPE)
    rec["v"] = tri
    rec["normal"] = _triangle_normals32(tri)
    rec["attr"] = 0
    header = b"binary STL written by preflight (units: mm)".ljust(80, b" ")
    count = np.uint32(len(f)).tobytes()
    write_atomic(path, [header, count, rec.tobytes()])


Chunks = bytes | str | Iterable[bytes | str]


@contextmanager
def atomic_path(path: str | os.PathLike[str], *, suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a fresh, empty temporary file beside ``path``; when the block ends without an
    error, make it ``path`` durably and atomically.

    For content another program writes (an external slicer's ``--output``). The file is
    created like any new file (mode 0666 minus the umask, not ``mkstemp``'s 0600). On a
    clean exit: fsync the file, rename it over ``path``, fsync the folder. On any error
    (including KeyboardInterrupt) the temporary file is removed and ``path`` is untouched.
    """
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp, fd = _create_beside(out, suffix)
    os.close(fd)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, out)
    except BaseException:
        _remove_quietly(tmp)
        raise
    _fsync_folder(out.parent)


def write_atomic(path: str | os.PathLike[str], chunks: Chunks) -> None:
    """Write ``chunks`` to ``path`` so that a reader (or a power cut) sees the old file or
    the whole new one, never a mix: the project's one atomic writer.

    ``chunks``: bytes, a str (written as UTF-8), or an iterable of either. The data goes
    to a temporary file in the same folder (mode 0666 minus the umask, like any new
    file), is fsynced, renamed over ``path``, and the folder is fsynced so the rename
    itself survives a crash. On any error the temporary file is removed and the old
    ``path`` is left as it was.
    """
    if isinstance(chunks, bytes | bytearray | memoryview | str):  # one value, not a list
        chunks = [chunks]
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp, fd = _create_beside(out, ".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk.encode("utf-8") if isinstance(chunk, str) else chunk)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, out)
    except BaseException:
        _remove_quietly(tmp)
        raise
    _fsync_folder(out.parent)


def _create_beside(out: Path, suffix: str) -> tuple[Path, int]:
    """Create a new hidden file next to ``out`` (O_EXCL, so never someone else's file);
    the kernel applies the umask to mode 0666. Returns (path, open write descriptor)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    while True:
        tmp = out.with_name(f".{out.name}.{os.urandom(4).hex()}{suffix}")
        try:
            return tmp, os.open(tmp, flags, 0o666)
        except FileExistsError:
            continue


def _remove_quietly(tmp: Path) -> None:
    try:
        os.unlink(tmp)
    except OSError:
        pass


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable. Some file systems cannot fsync a directory
    (EINVAL, ENOTSUP); there the rename is as durable as it gets."""
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)
