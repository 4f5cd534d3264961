"""STL in: binary (a triangle soup with a size-checked header) and ASCII (vectorised)."""

from __future__ import annotations

import re

import numpy as np

from repair.io.base import (
    STL_DTYPE,
    Mesh,
    MeshReadError,
    check_triangle_cap,
    finish,
    looks_like_text,
    parse_floats,
    sniff_foreign,
)
from repair.topology import weld_exact


def _stl_soup_to_mesh(tri: np.ndarray, fmt: str, name: str) -> Mesh:
    """(m, 3, 3) triangle corners -> Mesh with exactly coincident corners merged. NaN and
    infinite corners are welded like any others (by bit pattern) and refused by
    :func:`repair.io.base.finish`, which names the triangles that use them: checked on
    the welded vertices, a sixth as many as corners (35 ms of a 500k-triangle load)."""
    m = len(tri)
    soup = np.ascontiguousarray(tri).reshape(-1, 3)  # float32 (binary) or float64 (ASCII)
    v, f = weld_exact(soup, np.arange(3 * m, dtype=np.int64).reshape(m, 3))
    return finish(v, f, fmt, name)


def read_stl(data: bytes, name: str, max_triangles: int | None) -> Mesh:
    size = len(data)
    if size >= 84:
        n = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        expected = 84 + 50 * n
        # Sizes agree: binary, whatever the header says ("solid ..." is common in binary
        # headers). An ASCII file cannot agree by accident below 27 GB: its bytes 80..84
        # are text, so they read as n >= 0x20202020 triangles.
        if expected == size:
            check_triangle_cap(n, max_triangles, name)
            if n == 0:
                raise MeshReadError(f"{name}: binary STL with 0 triangles")
            rec = np.frombuffer(data, dtype=STL_DTYPE, count=n, offset=84)
            return _stl_soup_to_mesh(rec["v"], "stl-binary", name)
    else:
        n, expected = None, None

    stripped = data[:1024].removeprefix(b"\xef\xbb\xbf").lstrip()  # UTF-8 BOM, blanks
    if stripped[:5].lower() == b"solid" and b"\0" not in data[:1024]:
        if re.search(rb"(?i)\bfacet\b|\bendsolid\b", data[:4096]) or size < 4096:
            return _read_stl_ascii(data, name, max_triangles)

    foreign = sniff_foreign(data[:16])
    if foreign:
        raise MeshReadError(f"{name}: not a mesh, it is {foreign}")
    if n is None:
        raise MeshReadError(f"{name}: not an STL file ({size} bytes is too short for one)")
    if looks_like_text(data[:4096]):
        raise MeshReadError(f"{name}: not a mesh: a text file that is not an ASCII STL")
    # Size disagrees with the header. A genuine but cut-off file has plausible
    # coordinates in the triangles that are there; random bytes do not.
    whole = max(0, min(n, (size - 84) // 50))
    if whole:
        rec = np.frombuffer(data, dtype=STL_DTYPE, count=min(whole, 1000), offset=84)
        with np.errstate(invalid="ignore", over="ignore"):
            plausible = np.isfinite(rec["v"]).all() and np.abs(rec["v"]).max() < 1e7
        if not plausible:
            raise MeshReadError(
                f"{name}: not a mesh: neither an ASCII STL nor a binary STL "
                f"(header claims {n} triangles, coordinates are garbage)"
            )
    if size < expected:
        raise MeshReadError(
            f"{name}: truncated binary STL: header says {n} triangles "
            f"({expected} bytes) but the file has {size} bytes (room for {whole})"
        )
    raise MeshReadError(
        f"{name}: binary STL size mismatch: header says {n} triangles "
        f"({expected} bytes) but the file has {size} bytes"
    )


_ASCII_CHUNK = 8 << 20


def _ascii_stl_chunk(chunk: bytes) -> tuple[np.ndarray | None, int, int]:
    """Parse whole lines of an ASCII STL: (vertex coordinates, #vertex lines, #endfacet).

    Vectorised over the bytes: find lines whose first token is ``vertex`` (any case),
    keep the rest of those lines, and parse all of it with one C call.
    """
    a = np.frombuffer(chunk, dtype=np.uint8)
    low = a | 0x20  # ASCII letters to lower case (other bytes do not matter here)
    n_facets = low.tobytes().count(b"endfacet")
    ws = (a == 32) | ((a >= 9) & (a <= 13))
    cand = np.flatnonzero(low[: max(len(a) - 6, 0)] == ord("v"))
    for k, ch in enumerate(b"ertex", start=1):
        cand = cand[low[cand + k] == ch]
    cand = cand[ws[cand + 6]]
    # ``vertex`` must be the first token of its line (not part of a solid's name): walk
    # back over the indentation, a few bytes for all candidates at once.
    first = np.zeros(len(cand), dtype=bool)
    undecided = np.ones(len(cand), dtype=bool)
    for back in range(1, 17):
        pos = cand - back
        at_start = pos < 0
        byte = a[np.maximum(pos, 0)]
        first |= undecided & (at_start | (byte == 10))
        undecided &= ~at_start & (byte != 10) & ws[np.maximum(pos, 0)]
        if not undecided.any():
            break
    for idx in np.flatnonzero(undecided):  # indented by more than 16 blanks: rare
        line_start = chunk.rfind(b"\n", 0, int(cand[idx])) + 1
        first[idx] = not chunk[line_start : int(cand[idx])].strip()
    cand = cand[first]
    newline = np.flatnonzero(a == 10)
    # Keep each vertex line from after the keyword up to and including its newline.
    k = np.searchsorted(newline, cand)
    end = np.where(k < len(newline), newline[np.minimum(k, len(newline) - 1)], len(a) - 1)
    mark = np.zeros(len(a) + 1, dtype=np.int8)
    mark[cand + 6] = 1  # spans are disjoint: no position gets two marks
    mark[end + 1] = -1
    keep = np.cumsum(mark[:-1], dtype=np.int8) > 0
    return parse_floats(a[keep].tobytes()), len(cand), n_facets


def _read_stl_ascii(data: bytes, name: str, max_triangles: int | None) -> Mesh:
    values: list[np.ndarray] = []
    n_vertex = n_facets = 0
    start = 0
    while start < len(data):
        stop = data.find(b"\n", min(start + _ASCII_CHUNK, len(data)))
        stop = len(data) if stop < 0 else stop + 1
        chunk = data[start:stop]
        if not chunk.endswith(b"\n"):
            chunk += b"\n"
        vals, nv, nf = _ascii_stl_chunk(chunk)
        if vals is None or len(vals) != 3 * nv:
            raise MeshReadError(f"{name}: malformed ASCII STL: unreadable vertex coordinates")
        values.append(vals)
        n_vertex += nv
        n_facets += nf
        check_triangle_cap(n_facets, max_triangles, name)
        start = stop
    if n_facets == 0:
        raise MeshReadError(f"{name}: ASCII STL with no facets")
    if n_vertex != 3 * n_facets:
        raise MeshReadError(
            f"{name}: malformed ASCII STL: {n_facets} facets but {n_vertex} vertices "
            "(every facet needs 3)"
        )
    soup = np.concatenate(values).reshape(n_facets, 3, 3)
    return _stl_soup_to_mesh(soup, "stl-ascii", name)

