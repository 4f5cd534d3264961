"""load_mesh: pick the reader by suffix, apply the size limits, refuse what is not a mesh."""

from __future__ import annotations

import os
from pathlib import Path

from repair.io.base import (
    DEFAULT_MAX_3MF_DECOMPRESSED,
    EXPANSION_3MF,
    STEP_SUFFIXES,
    SUPPORTED_SUFFIXES,
    Mesh,
    MeshReadError,
    human_bytes,
    looks_like_text,
    sniff_foreign,
)


def load_mesh(
    path: str | os.PathLike[str],
    *,
    max_bytes: int | None = None,
    max_triangles: int | None = None,
    max_decompressed: int | None = None,
    deflection: float | None = None,
) -> Mesh:
    """Read a mesh file (STL, OBJ, PLY, 3MF, STEP) into a :class:`Mesh` in millimetres.

    ``max_bytes`` caps the file size; ``max_triangles`` caps the triangle count (checked
    from headers before the bulk is parsed where the format allows). For 3MF, the total
    decompressed size is capped at ``max_decompressed`` (default: 20 x ``max_bytes``, or
    1 GiB without ``max_bytes``), counted while reading, so a zip bomb is refused early.
    A STEP file (the optional ``cad`` extra) is tessellated at the chordal ``deflection``
    in mm (default :func:`repair.io.step.chordal_deflection`).
    Raises :class:`MeshReadError` (one line) for anything that is not a readable mesh.
    """
    p = Path(path)
    name = p.name
    suffix = p.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise MeshReadError(
            f"{name}: unsupported file type {suffix or '(no extension)'!r}; "
            f"expected one of {', '.join(SUPPORTED_SUFFIXES)}"
        )
    size = _file_size(p, name)
    if size == 0:
        raise MeshReadError(f"{name}: the file is empty")
    if max_bytes is not None and size > max_bytes:
        raise MeshReadError(
            f"{name}: file is {human_bytes(size)}, over the {human_bytes(max_bytes)} limit"
        )
    # each reader is imported when its format is read: a process that reads STL files never
    # loads the 3MF reader's zip/XML modules (start-up time of `preflight slice`/`repair`)
    if suffix in STEP_SUFFIXES:
        from repair.io.step import read_step

        return read_step(p, name, deflection=deflection, max_triangles=max_triangles)
    if suffix == ".3mf":
        return _load_3mf(p, name, max_bytes, max_triangles, max_decompressed)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise MeshReadError(f"{name}: cannot read: {exc.strerror or exc}") from None
    if not data[:65536].strip() and not data.strip():
        raise MeshReadError(f"{name}: the file is empty (only whitespace)")
    if suffix == ".stl":
        from repair.io.stl import read_stl

        return read_stl(data, name, max_triangles)
    foreign = sniff_foreign(data[:16])
    if foreign:
        raise MeshReadError(f"{name}: not a mesh, it is {foreign}")
    if suffix == ".obj":
        if not looks_like_text(data[:4096]):
            raise MeshReadError(f"{name}: not a mesh: binary data in an OBJ file")
        from repair.io.obj import read_obj

        return read_obj(data, name, max_triangles)
    from repair.io.ply import read_ply

    return read_ply(data, name, max_triangles)


def _load_3mf(p: Path, name: str, max_bytes: int | None, max_triangles: int | None,
              max_decompressed: int | None) -> Mesh:
    """A 3MF file, refused at once when it is not a zip, its decompressed size capped."""
    if max_decompressed is None:
        max_decompressed = (
            EXPANSION_3MF * max_bytes if max_bytes is not None else DEFAULT_MAX_3MF_DECOMPRESSED
        )
    try:
        with open(p, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise MeshReadError(f"{name}: cannot read: {exc.strerror or exc}") from None
    if head != b"PK\x03\x04":
        foreign = sniff_foreign(head)
        raise MeshReadError(f"{name}: not a 3MF file" + (f", it is {foreign}" if foreign else ""))
    from repair.io.threemf import read_3mf

    return read_3mf(p, name, max_triangles, max_decompressed)


def _file_size(p: Path, name: str) -> int:
    """Size of the mesh file; every way it cannot be one is a refusal, not an OSError
    (missing, a folder, no permission, a name too long, a symlink loop, an I/O error)."""
    try:
        size = p.stat().st_size
        if p.is_dir():
            raise MeshReadError(f"{name}: is a directory, not a mesh file")
    except FileNotFoundError:
        raise MeshReadError(f"{name}: no such file") from None
    except PermissionError:
        raise MeshReadError(f"{name}: permission denied") from None
    except OSError as exc:
        raise MeshReadError(f"{name}: cannot read: {exc.strerror or exc}") from None
    return size
