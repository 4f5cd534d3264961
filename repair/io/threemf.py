"""3MF in: a zip archive of XML model parts, read under a decompressed-size budget."""

from __future__ import annotations

import io
import zipfile
import zlib
from pathlib import Path
from typing import IO
from xml.parsers import expat

import numpy as np

from repair.io.base import (
    Mesh,
    MeshReadError,
    check_triangle_cap,
    finish,
    human_bytes,
    parse_floats,
)

# 3MF model units, as factors to millimetres.
_UNITS_MM = {
    "micron": 0.001,
    "millimeter": 1.0,
    "centimeter": 10.0,
    "inch": 25.4,
    "foot": 304.8,
    "meter": 1000.0,
}
_NS_CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
_NS_PROD = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
_NS_RELS = "http://schemas.openxmlformats.org/package/2006/relationships"
_REL_MODEL = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"
#: What a damaged zip raises while being opened or inflated: a bad structure, a corrupt
#: deflate stream, an unsupported compression method, an encrypted entry (RuntimeError),
#: a non-UTF-8 name flagged as UTF-8, or a seek outside the file.
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, OSError, EOFError, RuntimeError,
               NotImplementedError, UnicodeDecodeError)
_SEP = " "  # expat's namespace separator
_T_VERTEX, _T_TRIANGLE, _T_OBJECT, _T_MESH, _T_COMPONENT, _T_ITEM, _T_MODEL = (
    _NS_CORE + _SEP + tag
    for tag in ("vertex", "triangle", "object", "mesh", "component", "item", "model")
)
_PROD_PATH = _NS_PROD + _SEP + "path"


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
                f"{self.name}: 3MF decompresses to more than {human_bytes(self.limit)}; "
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


class _ModelParser:
    """Streams one .model part through expat: (unit, objects, build items).

    ``objects``: {id: ("mesh", vertices, faces) | ("components", [(path, id, T), ...])}.
    Vertex and triangle attributes are collected flat and converted with one numpy call
    per object. A DTD is refused outright: 3MF (an OPC package) forbids DTDs, and
    refusing them closes entity expansion ("billion laughs") and external entities.
    """

    def __init__(self, part: str, name: str) -> None:
        self.part, self.name = part, name
        self.unit = "millimeter"
        self.obj: str | None = None
        self.mesh = False
        self.done = 0  # triangles in finished objects
        self.objects: dict[str, tuple] = {}
        self.items: list[tuple[str, str, np.ndarray | None]] = []
        self.vals_v: list[str] = []
        self.vals_t: list[str] = []
        self.comps: list[tuple[str, str, np.ndarray | None]] = []

    def pending_triangles(self) -> int:
        return self.done + len(self.vals_t) // 3

    def start(self, tag: str, attrs: list[str]) -> None:
        # Hot path first: one call per vertex / triangle.
        if tag == _T_VERTEX:
            if len(attrs) == 6 and attrs[0] == "x" and attrs[2] == "y" and attrs[4] == "z":
                self.vals_v.extend((attrs[1], attrs[3], attrs[5]))
            else:
                self.vals_v.extend(_pick(attrs, ("x", "y", "z")))
        elif tag == _T_TRIANGLE:
            if len(attrs) >= 6 and attrs[0] == "v1" and attrs[2] == "v2" and attrs[4] == "v3":
                self.vals_t.extend((attrs[1], attrs[3], attrs[5]))
            else:
                self.vals_t.extend(_pick(attrs, ("v1", "v2", "v3")))
        elif tag == _T_COMPONENT or tag == _T_ITEM:
            d = dict(zip(attrs[::2], attrs[1::2], strict=False))
            entry = (d.get(_PROD_PATH, self.part), d.get("objectid", ""))
            target = self.comps if tag == _T_COMPONENT else self.items
            target.append((*entry, _parse_transform(d.get("transform"), self.name)))
        elif tag == _T_OBJECT:
            d = dict(zip(attrs[::2], attrs[1::2], strict=False))
            if "id" not in d:
                raise MeshReadError(f"{self.name}: malformed 3MF: an object without id")
            self.obj, self.mesh = d["id"], False
            self.vals_v.clear()
            self.vals_t.clear()
            self.comps.clear()
        elif tag == _T_MESH:
            self.mesh = True
        elif tag == _T_MODEL:
            d = dict(zip(attrs[::2], attrs[1::2], strict=False))
            self.unit = d.get("unit", "millimeter")

    def end(self, tag: str) -> None:
        if tag != _T_OBJECT:
            return
        oid = self.obj
        if self.mesh:
            v = parse_floats(" ".join(self.vals_v).encode())
            f = parse_floats(" ".join(self.vals_t).encode())
            if (
                v is None
                or f is None
                or len(v) != len(self.vals_v)
                or len(f) != len(self.vals_t)
                or not np.all(f == np.round(f))
                or (len(f) and np.abs(f).max() > 2**53)  # also inf: not an index
            ):
                raise MeshReadError(
                    f"{self.name}: malformed 3MF: unreadable vertices or triangles in object {oid}"
                )
            self.objects[oid] = ("mesh", v.reshape(-1, 3), f.astype(np.int64).reshape(-1, 3))
            self.done += len(f) // 3
            self.vals_v.clear()
            self.vals_t.clear()
        else:
            self.objects[oid] = ("components", list(self.comps))
        self.obj = None

    def doctype(self, *_args: object) -> None:
        raise MeshReadError(
            f"{self.name}: malformed 3MF: {self.part} has a DTD (not allowed in 3MF); refusing"
        )

    def parse(self, stream: IO[bytes], tri_before: int, max_triangles: int | None) -> None:
        parser = expat.ParserCreate(namespace_separator=_SEP)
        parser.ordered_attributes = True
        parser.buffer_text = True
        parser.StartElementHandler = self.start
        parser.EndElementHandler = self.end
        parser.StartDoctypeDeclHandler = self.doctype
        try:
            while True:
                chunk = stream.read(1 << 20)
                parser.Parse(chunk, not chunk)
                seen = tri_before + self.pending_triangles()
                if max_triangles is not None and seen > max_triangles:
                    raise MeshReadError(
                        f"{self.name}: 3MF has more than {max_triangles} triangles, "
                        "over the limit"
                    )
                if not chunk:
                    break
        except expat.ExpatError as exc:
            raise MeshReadError(
                f"{self.name}: malformed 3MF: XML error in {self.part}: {exc}"
            ) from None


def _pick(attrs: list[str], keys: tuple[str, str, str]) -> tuple[str, str, str]:
    d = dict(zip(attrs[::2], attrs[1::2], strict=False))
    return (d.get(keys[0], "?"), d.get(keys[1], "?"), d.get(keys[2], "?"))


def _model_targets(data: bytes, name: str) -> list[str]:
    """Targets of the 3D-model relationships in a ``_rels/.rels`` part ([] if unreadable)."""
    targets: list[str] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        if tag == _NS_RELS + _SEP + "Relationship" and attrs.get("Type") == _REL_MODEL:
            targets.append(attrs.get("Target", "").lstrip("/"))

    def doctype(*_args: object) -> None:
        raise MeshReadError(f"{name}: malformed 3MF: _rels/.rels has a DTD; refusing")

    parser = expat.ParserCreate(namespace_separator=_SEP)
    parser.StartElementHandler = start
    parser.StartDoctypeDeclHandler = doctype
    try:
        parser.Parse(data, True)
    except expat.ExpatError:
        return []
    return targets


def _root_model_part(zf: zipfile.ZipFile, budget: _Budget, name: str) -> str:
    names = set(zf.namelist())
    if "_rels/.rels" in names:
        try:
            rels = _read_zip_entry(zf, "_rels/.rels", budget)
        except _ZIP_ERRORS as exc:
            raise MeshReadError(f"{name}: corrupt 3MF archive: {exc}") from None
        for target in _model_targets(rels, name):
            if target in names:
                return "/" + target
    for cand in ("3D/3dmodel.model",):
        if cand in names:
            return "/" + cand
    models = sorted(n for n in names if n.lower().endswith(".model"))
    if models:
        return "/" + models[0]
    raise MeshReadError(f"{name}: not a 3MF file: no 3D model part in the archive")


#: Most component instances one file may expand to. Nesting multiplies instances (two
#: components per level, 32 levels: 4 billion instances), so the count is capped too.
MAX_3MF_INSTANCES = 1 << 14
_MAX_DEPTH = 32


class _Assembly:
    """Reads the parts of an open 3MF archive on demand and flattens the build into one
    vertex and face list, composing component transforms."""

    def __init__(self, zf: zipfile.ZipFile, budget: _Budget, name: str,
                 max_triangles: int | None) -> None:
        self.zf, self.budget, self.name = zf, budget, name
        self.max_triangles = max_triangles
        self.parts: dict[str, _ModelParser] = {}
        self.triangles_read = 0
        self.out_v: list[np.ndarray] = []
        self.out_f: list[np.ndarray] = []
        self.n_vertices = self.n_triangles = self.instances = 0

    def load_part(self, part: str) -> _ModelParser:
        if part in self.parts:
            return self.parts[part]
        name = self.name
        try:
            info = self.zf.getinfo(part.lstrip("/"))
        except KeyError:
            raise MeshReadError(f"{name}: malformed 3MF: missing part {part}") from None
        if info.file_size > self.budget.left:  # refuse before inflating anything
            raise MeshReadError(
                f"{name}: 3MF part {part} declares {human_bytes(info.file_size)} "
                f"uncompressed, over the {human_bytes(self.budget.limit)} limit; "
                "refusing (zip bomb?)"
            )
        model = _ModelParser(part, name)
        try:
            with self.zf.open(info) as raw:
                reader = io.BufferedReader(_LimitedReader(raw, self.budget))
                model.parse(reader, self.triangles_read, self.max_triangles)
        except _ZIP_ERRORS as exc:
            raise MeshReadError(f"{name}: corrupt 3MF archive: {exc}") from None
        self.triangles_read += model.done
        self.parts[part] = model
        return model

    def emit(self, part: str, oid: str, transform: np.ndarray | None,
             path: tuple[tuple[str, str], ...] = ()) -> None:
        name = self.name
        if (part, oid) in path:
            raise MeshReadError(f"{name}: malformed 3MF: object {oid} contains itself")
        if len(path) > _MAX_DEPTH:
            raise MeshReadError(f"{name}: malformed 3MF: components nested too deep")
        self.instances += 1
        if self.instances > MAX_3MF_INSTANCES:
            raise MeshReadError(
                f"{name}: 3MF expands to more than {MAX_3MF_INSTANCES} object instances"
            )
        objs = self.load_part(part).objects
        if oid not in objs:
            raise MeshReadError(f"{name}: malformed 3MF: no object {oid} in {part}")
        obj = objs[oid]
        if obj[0] == "components":
            for cpart, cid, ct in obj[1]:
                self.emit(cpart, cid, _compose(transform, ct), (*path, (part, oid)))
            return
        v, f = obj[1], obj[2]
        if len(f) == 0:
            return
        if f.min() < 0 or f.max() >= len(v):
            raise MeshReadError(
                f"{name}: malformed 3MF: a triangle refers to a missing vertex in object {oid}"
            )
        self.n_triangles += len(f)
        check_triangle_cap(self.n_triangles, self.max_triangles, name)
        if transform is not None:
            v = v @ transform[:3] + transform[3]
        self.out_v.append(v)
        self.out_f.append(f + self.n_vertices)
        self.n_vertices += len(v)


def read_3mf(path: Path, name: str, max_triangles: int | None, max_decompressed: int) -> Mesh:
    budget = _Budget(max_decompressed, name)
    try:
        zf = zipfile.ZipFile(path)
    except _ZIP_ERRORS as exc:
        raise MeshReadError(f"{name}: not a 3MF file (not a valid zip archive: {exc})") from None
    with zf:
        assembly = _Assembly(zf, budget, name, max_triangles)
        root = assembly.load_part(_root_model_part(zf, budget, name))
        if root.unit not in _UNITS_MM:
            raise MeshReadError(f"{name}: 3MF has an unknown unit {root.unit!r}")
        scale = _UNITS_MM[root.unit]
        if not root.items:
            raise MeshReadError(f"{name}: 3MF has no build items (nothing to print)")
        for ipart, iid, it in root.items:
            assembly.emit(ipart, iid, it)
    if not assembly.out_f:
        raise MeshReadError(f"{name}: the 3MF file contains no triangles")
    vertices = np.vstack(assembly.out_v) * scale
    return finish(vertices, np.vstack(assembly.out_f), "3mf", name, unit_scale=scale)
