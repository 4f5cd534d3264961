"""Mesh files in and out: STL (binary and ASCII), OBJ, PLY, 3MF and STEP in; binary STL out.

Every reader returns a :class:`Mesh` in millimetres, or raises :class:`MeshReadError`
with a one-line human-readable message. Readers weld nothing except what the format
implies: STL is a triangle soup (so is Open CASCADE's tessellation of a STEP), so exactly
coincident corners are merged (bit-for-bit equal coordinates, no tolerance); OBJ, PLY and
3MF index shared vertices already and are kept as they are. Degenerate triangles are kept
(the repair turns them into wires); OBJ ``l`` polylines become degenerate triangles
``(a, b, b)`` for the same reason.

One module per format (``stl``, ``obj``, ``ply``, ``threemf``, and ``step`` with the optional
``cad`` extra), the shared pieces in ``base``, the dispatch in ``read`` and the writers in
``write``.
"""

from repair.io.base import (
    DEFAULT_MAX_3MF_DECOMPRESSED,
    SUPPORTED_SUFFIXES,
    Mesh,
    MeshReadError,
)
from repair.io.read import load_mesh
from repair.io.write import atomic_path, face_normals32, write_atomic, write_stl

__all__ = [
    "DEFAULT_MAX_3MF_DECOMPRESSED",
    "SUPPORTED_SUFFIXES",
    "Mesh",
    "atomic_path",
    "MeshReadError",
    "face_normals32",
    "load_mesh",
    "write_atomic",
    "write_stl",
]
