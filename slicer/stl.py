"""A minimal STL reader (binary and ASCII) in numpy, so slicing a file needs no trimesh.

Returns a triangle soup: vertices (3·m, 3) float64 mm and faces (m, 3) int64; the slicer
welds bit-identical corners itself.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from slicer.errors import SliceError

_BINARY = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")


def read_stl(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an STL file; raises SliceError with a one-line reason when it is not one."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise SliceError(f"cannot read {p}: {exc.strerror or exc}") from None
    if len(data) >= 84:
        count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        if 84 + 50 * count == len(data):
            tri = np.frombuffer(data, dtype=_BINARY, count=count, offset=84)["v"]
            return _soup(tri.astype(np.float64).reshape(-1, 3), p)
    if data.lstrip()[:5].lower() == b"solid":
        found = _VERTEX.findall(data)
        if found and len(found) % 3 == 0:
            try:
                verts = np.array(found, dtype=np.float64)
            except ValueError:
                raise SliceError(f"{p.name}: malformed ASCII STL vertex") from None
            return _soup(verts, p)
    raise SliceError(f"{p.name} is not an STL file (binary size mismatch, no ASCII facets)")


def _soup(verts: np.ndarray, p: Path) -> tuple[np.ndarray, np.ndarray]:
    if len(verts) == 0:
        raise SliceError(f"{p.name} holds no triangles")
    return verts, np.arange(len(verts), dtype=np.int64).reshape(-1, 3)
