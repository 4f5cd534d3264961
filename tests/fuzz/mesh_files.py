"""Hypothesis strategies that build small mesh files, valid and hostile, for every format
``repair.io.load_mesh`` reads. Each returns the file's bytes; ``targets_mesh`` saves them
under the right suffix and loads them.

The hostile knobs are drawn next to the valid ones: lying counts, NaN and infinite
coordinates, out-of-range indices, 3MF component nesting and cycles, DTDs with entity
expansion or external entities, highly compressible padding and many-entry archives.
"""

from __future__ import annotations

import io
import struct
import zipfile

import numpy as np
from hypothesis import strategies as st

#: Coordinates: mostly ordinary, sometimes NaN, infinite or beyond float32.
coordinates = st.one_of(
    st.floats(-100, 100, allow_nan=False, width=32),
    st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.0, -0.0, 3.5e38, 1e300]),
)
#: Counts a header may declare: honest small ones and absurd ones.
declared_counts = st.one_of(
    st.integers(0, 8), st.sampled_from([2**31 - 1, 2**31, 2**32 - 1, 10**9, 10**18])
)
#: 1-based OBJ / 0-based PLY/3MF indices, in range or not.
indices = st.one_of(st.integers(-6, 8), st.sampled_from([0, -1, 2**31, 2**63 - 1, -(2**40)]))


def _text_number(value: float) -> str:
    return repr(float(value))


@st.composite
def triangles(draw, max_triangles: int = 6) -> np.ndarray:
    """(m, 3, 3) float64 corners, m >= 1, possibly with NaN/Inf coordinates."""
    count = draw(st.integers(1, max_triangles))
    values = draw(st.lists(coordinates, min_size=9 * count, max_size=9 * count))
    return np.array(values, dtype=np.float64).reshape(count, 3, 3)


@st.composite
def stl_binary(draw) -> bytes:
    tri = draw(triangles())
    with np.errstate(over="ignore"):
        corners = tri.astype("<f4")
    records = b"".join(
        struct.pack("<3f", 0, 0, 0) + corner.tobytes() + b"\0\0" for corner in corners
    )
    header = draw(st.sampled_from([b"binary", b"solid lying binary header", b""])).ljust(80)
    count = draw(st.one_of(st.just(len(tri)), declared_counts)) % 2**32
    return header + struct.pack("<I", count) + records


@st.composite
def stl_ascii(draw) -> bytes:
    tri = draw(triangles())
    per_facet = draw(st.sampled_from([3, 3, 3, 2, 4]))  # vertex lines per facet
    lines = ["solid fuzz"]
    for corners in tri:
        lines += ["facet normal 0 0 1", " outer loop"]
        lines += [f"  vertex {' '.join(map(_text_number, c))}" for c in corners[:per_facet]]
        lines += [" endloop", "endfacet"]
    lines.append("endsolid fuzz")
    return "\n".join(lines).encode() + b"\n"


@st.composite
def obj_text(draw) -> bytes:
    n_vertices = draw(st.integers(1, 6))
    values = draw(st.lists(coordinates, min_size=3 * n_vertices, max_size=3 * n_vertices))
    lines = [f"v {' '.join(map(_text_number, values[i:i + 3]))}" for i in range(0, len(values), 3)]
    for _ in range(draw(st.integers(1, 4))):
        keyword = draw(st.sampled_from(["f", "f", "l"]))
        refs = draw(st.lists(indices, min_size=1, max_size=5))
        style = draw(st.sampled_from(["{}", "{}/1", "{}//2", "{}/1/2"]))
        lines.append(keyword + " " + " ".join(style.format(r) for r in refs))
    if draw(st.booleans()):
        lines.insert(draw(st.integers(0, len(lines))), "# a comment \\")
    return "\n".join(lines).encode() + b"\n"


_PLY_TYPES = {"float": "<f4", "double": "<f8", "int": "<i4", "uchar": "u1", "ushort": "<u2"}


@st.composite
def ply_file(draw) -> bytes:
    binary = draw(st.booleans())
    n_vertices = draw(st.integers(1, 6))
    values = draw(st.lists(coordinates, min_size=3 * n_vertices, max_size=3 * n_vertices))
    faces = draw(st.lists(st.lists(indices, min_size=3, max_size=3), min_size=1, max_size=4))
    vertex_type = draw(st.sampled_from(["float", "double"]))
    index_type = draw(st.sampled_from(["int", "uchar", "ushort"]))
    declared_v = draw(st.one_of(st.just(n_vertices), declared_counts))
    declared_f = draw(st.one_of(st.just(len(faces)), declared_counts))
    header = [
        "ply",
        "format " + ("binary_little_endian" if binary else "ascii") + " 1.0",
        f"element vertex {declared_v}",
        *(f"property {vertex_type} {axis}" for axis in "xyz"),
        f"element face {declared_f}",
        f"property list uchar {index_type} vertex_indices",
        "end_header",
    ]
    head = ("\n".join(header) + "\n").encode()
    if not binary:
        body = [" ".join(map(_text_number, values[i:i + 3])) for i in range(0, len(values), 3)]
        body += ["3 " + " ".join(str(i) for i in face) for face in faces]
        return head + ("\n".join(body) + "\n").encode()
    with np.errstate(over="ignore", invalid="ignore"):
        vertex_bytes = np.array(values, dtype=np.float64).astype(_PLY_TYPES[vertex_type])
        index_dtype = np.dtype(_PLY_TYPES[index_type])
        info = np.iinfo(index_dtype)
        face_bytes = b"".join(
            b"\x03" + np.clip(np.array(face), info.min, info.max).astype(index_dtype).tobytes()
            for face in faces
        )
    return head + vertex_bytes.tobytes() + face_bytes


# --------------------------------------------------------------------------- 3MF

_NS = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
_NS_PROD = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
_RELS = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
    '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
    'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>'
)
_BILLION_LAUGHS = (
    '<!DOCTYPE model [<!ENTITY lol "lol">'
    + "".join(f'<!ENTITY lol{k} "{("&lol" + (str(k - 1) if k > 1 else "") + ";") * 10}">'
              for k in range(1, 10))
    + "]>"
)
_EXTERNAL_ENTITY = '<!DOCTYPE model [<!ENTITY ext SYSTEM "file:///etc/passwd">]>'


def _attributes(names: tuple[str, ...], values: list, order: list[int]) -> str:
    """XML attributes in the drawn order; an order longer than the names adds a stray
    attribute, a shorter one leaves some out."""
    pairs = [(names[k], values[k]) if k < len(names) else ("color", "#fff") for k in order]
    return " ".join(f'{key}="{value}"' for key, value in pairs)


def _mesh_object(object_id: int, tri: np.ndarray, refs: list[list[int]],
                 order: list[int]) -> str:
    corners = tri.reshape(-1, 3)
    vertices = "".join(
        f"<vertex {_attributes(('x', 'y', 'z'), list(map(_text_number, c)), order)}/>"
        for c in corners.tolist()
    )
    faces = "".join(f"<triangle {_attributes(('v1', 'v2', 'v3'), r, order)}/>" for r in refs)
    return (f'<object id="{object_id}" type="model"><mesh><vertices>{vertices}</vertices>'
            f"<triangles>{faces}</triangles></mesh></object>")


#: Attribute orders: the usual one (the parser's fast path), shuffled, one stray extra,
#: one missing.
attribute_orders = st.sampled_from([[0, 1, 2], [0, 1, 2], [2, 0, 1], [0, 1, 2, 3], [0, 1]])
#: Component and item transforms: none, a valid one, non-finite, too short, not numbers.
transforms = st.sampled_from(["", ' transform="1 0 0 0 1 0 0 0 1 5 5 5"',
                              ' transform="0 1 0 -1 0 0 0 0 2 0 0 0"',
                              ' transform="nan 0 0 0 1 0 0 0 1 0 0 0"',
                              ' transform="1 2 3"', ' transform="a b c"'])


@st.composite
def threemf_model(draw) -> str:
    """A model part: one mesh object, then a chain of component objects over it (each may
    point at any earlier object, or at a later one: a cycle), and build items."""
    tri = draw(triangles(max_triangles=3))
    n_corners = 3 * len(tri)
    refs = draw(st.lists(st.lists(st.one_of(st.integers(0, n_corners - 1), indices),
                                  min_size=3, max_size=3), min_size=1, max_size=4))
    objects = [_mesh_object(1, tri, refs, draw(attribute_orders))]
    depth = draw(st.sampled_from([0, 1, 3, 40]))
    for object_id in range(2, depth + 2):
        fan_out = draw(st.integers(1, 3))
        children = draw(st.lists(st.integers(1, depth + 2), min_size=fan_out, max_size=fan_out))
        transform = draw(transforms)
        path = draw(st.sampled_from(["", "", ' p:path="/3D/other.model"', ' p:path="/nowhere"']))
        object_attrs = f'id="{object_id}"' if draw(st.integers(0, 20)) else 'name="no id"'
        objects.append(f'<object {object_attrs} type="model"><components>'
                       + "".join(f'<component objectid="{c}"{path}{transform}/>'
                                 for c in children)
                       + "</components></object>")
    unit = draw(st.sampled_from(["millimeter", "inch", "parsec", "micron"]))
    doctype = draw(st.sampled_from(["", "", _BILLION_LAUGHS, _EXTERNAL_ENTITY]))
    text_entity = {_BILLION_LAUGHS: "&lol9;", _EXTERNAL_ENTITY: "&ext;"}.get(doctype, "")
    item_transform = draw(transforms)
    build = (f'<item objectid="{depth + 1}"{item_transform}/>'
             if draw(st.booleans()) or not depth else "")
    build += "".join(f'<item objectid="{i}"/>' for i in draw(st.lists(st.integers(0, 3),
                                                                       max_size=2)))
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n{doctype}<model unit="{unit}" '
            f'xmlns="{_NS}" xmlns:p="{_NS_PROD}"><metadata name="Title">{text_entity}</metadata>'
            f"<resources>{''.join(objects)}</resources><build>{build}</build></model>")


#: Relationship parts: none, the usual one, pointing nowhere, with a DTD, not XML.
_RELS_VARIANTS = [None, _RELS, _RELS.replace("/3D/3dmodel.model", "/3D/missing.model"),
                  _RELS.replace("<Relationships", _EXTERNAL_ENTITY + "<Relationships"),
                  "<Relationships><unclosed"]


@st.composite
def threemf_file(draw) -> bytes:
    """A 3MF zip: the model part (sometimes edited at the XML text level, sometimes under
    an unusual name), optionally padded with highly compressible blanks (zip bomb shape),
    a second model part for production-extension paths, many tiny entries, and one of
    several relationship parts."""
    model = draw(threemf_model()).encode()
    if draw(st.integers(0, 3)) == 0:
        model = draw(mutated(st.just(model)))
    padding = draw(st.sampled_from([0, 0, 0, 0, 1 << 20, 22 << 20]))
    if padding:  # the padding sits inside the model, where the parser has to read it
        model = model.replace(b"<resources>", b"<resources>" + b" " * padding, 1)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        rels = draw(st.sampled_from(_RELS_VARIANTS))
        if rels is not None:
            archive.writestr("_rels/.rels", rels)
        part = draw(st.sampled_from(["3D/3dmodel.model", "3D/3dmodel.model", "3D/Other.MODEL"]))
        archive.writestr(part, model, compresslevel=1 if padding else None)
        if draw(st.booleans()):
            archive.writestr("3D/other.model", draw(threemf_model()))
        for k in range(draw(st.sampled_from([0, 0, 0, 500]))):
            archive.writestr(f"Metadata/{k}.txt", b"", compress_type=zipfile.ZIP_STORED)
    return buffer.getvalue()


# --------------------------------------------------------------------------- mutation


@st.composite
def mutated(draw, valid: st.SearchStrategy[bytes]) -> bytes:
    """A valid file with a few byte-level edits: flips, inserts, deletions, truncation,
    or a splice with another valid file of the same format."""
    data = bytearray(draw(valid))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "splice"]))
        at = draw(st.integers(0, len(data)))
        if op == "flip" and data:
            at = min(at, len(data) - 1)
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif op == "delete":
            del data[at:at + draw(st.integers(1, 16))]
        elif op == "truncate":
            del data[at:]
        elif op == "splice":
            other = draw(valid)
            data[at:] = other[draw(st.integers(0, len(other))):]
    return bytes(data)


def valid_or_mutated(valid: st.SearchStrategy[bytes]) -> st.SearchStrategy[bytes]:
    return st.one_of(valid, mutated(valid))
