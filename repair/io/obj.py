"""OBJ in: ``v`` vertices, ``f`` polygons (fan-triangulated), ``l`` polylines (degenerate
triangles); relative (negative) indices and line continuations are honoured."""

from __future__ import annotations

import re

import numpy as np

from repair.io.base import Mesh, MeshReadError, check_triangle_cap, finish, parse_floats

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
            nums = parse_floats(text.replace(b"/", b" "))
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
        flat = parse_floats(text)
    if flat is None or len(flat) != n_tokens or not np.all(flat == np.round(flat)):
        raise MeshReadError(f"{name}: malformed OBJ: unreadable face indices")
    if len(flat) and np.abs(flat).max() > 2**53:  # beyond any file; not exact in int64
        raise MeshReadError(f"{name}: malformed OBJ: a face refers to a missing vertex")
    idx = flat.astype(np.int64)
    if np.any(idx == 0):
        raise MeshReadError(f"{name}: malformed OBJ: vertex index 0 (OBJ counts from 1)")
    if np.any(idx < 0):
        # Negative indices count back from the vertices defined before that record.
        idx = np.where(idx < 0, np.repeat(defined, counts) + idx, idx - 1)
    else:
        idx -= 1
    return idx, counts


def read_obj(data: bytes, name: str, max_triangles: int | None) -> Mesh:
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
    flat = parse_floats(b"\n".join(v_lines))
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
        check_triangle_cap(n_tri, max_triangles, name)
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
        # The last point of a polyline starts no segment (an empty ``l`` record has none).
        is_seg[(np.cumsum(l_counts) - 1)[l_counts > 0]] = False
        a = np.flatnonzero(is_seg)
        tris.append(np.stack([l_idx[a], l_idx[a + 1], l_idx[a + 1]], 1))
    if not any(len(t) for t in tris):  # a one-point polyline has no segment
        raise MeshReadError(f"{name}: not a mesh: the OBJ file has no faces")
    faces = np.vstack(tris)
    check_triangle_cap(len(faces), max_triangles, name)
    if faces.min() < 0 or faces.max() >= len(verts):
        raise MeshReadError(f"{name}: malformed OBJ: a face refers to a missing vertex")
    return finish(verts, faces, "obj", name)

