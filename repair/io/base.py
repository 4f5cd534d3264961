"""What every mesh reader shares: the Mesh it returns, the one error it raises, the limits,
sniffing of foreign formats, and the final validation of reader output."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

STEP_SUFFIXES = (".step", ".stp")  # read by repair/io/step.py (the optional ``cad`` extra)
SUPPORTED_SUFFIXES = (".stl", ".obj", ".ply", ".3mf", *STEP_SUFFIXES)

#: Default cap on the total decompressed size of a 3MF archive when the caller gives no
#: ``max_bytes`` (with ``max_bytes``, the cap is ``EXPANSION_3MF * max_bytes``).
DEFAULT_MAX_3MF_DECOMPRESSED = 1 << 30
EXPANSION_3MF = 20

STL_DTYPE = np.dtype(
    [("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")]
)  # 50 bytes per triangle

_MAGIC: tuple[tuple[bytes, str], ...] = (
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"GIF8", "a GIF image"),
    (b"%PDF", "a PDF document"),
    (b"PK\x03\x04", "a zip archive"),
    (b"\x1f\x8b", "a gzip archive"),
    (b"\x7fELF", "an executable"),
)


#: A refusal longer than this is cut (with an ellipsis): it is read by a person.
MAX_MESSAGE = 300


class MeshReadError(ValueError):
    """A mesh file could not be read; ``str(err)`` is one human-readable line.

    The line is enforced here, for every reader: line breaks become spaces and a message
    carrying file content (a parser's error quoting bytes, an attribute value) is cut
    to ``MAX_MESSAGE`` characters.
    """

    def __init__(self, message: str) -> None:
        line = " ".join(str(message).split())
        if len(line) > MAX_MESSAGE:
            line = line[: MAX_MESSAGE - 1].rstrip() + "\u2026"
        super().__init__(line)


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh read from a file.

    ``vertices``: float64 (n, 3) in mm, all finite. ``faces``: int64 (m, 3) indices into
    ``vertices`` (may contain degenerate triangles). ``source_format``: one of
    ``"stl-binary"``, ``"stl-ascii"``, ``"obj"``, ``"ply"``, ``"3mf"``, ``"step"``. ``unit_scale``:
    the factor that was applied to the file's coordinates to get mm (1.0 except for 3MF
    files in other units).
    """

    vertices: np.ndarray
    faces: np.ndarray
    source_format: str
    unit_scale: float = 1.0

    @property
    def triangles(self) -> int:
        return int(len(self.faces))



def human_bytes(n: int) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} bytes"  # pragma: no cover


def sniff_foreign(head: bytes) -> str | None:
    """Name of a well-known non-mesh format the bytes start with, if any."""
    for magic, name in _MAGIC:
        if head.startswith(magic):
            return name
    return None


def check_triangle_cap(n: int, max_triangles: int | None, what: str) -> None:
    if max_triangles is not None and n > max_triangles:
        raise MeshReadError(f"{what} has {n} triangles, over the limit of {max_triangles}")


def finish(
    vertices: np.ndarray, faces: np.ndarray, fmt: str, name: str, unit_scale: float = 1.0
) -> Mesh:
    """Validate and package reader output."""
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        raise MeshReadError(f"{name}: the file contains no triangles")
    if f.min() < 0 or f.max() >= len(v):
        raise MeshReadError(f"{name}: a face refers to a vertex that does not exist")
    bad = ~np.isfinite(v)
    if bad.any():
        # Only coordinates that faces use matter, but a NaN anywhere means a broken export.
        bad_faces = np.flatnonzero(bad.any(axis=1)[f].any(axis=1))
        where = (
            f"{len(bad_faces)} triangle(s), first is #{bad_faces[0]}"
            if len(bad_faces)
            else "unused vertices"
        )
        raise MeshReadError(f"{name}: NaN or infinite coordinates in {where}")
    return Mesh(vertices=v, faces=f, source_format=fmt, unit_scale=float(unit_scale))


def looks_like_text(chunk: bytes) -> bool:
    if not chunk or b"\0" in chunk:
        return False
    try:
        chunk.decode("utf-8")
    except UnicodeDecodeError:
        # a multi-byte character may be cut at the end of the chunk
        try:
            chunk[:-4].decode("utf-8")
        except UnicodeDecodeError:
            return False
    printable = sum(1 for b in chunk[:512] if b in b"\t\r\n" or 32 <= b < 127)
    return printable >= 0.9 * min(len(chunk), 512)


def parse_floats(text: bytes) -> np.ndarray | None:
    """All whitespace-separated floats in ``text`` (C speed); None if any token is not."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return np.fromstring(text, dtype=np.float64, sep=" ")  # noqa: NPY201
        except (DeprecationWarning, ValueError):
            return None


