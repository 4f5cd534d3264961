"""Mesh files out: binary STL, and the project's one atomic file writer."""

from __future__ import annotations

import os
import tempfile
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
    tri = v.astype(np.float32)[f]  # (m, 3, 3): one gather, shared by corners and normals
    rec = np.empty(len(f), dtype=STL_DTYPE)
    rec["v"] = tri
    rec["normal"] = _triangle_normals32(tri)
    rec["attr"] = 0
    header = b"binary STL written by preflight (units: mm)".ljust(80, b" ")
    count = np.uint32(len(f)).tobytes()
    write_atomic(path, [header, count, rec.tobytes()])


def write_atomic(path: str | os.PathLike[str], chunks: list[bytes]) -> None:
    """Write ``chunks`` to ``path`` atomically: a temporary file in the same folder
    (mode 0644), then a rename, so a reader never sees a half-written file."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + out.name + ".", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
