"""Small measures and concatenation of indexed triangle meshes.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

__all__ = ["concat_meshes", "shell_volumes", "surface_area"]


def concat_meshes(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One ``(vertices, faces)`` holding all the parts (faces re-indexed; parts without
    faces skipped; vertices are not welded)."""
    vs, fs, off = [], [], 0
    for v, f in parts:
        if len(f) == 0:
            continue
        vs.append(np.asarray(v, dtype=np.float64))
        fs.append(np.asarray(f, dtype=np.int64) + off)
        off += len(v)
    if not fs:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(vs), np.vstack(fs)


def shell_volumes(v: np.ndarray, f: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Signed volume (mm³) of each of the ``n`` shells, ``labels`` giving each face's."""
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    a, b, c = v[f[:, 0]] - centre, v[f[:, 1]] - centre, v[f[:, 2]] - centre
    return np.bincount(labels, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0, minlength=n)


def surface_area(v: np.ndarray, f: np.ndarray) -> float:
    """Total area of the faces, mm²."""
    if len(f) == 0:
        return 0.0
    p = v[f]
    return float(0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())
