"""Fuzz targets for every mesh reader, each through the public entry point ``load_mesh``.

An input is a file's bytes; it is saved under the format's suffix and loaded with the
limits the daemon applies (``[limits]``: file size and triangle count). The only clean
refusal is ``MeshReadError``: ``load_mesh`` turns a missing or unreadable file into one
too, so no other exception type is expected from any content.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

from harness import Target
from hypothesis import strategies as st
from mesh_files import (
    obj_text,
    ply_file,
    stl_ascii,
    stl_binary,
    threemf_file,
    valid_or_mutated,
)

from repair.io import MeshReadError, load_mesh

#: The daemon's limits for a dropped file (a 3MF may decompress to 20 x max_bytes).
MAX_BYTES = 1 << 20
MAX_TRIANGLES = 2_000_000

_FOLDER = Path(tempfile.mkdtemp(prefix="preflight-fuzz-mesh-"))
atexit.register(shutil.rmtree, _FOLDER, True)

_MODULES = ("repair.io.base", "repair.io.read")


def load_bytes(data: bytes, suffix: str) -> object:
    """Save ``data`` as a file with ``suffix`` and load it as the daemon would."""
    path = _FOLDER / f"input{suffix}"
    path.write_bytes(data)
    return load_mesh(path, max_bytes=MAX_BYTES, max_triangles=MAX_TRIANGLES)


def _target(name: str, strategy: st.SearchStrategy[bytes], suffix: str, module: str) -> Target:
    return Target(name=name, strategy=strategy, run=lambda data: load_bytes(data, suffix),
                  expected=(MeshReadError,), modules=(f"repair.io.{module}", *_MODULES))


TARGETS: list[Target] = [
    _target("mesh-stl-binary", valid_or_mutated(stl_binary()), ".stl", "stl"),
    _target("mesh-stl-ascii", valid_or_mutated(stl_ascii()), ".stl", "stl"),
    _target("mesh-obj", valid_or_mutated(obj_text()), ".obj", "obj"),
    _target("mesh-ply", valid_or_mutated(ply_file()), ".ply", "ply"),
    _target("mesh-3mf", valid_or_mutated(threemf_file()), ".3mf", "threemf"),
    Target(
        name="mesh-random-bytes",
        strategy=st.tuples(st.sampled_from([".stl", ".obj", ".ply", ".3mf"]),
                           st.binary(max_size=4096)),
        run=lambda pair: load_bytes(pair[1], pair[0]),
        expected=(MeshReadError,),
        modules=("repair.io.stl", "repair.io.obj", "repair.io.ply", "repair.io.threemf",
                 *_MODULES),
    ),
]
