"""Mesh files in and out: STL (binary and ASCII), OBJ, PLY and 3MF in; binary STL out.

Every reader returns a :class:`Mesh` in millimetres, or raises :class:`MeshReadError`
with a one-line human-readable message. Readers weld nothing except what the format
implies: STL is a triangle soup, so exactly coincident corners are merged (bit-for-bit
equal coordinates, no tolerance); OBJ, PLY and 3MF index shared vertices already and are
kept as they are. Degenerate triangles are kept (the repair turns them into wires);
OBJ ``l`` polylines become degenerate triangles ``(a, b, b)`` for the same reason.
"""

from __future__ import annotations

import io
import os
import re
import tempfile
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from repair.check import weld_exact

__all__ = ["Mesh", "MeshReadError", "load_mesh", "write_stl", "SUPPORTED_SUFFIXES"]

SUPPORTED_SUFFIXES = (".stl", ".obj", ".ply", ".3mf")

#: Default cap on the total decompressed size of a 3MF archive when the caller gives no
#: ``max_bytes`` (with ``max_bytes``, the cap is ``_3MF_EXPANSION * max_bytes``).
DEFAULT_MAX_3MF_DECOMPRESSED = 1 << 30
_3MF_EXPANSION = 20

# 3MF model units, as factors to millimetres.
_UNITS_MM = {
    "micron": 0.001,
    "millimeter": 1.0,
    "centimeter": 10.0,
    "inch": 25.4,
    "foot": 304.8,
    "meter": 1000.0,
}

_STL_DTYPE = np.dtype(
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


class MeshReadError(ValueError):
    """A mesh file could not be read; ``str(err)`` is one human-readable line."""


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh read from a file.

    ``vertices``: float64 (n, 3) in mm, all finite. ``faces``: int64 (m, 3) indices into
    ``vertices`` (may contain degenerate triangles). ``source_format``: one of
    ``"stl-binary"``, ``"stl-ascii"``, ``"obj"``, ``"ply"``, ``"3mf"``. ``unit_scale``:
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


# --------------------------------------------------------------------------- helpers


def _human_bytes(n: int) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} bytes"  # pragma: no cover


def _sniff_foreign(head: bytes) -> str | None:
    """Name of a well-known non-mesh format the bytes start with, if any."""
    for magic, name in _MAGIC:
        if head.startswith(magic):
            return name
    return None


def _check_triangle_cap(n: int, max_triangles: int | None, what: str) -> None:
    if max_triangles is not None and n > max_triangles:
        raise MeshReadError(f"{what} has {n} triangles, over the limit of {max_triangles}")


def _finish(
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


# --------------------------------------------------------------------------- STL


def _stl_soup_to_mesh(tri: np.ndarray, fmt: str, name: str) -> Mesh:
    """(m, 3, 3) triangle corners -> Mesh with exactly coincident corners merged."""
    m = len(tri)
    soup = np.ascontiguousarray(tri).reshape(-1, 3)  # float32 (binary) or float64 (ASCII)
    finite = np.isfinite(soup).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite) // 3
        raise MeshReadError(
            f"{name}: NaN or infinite coordinates in {len(np.unique(bad))} triangle(s), "
            f"first is #{bad[0]}"
        )
    v, f = weld_exact(soup, np.arange(3 * m, dtype=np.int64).reshape(m, 3))
    return _finish(v, f, fmt, name)


def _read_stl(data: bytes, name: str, max_triangles: int | None) -> Mesh:
    size = len(data)
    if size >= 84:
        n = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        expected = 84 + 50 * n
        # Sizes agree: binary, whatever the header says ("solid ..." is common in binary
        # headers). An ASCII file cannot agree by accident below 27 GB: its bytes 80..84
        # are text, so they read as n >= 0x20202020 triangles.
        if expected == size:
            _check_triangle_cap(n, max_triangles, name)
            if n == 0:
                raise MeshReadError(f"{name}: binary STL with 0 triangles")
            rec = np.frombuffer(data, dtype=_STL_DTYPE, count=n, offset=84)
            return _stl_soup_to_mesh(rec["v"], "stl-binary", name)
    else:
        n, expected = None, None

    stripped = data[:1024].removeprefix(b"\xef\xbb\xbf").lstrip()  # UTF-8 BOM, blanks
    if stripped[:5].lower() == b"solid" and b"\0" not in data[:1024]:
        if re.search(rb"(?i)\bfacet\b|\bendsolid\b", data[:4096]) or size < 4096:
            return _read_stl_ascii(data, name, max_triangles)

    foreign = _sniff_foreign(data[:16])
    if foreign:
        raise MeshReadError(f"{name}: not a mesh, it is {foreign}")
    if n is None:
        raise MeshReadError(f"{name}: not an STL file ({size} bytes is too short for one)")
    if _looks_like_text(data[:4096]):
        raise MeshReadError(f"{name}: not a mesh: a text file that is not an ASCII STL")
    # Size disagrees with the header. A genuine but cut-off file has plausible
    # coordinates in the triangles that are there; random bytes do not.
    whole = max(0, min(n, (size - 84) // 50))
    if whole:
        rec = np.frombuffer(data, dtype=_STL_DTYPE, count=min(whole, 1000), offset=84)
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


def _looks_like_text(chunk: bytes) -> bool:
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


def _parse_floats(text: bytes) -> np.ndarray | None:
    """All whitespace-separated floats in ``text`` (C speed); None if any token is not."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return np.fromstring(text, dtype=np.float64, sep=" ")  # noqa: NPY201
        except (DeprecationWarning, ValueError):
            return None


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
    return _parse_floats(a[keep].tobytes()), len(cand), n_facets


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
        _check_triangle_cap(n_facets, max_triangles, name)
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


# --------------------------------------------------------------------------- OBJ

_OBJ_KIND = {b"v": 1, b"f": 2, b"l": 3}


def _obj_indices(
    records: list[bytes], defined: np.ndarray, name: str
) -> tuple[np.ndarray, np.ndarray]:
    """Flat 0-based vertex indices and per-record counts for OBJ ``f``/``l`` records.

    ``defined[i]``: how many vertices precede record i (for negative, relative indices).
    Tokens are ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``; only ``v`` is kept.
    """
    if not records:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    counts = np.fromiter((len(r.split()) for r in records), dtype=np.int64, count=len(records))
    text = b"\n".join(records)
    n_tokens = int(counts.sum())
    flat = None
    if b"/" in text:
        # One layout for the whole file (the usual case): split at the slashes and keep
        # every k-th number. Otherwise fall back to a per-token split.
        token = records[0].split()[0] if records[0].split() else b""
        slashes = token.count(b"/")
        per_token = slashes + 1 - token.count(b"//")
        if text.count(b"/") == slashes * n_tokens and text.count(b"//") == (
            token.count(b"//") * n_tokens
        ):
            nums = _parse_floats(text.replace(b"/", b" "))
            if nums is not None and len(nums) == per_token * n_tokens:
                flat = nums[::per_token]
        if flat is None:
            try:
                flat = np.array(
                    [float(t.split(b"/")[0]) for r in records for t in r.split()],
                    dtype=np.float64,
                )
            except ValueError:
                flat = None
    else:
        flat = _parse_floats(text)
    if flat is None or len(flat) != n_tokens or not np.all(flat == np.round(flat)):
        raise MeshReadError(f"{name}: malformed OBJ: unreadable face indices")
    idx = flat.astype(np.int64)
    if np.any(idx == 0):
        raise MeshReadError(f"{name}: malformed OBJ: vertex index 0 (OBJ counts from 1)")
    if np.any(idx < 0):
        # Negative indices count back from the vertices defined before that record.
        idx = np.where(idx < 0, np.repeat(defined, counts) + idx, idx - 1)
    else:
        idx -= 1
    return idx, counts


def _read_obj(data: bytes, name: str, max_triangles: int | None) -> Mesh:
    if b"\\" in data:  # a backslash at the end of a line continues it
        data = re.sub(rb"\\[ \t]*\r?\n", b" ", data)
    lines = data.splitlines()
    if any(line[:1] in (b" ", b"\t") for line in lines):
        lines = [line.lstrip() for line in lines]
    # Record kind per line: the keyword must be followed by a blank ("vt", "vn" are not v).
    kind = np.fromiter(
        (_OBJ_KIND.get(line[:1], 0) if line[1:2] in (b" ", b"\t") else 0 for line in lines),
        dtype=np.int8,
        count=len(lines),
    )
    v_rows = np.flatnonzero(kind == 1)
    if len(v_rows) == 0:
        raise MeshReadError(f"{name}: not a mesh: no OBJ vertices ('v' lines) found")

    def records(rows: np.ndarray) -> list[bytes]:
        out = [lines[i][2:] for i in rows]
        if any(b"#" in r for r in out):
            out = [r.split(b"#", 1)[0] for r in out]
        return out

    v_lines = records(v_rows)
    flat = _parse_floats(b"\n".join(v_lines))
    if flat is not None and len(flat) == 3 * len(v_lines):
        verts = flat.reshape(-1, 3)
    else:
        # Extra values (w, or r g b colours) or a bad token: per line, keep x y z.
        try:
            rows = [[float(t) for t in r.split()[:3]] for r in v_lines]
        except ValueError:
            raise MeshReadError(f"{name}: malformed OBJ: unreadable vertex coordinates") from None
        if any(len(r) != 3 for r in rows):
            raise MeshReadError(f"{name}: malformed OBJ: a vertex has fewer than 3 coordinates")
        verts = np.array(rows, dtype=np.float64).reshape(-1, 3)
    defined_before = np.cumsum(kind == 1)  # vertices defined up to and including each line

    f_rows = np.flatnonzero(kind == 2)
    idx, counts = _obj_indices(records(f_rows), defined_before[f_rows], name)
    tris = []
    if len(counts):
        if np.any(counts < 3):
            raise MeshReadError(f"{name}: malformed OBJ: a face with fewer than 3 vertices")
        n_tri = int((counts - 2).sum())
        _check_triangle_cap(n_tri, max_triangles, name)
        # Fan-triangulate polygons: (p0, p_i, p_i+1), vectorised over all faces.
        starts = np.r_[0, np.cumsum(counts)[:-1]]
        owner = np.repeat(np.arange(len(counts)), counts - 2)
        local = np.arange(n_tri) - np.repeat(np.cumsum(counts - 2) - (counts - 2), counts - 2)
        base = starts[owner]
        tris.append(np.stack([idx[base], idx[base + local + 1], idx[base + local + 2]], 1))
    l_rows = np.flatnonzero(kind == 3)
    l_idx, l_counts = _obj_indices(records(l_rows), defined_before[l_rows], name)
    if len(l_counts):
        # Polylines become degenerate triangles (a, b, b): the repair inflates them.
        is_seg = np.ones(len(l_idx), bool)
        is_seg[np.cumsum(l_counts) - 1] = False  # the last point of a polyline starts none
        a = np.flatnonzero(is_seg)
        tris.append(np.stack([l_idx[a], l_idx[a + 1], l_idx[a + 1]], 1))
    if not tris:
        raise MeshReadError(f"{name}: not a mesh: the OBJ file has no faces")
    faces = np.vstack(tris)
    _check_triangle_cap(len(faces), max_triangles, name)
    if faces.min() < 0 or faces.max() >= len(verts):
        raise MeshReadError(f"{name}: malformed OBJ: a face refers to a missing vertex")
    return _finish(verts, faces, "obj", name)


# --------------------------------------------------------------------------- PLY


def _read_ply(data: bytes, name: str, max_triangles: int | None) -> Mesh:
    if not data.startswith(b"ply"):
        foreign = _sniff_foreign(data[:16])
        raise MeshReadError(f"{name}: not a PLY file" + (f", it is {foreign}" if foreign else ""))
    head = data[: min(len(data), 1 << 16)]
    end = head.find(b"end_header")
    if end < 0:
        raise MeshReadError(f"{name}: malformed PLY: no end_header")
    m = re.search(rb"(?m)^element[ \t]+face[ \t]+(\d+)", head[:end])
    if not m or int(m.group(1)) == 0:
        raise MeshReadError(f"{name}: not a mesh: the PLY file has no faces")
    _check_triangle_cap(int(m.group(1)), max_triangles, name)
    from trimesh.exchange.ply import load_ply

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = load_ply(io.BytesIO(data), fix_texture=False, skip_materials=True)
        verts = np.asarray(out["vertices"], dtype=np.float64)
        faces = np.asarray(out["faces"], dtype=np.int64)
    except MeshReadError:
        raise
    except Exception as exc:  # trimesh raises many kinds on malformed input
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise MeshReadError(f"{name}: malformed PLY: {msg}") from None
    if faces.ndim != 2 or faces.shape[1] < 3:
        raise MeshReadError(f"{name}: malformed PLY: faces are not polygons")
    if faces.shape[1] > 3:  # all faces have k > 3 corners: fan-triangulate
        k = faces.shape[1]
        faces = np.stack(
            [np.repeat(faces[:, 0], k - 2), faces[:, 1:-1].reshape(-1), faces[:, 2:].reshape(-1)],
            axis=1,
        )
    _check_triangle_cap(len(faces), max_triangles, name)
    return _finish(verts, faces, "ply", name)


# --------------------------------------------------------------------------- 3MF

_NS_CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
_NS_PROD = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
_NS_RELS = "http://schemas.openxmlformats.org/package/2006/relationships"
_REL_MODEL = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"


class _Budget:
    """A running limit on decompressed bytes read from a zip archive."""

    def __init__(self, limit: int, name: str) -> None:
        self.left = limit
        self.limit = limit
        self.name = name

    def take(self, n: int) -> None:
        self.left -= n
        if self.left < 0:
            raise MeshReadError(
                f"{self.name}: 3MF decompresses to more than {_human_bytes(self.limit)}; "
                "refusing (zip bomb?)"
            )


class _LimitedReader(io.RawIOBase):
    """A read-only stream over a zip entry that charges every byte to a budget."""

    def __init__(self, raw: IO[bytes], budget: _Budget) -> None:
        self.raw = raw
        self.budget = budget

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:  # type: ignore[override]
        chunk = self.raw.read(min(len(buf), 1 << 20))
        self.budget.take(len(chunk))
        buf[: len(chunk)] = chunk
        return len(chunk)


def _read_zip_entry(zf: zipfile.ZipFile, entry: str, budget: _Budget) -> bytes:
    with zf.open(entry) as raw:
        parts = []
        while True:
            chunk = raw.read(1 << 20)
            if not chunk:
                break
            budget.take(len(chunk))
            parts.append(chunk)
    return b"".join(parts)


def _parse_transform(text: str | None, name: str) -> np.ndarray | None:
    """3MF transform "m00 m01 m02 m10 ... m32" -> 4x3 matrix (row-vector convention)."""
    if not text:
        return None
    try:
        vals = np.array([float(t) for t in text.split()], dtype=np.float64)
    except ValueError:
        raise MeshReadError(f"{name}: malformed 3MF: bad transform {text!r}") from None
    if vals.shape != (12,) or not np.isfinite(vals).all():
        raise MeshReadError(f"{name}: malformed 3MF: bad transform {text!r}")
    return vals.reshape(4, 3)


def _compose(outer: np.ndarray | None, inner: np.ndarray | None) -> np.ndarray | None:
    """Transform applying ``inner`` first, then ``outer`` (4x3 row-vector matrices)."""
    if outer is None:
        return inner
    if inner is None:
        return outer
    i4 = np.eye(4)
    i4[:, :3] = inner
    o4 = np.eye(4)
    o4[:, :3] = outer
    return (i4 @ o4)[:, :3]


def _parse_3mf_model(
    stream: IO[bytes], part: str, name: str, tri_count: list[int], max_triangles: int | None
) -> tuple[str, dict, list]:
    """Parse one .model part: (unit, objects, build items).

    ``objects``: {id: ("mesh", vertices, faces) | ("components", [(path, id, T), ...])}.
    Streams the XML through expat; vertex and triangle attributes are collected flat and
    converted with one numpy call per object.
    """
    from xml.parsers import expat

    sep = " "
    core = _NS_CORE + sep
    t_vertex, t_triangle = core + "vertex", core + "triangle"
    t_object, t_mesh, t_component = core + "object", core + "mesh", core + "component"
    t_item, t_model = core + "item", core + "model"
    prod_path = _NS_PROD + sep + "path"
    xyz = ("x", "y", "z")
    v123 = ("v1", "v2", "v3")

    state: dict = {"unit": "millimeter", "obj": None, "mesh": False, "done": 0}
    objects: dict[str, tuple] = {}
    items: list[tuple[str, str, np.ndarray | None]] = []
    vals_v: list[str] = []
    vals_t: list[str] = []
    comps: list[tuple[str, str, np.ndarray | None]] = []

    def pick(attrs: list[str], keys: tuple[str, str, str]) -> tuple[str, str, str]:
        d = dict(zip(attrs[::2], attrs[1::2], strict=False))
        return (d.get(keys[0], "?"), d.get(keys[1], "?"), d.get(keys[2], "?"))

    def start(tag: str, attrs: list[str]) -> None:
        # Hot path first: one call per vertex / triangle.
        if tag == t_vertex:
            if len(attrs) == 6 and attrs[0] == "x" and attrs[2] == "y" and attrs[4] == "z":
                vals_v.extend((attrs[1], attrs[3], attrs[5]))
            else:
                vals_v.extend(pick(attrs, xyz))
        elif tag == t_triangle:
            if len(attrs) >= 6 and attrs[0] == "v1" and attrs[2] == "v2" and attrs[4] == "v3":
                vals_t.extend((attrs[1], attrs[3], attrs[5]))
            else:
                vals_t.extend(pick(attrs, v123))
        elif tag == t_component or tag == t_item:
            d = dict(zip(attrs[::2], attrs[1::2], strict=False))
            entry = (d.get(prod_path, part), d.get("objectid", ""))
            target = comps if tag == t_component else items
            target.append((*entry, _parse_transform(d.get("transform"), name)))
        elif tag == t_object:
            d = dict(zip(attrs[::2], attrs[1::2], strict=False))
            if "id" not in d:
                raise MeshReadError(f"{name}: malformed 3MF: an object without id")
            state["obj"], state["mesh"] = d["id"], False
            vals_v.clear()
            vals_t.clear()
            comps.clear()
        elif tag == t_mesh:
            state["mesh"] = True
        elif tag == t_model:
            d = dict(zip(attrs[::2], attrs[1::2], strict=False))
            state["unit"] = d.get("unit", "millimeter")

    def end(tag: str) -> None:
        if tag != t_object:
            return
        oid = state["obj"]
        if state["mesh"]:
            v = _parse_floats(" ".join(vals_v).encode())
            f = _parse_floats(" ".join(vals_t).encode())
            if (
                v is None
                or f is None
                or len(v) != len(vals_v)
                or len(f) != len(vals_t)
                or not np.all(f == np.round(f))
            ):
                raise MeshReadError(
                    f"{name}: malformed 3MF: unreadable vertices or triangles in object {oid}"
                )
            objects[oid] = ("mesh", v.reshape(-1, 3), f.astype(np.int64).reshape(-1, 3))
            state["done"] += len(f) // 3
            vals_v.clear()
            vals_t.clear()
        else:
            objects[oid] = ("components", list(comps))
        state["obj"] = None

    parser = expat.ParserCreate(namespace_separator=sep)
    parser.ordered_attributes = True
    parser.buffer_text = True
    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        while True:
            chunk = stream.read(1 << 20)
            parser.Parse(chunk, not chunk)
            seen = tri_count[0] + state["done"] + len(vals_t) // 3
            if max_triangles is not None and seen > max_triangles:
                raise MeshReadError(
                    f"{name}: 3MF has more than {max_triangles} triangles, over the limit"
                )
            if not chunk:
                break
    except expat.ExpatError as exc:
        raise MeshReadError(f"{name}: malformed 3MF: XML error in {part}: {exc}") from None
    tri_count[0] += state["done"]
    return state["unit"], objects, items


def _root_model_part(zf: zipfile.ZipFile, budget: _Budget, name: str) -> str:
    names = set(zf.namelist())
    if "_rels/.rels" in names:
        import xml.etree.ElementTree as ET

        try:
            rels = ET.fromstring(_read_zip_entry(zf, "_rels/.rels", budget))
        except ET.ParseError:
            rels = None
        if rels is not None:
            for rel in rels.iter("{" + _NS_RELS + "}Relationship"):
                if rel.get("Type") == _REL_MODEL:
                    target = rel.get("Target", "").lstrip("/")
                    if target in names:
                        return "/" + target
    for cand in ("3D/3dmodel.model",):
        if cand in names:
            return "/" + cand
    models = sorted(n for n in names if n.lower().endswith(".model"))
    if models:
        return "/" + models[0]
    raise MeshReadError(f"{name}: not a 3MF file: no 3D model part in the archive")


def _read_3mf(path: Path, name: str, max_triangles: int | None, max_decompressed: int) -> Mesh:
    budget = _Budget(max_decompressed, name)
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise MeshReadError(f"{name}: not a 3MF file (not a valid zip archive: {exc})") from None
    with zf:
        root = _root_model_part(zf, budget, name)
        tri_count = [0]
        parts: dict[str, tuple[str, dict, list]] = {}
        units = "millimeter"

        def load_part(part: str) -> dict:
            if part not in parts:
                entry = part.lstrip("/")
                try:
                    info = zf.getinfo(entry)
                except KeyError:
                    raise MeshReadError(f"{name}: malformed 3MF: missing part {part}") from None
                if info.file_size > budget.left:  # refuse before inflating anything
                    raise MeshReadError(
                        f"{name}: 3MF part {part} declares {_human_bytes(info.file_size)} "
                        f"uncompressed, over the {_human_bytes(max_decompressed)} limit; "
                        "refusing (zip bomb?)"
                    )
                try:
                    with zf.open(info) as raw:
                        reader = io.BufferedReader(_LimitedReader(raw, budget))
                        parts[part] = _parse_3mf_model(reader, part, name, tri_count, max_triangles)
                except (zipfile.BadZipFile, OSError, EOFError) as exc:
                    raise MeshReadError(f"{name}: corrupt 3MF archive: {exc}") from None
            return parts[part][1]

        load_part(root)
        units, _, items = parts[root]
        if units not in _UNITS_MM:
            raise MeshReadError(f"{name}: 3MF has an unknown unit {units!r}")
        scale = _UNITS_MM[units]

        out_v: list[np.ndarray] = []
        out_f: list[np.ndarray] = []
        n_out = [0, 0]  # vertices, triangles

        def emit(part: str, oid: str, transform: np.ndarray | None, depth: int) -> None:
            if depth > 32:
                raise MeshReadError(f"{name}: malformed 3MF: components nested too deep")
            objs = load_part(part)
            if oid not in objs:
                raise MeshReadError(f"{name}: malformed 3MF: no object {oid} in {part}")
            obj = objs[oid]
            if obj[0] == "mesh":
                v, f = obj[1], obj[2]
                if len(f) == 0:
                    return
                if f.min() < 0 or f.max() >= len(v):
                    raise MeshReadError(
                        f"{name}: malformed 3MF: a triangle refers to a missing vertex "
                        f"in object {oid}"
                    )
                n_out[1] += len(f)
                _check_triangle_cap(n_out[1], max_triangles, name)
                if transform is not None:
                    v = v @ transform[:3] + transform[3]
                out_v.append(v)
                out_f.append(f + n_out[0])
                n_out[0] += len(v)
            else:
                for cpart, cid, ct in obj[1]:
                    emit(cpart, cid, _compose(transform, ct), depth + 1)

        if not items:
            raise MeshReadError(f"{name}: 3MF has no build items (nothing to print)")
        for ipart, iid, it in items:
            emit(ipart, iid, it, 0)
    if not out_f:
        raise MeshReadError(f"{name}: the 3MF file contains no triangles")
    vertices = np.vstack(out_v) * scale
    return _finish(vertices, np.vstack(out_f), "3mf", name, unit_scale=scale)


# --------------------------------------------------------------------------- public


def load_mesh(
    path: str | os.PathLike[str],
    *,
    max_bytes: int | None = None,
    max_triangles: int | None = None,
    max_decompressed: int | None = None,
) -> Mesh:
    """Read a mesh file (STL, OBJ, PLY, 3MF) into a :class:`Mesh` in millimetres.

    ``max_bytes`` caps the file size; ``max_triangles`` caps the triangle count (checked
    from headers before the bulk is parsed where the format allows). For 3MF, the total
    decompressed size is capped at ``max_decompressed`` (default: 20 x ``max_bytes``, or
    1 GiB without ``max_bytes``), counted while reading, so a zip bomb is refused early.
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
    try:
        size = p.stat().st_size
        if p.is_dir():
            raise MeshReadError(f"{name}: is a directory, not a mesh file")
    except FileNotFoundError:
        raise MeshReadError(f"{name}: no such file") from None
    except PermissionError:
        raise MeshReadError(f"{name}: permission denied") from None
    if size == 0:
        raise MeshReadError(f"{name}: the file is empty")
    if max_bytes is not None and size > max_bytes:
        raise MeshReadError(
            f"{name}: file is {_human_bytes(size)}, over the {_human_bytes(max_bytes)} limit"
        )
    if suffix == ".3mf":
        if max_decompressed is None:
            max_decompressed = (
                _3MF_EXPANSION * max_bytes
                if max_bytes is not None
                else DEFAULT_MAX_3MF_DECOMPRESSED
            )
        with open(p, "rb") as fh:
            head = fh.read(4)
        if head != b"PK\x03\x04":
            foreign = _sniff_foreign(head)
            raise MeshReadError(
                f"{name}: not a 3MF file" + (f", it is {foreign}" if foreign else "")
            )
        return _read_3mf(p, name, max_triangles, max_decompressed)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise MeshReadError(f"{name}: cannot read: {exc.strerror or exc}") from None
    if not data[:65536].strip() and not data.strip():
        raise MeshReadError(f"{name}: the file is empty (only whitespace)")
    if suffix == ".stl":
        return _read_stl(data, name, max_triangles)
    foreign = _sniff_foreign(data[:16])
    if foreign:
        raise MeshReadError(f"{name}: not a mesh, it is {foreign}")
    if suffix == ".obj":
        if not _looks_like_text(data[:4096]):
            raise MeshReadError(f"{name}: not a mesh: binary data in an OBJ file")
        return _read_obj(data, name, max_triangles)
    return _read_ply(data, name, max_triangles)


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
    rec = np.empty(len(f), dtype=_STL_DTYPE)
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
