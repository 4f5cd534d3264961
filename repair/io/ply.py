"""PLY in (ASCII and binary), through trimesh's PLY parser behind a header check."""

from __future__ import annotations

import io
import re
import warnings

import numpy as np

from repair.io.base import Mesh, MeshReadError, check_triangle_cap, finish, sniff_foreign


def read_ply(data: bytes, name: str, max_triangles: int | None) -> Mesh:
    if not data.startswith(b"ply"):
        foreign = sniff_foreign(data[:16])
        raise MeshReadError(f"{name}: not a PLY file" + (f", it is {foreign}" if foreign else ""))
    head = data[: min(len(data), 1 << 16)]
    end = head.find(b"end_header")
    if end < 0:
        raise MeshReadError(f"{name}: malformed PLY: no end_header")
    m = re.search(rb"(?m)^element[ \t]+face[ \t]+(\d+)", head[:end])
    if not m or int(m.group(1)) == 0:
        raise MeshReadError(f"{name}: not a mesh: the PLY file has no faces")
    check_triangle_cap(int(m.group(1)), max_triangles, name)
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
    check_triangle_cap(len(faces), max_triangles, name)
    return finish(verts, faces, "ply", name)

