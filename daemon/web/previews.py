"""The pictures of a job's report, computed on demand in the web server's executor and
kept for the few jobs last looked at:

* :func:`mesh_bytes`: the input or the repaired mesh as binary triangles with, per face,
  what the repair did to it (:func:`repair.changes.face_changes`);
* :func:`gcode_layers`: the G-code read with :func:`printer.gcode.lex` into polylines per
  layer, labelled with the slicer's ``;TYPE:`` comments where it writes them.
"""

from __future__ import annotations

import json
import threading
from array import array
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.journal import Job
from daemon.web.toolpath import read_layers
from daemon.web.uploads import Refused

MESH_MAGIC = b"PFM1"
#: Larger meshes or G-code are not drawn (the page says why): the daemon's memory on a Pi.
MAX_PREVIEW_TRIANGLES = 600_000
MAX_PREVIEW_GCODE_BYTES = 48 * 1024 * 1024
CACHED = 4


class _Cache:
    """A small thread-safe LRU keyed by (job id, what, file identities)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._items: OrderedDict[Any, Any] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Any) -> Any:
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        return None

    def put(self, key: Any, value: Any) -> None:
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)


_MESHES = _Cache(CACHED)
_LAYERS = _Cache(CACHED)
#: One preview computed at a time: two browsers opening the same big job wait for one
#: reading instead of holding two copies.
_COMPUTING = threading.Lock()


def _identity(path: str | None) -> tuple[str, int, int] | None:
    if not path:
        return None
    try:
        st = Path(path).stat()
    except OSError:
        return None
    return path, st.st_size, st.st_mtime_ns


def mesh_paths(job: Job) -> tuple[str | None, str | None]:
    """(input, repaired) mesh files of a job, wherever they are now (work folder while it
    runs, ``done/`` or ``failed/`` once archived)."""
    outputs = job.outputs or {}
    found = []
    for key, live in (("input", job.input_path), ("repaired", job.repaired_path)):
        found.append(next((p for p in (outputs.get(key), live) if p and Path(p).is_file()),
                          None))
    return found[0], found[1]


def mesh_bytes(cfg: Any, job: Job, which: str) -> bytes:
    """``PFM1``, uint32 face count n, n*9 float32 corner coordinates (mm), n uint8 labels
    (indices into :data:`repair.changes.LABELS`); then a JSON line of label counts."""
    if job.kind != "mesh":
        raise Refused(404, f"job {job.id} is G-code: it has no mesh")
    inp, rep = mesh_paths(job)
    if inp is None:
        raise Refused(404, f"job {job.id}'s input file is gone")
    if which == "repaired" and rep is None:
        raise Refused(404, f"job {job.id} has no repaired mesh ({job.state})")
    key = (job.id, _identity(inp), _identity(rep), job.epsilon)
    both = _MESHES.get(key)
    if both is None:
        with _COMPUTING:
            both = _MESHES.get(key)
            if both is None:
                both = _label_meshes(cfg, job, inp, rep)
                _MESHES.put(key, both)
    return both[which]


def _pack(v: Any, f: Any, labels: Any, counts: dict[str, int]) -> bytes:
    import numpy as np

    tris = v[f].astype("<f4").reshape(-1)
    head = MESH_MAGIC + np.uint32(len(f)).astype("<u4").tobytes()
    tail = json.dumps(counts).encode()
    return head + tris.tobytes() + labels.astype(np.uint8).tobytes() + tail


def _label_meshes(cfg: Any, job: Job, inp: str, rep: str | None) -> dict[str, bytes]:
    # numpy, the mesh readers and libigl load on the first 3D view, not at the daemon's
    # start: the idle daemon stays small
    import numpy as np

    from repair.changes import KEPT, face_changes
    from repair.io import MeshReadError, load_mesh
    from repair.io.step import STEP_SUFFIXES

    limit = min(MAX_PREVIEW_TRIANGLES, cfg.limits.max_triangles)
    if Path(inp).suffix.lower() in STEP_SUFFIXES:
        # a STEP is exact surfaces, not a mesh: tessellating it here would load Open CASCADE
        # (~300 MB) into the daemon. Its input view is its tessellation, as repaired.
        if rep is None:
            raise Refused(404, f"job {job.id}'s input is a STEP file: its 3D view is shown "
                               "once it is tessellated and repaired")
        inp = rep
    try:
        m_in = load_mesh(inp, max_triangles=limit)
        m_out = load_mesh(rep, max_triangles=limit) if rep else None
    except MeshReadError as e:
        raise Refused(413 if "triangles" in str(e) else 422,
                      f"cannot show job {job.id}'s mesh: {e}") from None
    if m_out is None:
        labels = np.full(len(m_in.faces), KEPT, dtype=np.uint8)
        return {"input": _pack(m_in.vertices, m_in.faces, labels, {})}
    after = (job.repair_report or {}).get("after") or {}
    changes = face_changes(
        m_in.vertices, m_in.faces, m_out.vertices, m_out.faces,
        float(job.epsilon or cfg.printer.nozzle_diameter),
        thickened=bool(after.get("sheet_triangles_thickened") or after.get("wires_inflated")
                       or after.get("singular_edges_thickened")),
        lids=bool(((job.repair_report or {}).get("holes_closed") or {}).get("count")))
    counts = changes.counts()
    return {"input": _pack(m_in.vertices, m_in.faces, changes.input, counts["input"]),
            "repaired": _pack(m_out.vertices, m_out.faces, changes.output, counts["output"])}


@dataclass
class Layers:
    """The G-code's extruding moves by layer: ``paths[i]`` is a list of (type index,
    flat x, y array) polylines at height ``z[i]``; ``types`` names the type indices."""

    z: list[float] = field(default_factory=list)
    paths: list[list[tuple[int, array]]] = field(default_factory=list)
    types: list[str] = field(default_factory=lambda: ["extrusion"])
    bounds: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])

    def window(self, first: int, count: int) -> dict[str, Any]:
        first = max(0, min(first, max(len(self.z) - 1, 0)))
        chosen = range(first, min(first + count, len(self.z)))
        return {"count": len(self.z), "z": [round(z, 3) for z in self.z], "types": self.types,
                "bounds": [round(b, 2) for b in self.bounds], "from": first,
                "layers": [{"index": i, "z": round(self.z[i], 3),
                            "paths": [[t, *[round(c, 2) for c in pts]]
                                      for t, pts in self.paths[i]]} for i in chosen]}


def gcode_layers(job: Job) -> Layers:
    from daemon.web.snapshot import _gcode_path

    path = _gcode_path(job)
    if path is None:
        raise Refused(404, f"job {job.id} has no G-code ({job.state})")
    ident = _identity(path)
    if ident and ident[1] > MAX_PREVIEW_GCODE_BYTES:
        raise Refused(413, f"the G-code is {ident[1] / 1048576:.0f} MB, too large to preview "
                           f"(the limit is {MAX_PREVIEW_GCODE_BYTES // 1048576} MB)")
    cached = _LAYERS.get(ident)
    if cached is None:
        with _COMPUTING:
            cached = _LAYERS.get(ident)
            if cached is None:
                with open(path, encoding="utf-8", errors="replace") as lines:
                    cached = read_layers(lines)
                _LAYERS.put(ident, cached)
    return cached
