"""Small mesh files for the reader tests: a cube, an ASCII STL, a minimal 3MF package."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh

from repair.io import Mesh, MeshReadError, load_mesh


def write_3mf(
    path: Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    unit: str = "millimeter",
    item_transform: str | None = None,
    component_transform: str | None = None,
) -> None:
    """Write a minimal 3MF package (core spec): one mesh object, optionally wrapped in a
    components object, one build item. Transforms are 12 numbers, 3MF row-vector order."""
    vs = "\n".join(f'<vertex x="{x!r}" y="{y!r}" z="{z!r}"/>' for x, y, z in vertices.tolist())
    ts = "\n".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in faces.tolist())
    objects = (
        f'<object id="1" type="model"><mesh><vertices>\n{vs}\n</vertices>'
        f"<triangles>\n{ts}\n</triangles></mesh></object>"
    )
    build_id = "1"
    if component_transform is not None:
        objects += (
            '<object id="2" type="model"><components>'
            f'<component objectid="1" transform="{component_transform}"/>'
            "</components></object>"
        )
        build_id = "2"
    item_attr = f' transform="{item_transform}"' if item_transform else ""
    model = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<model unit="{unit}" xml:lang="en-US" '
        'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">\n'
        f"<resources>{objects}</resources>\n"
        f'<build><item objectid="{build_id}"{item_attr}/></build>\n</model>\n'
    )
    rels = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
        '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
        'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>'
        "</Relationships>\n"
    )
    types = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">'
        '<Default Extension="rels" '
        'ContentType="application/vnd.openxmlformats-package.relationships+xml"/>'
        '<Default Extension="model" '
        'ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>'
        "</Types>\n"
    )
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("[Content_Types].xml", types)
        zf.writestr("_rels/.rels", rels)
        zf.writestr("3D/3dmodel.model", model)


def cube(size: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.box(bounds=[[0, 0, 0], [size, size, size]])
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def ascii_stl(vertices: np.ndarray, faces: np.ndarray, name: str = "part") -> bytes:
    out = [f"solid {name}"]
    for tri in vertices[faces]:
        out.append("  facet normal 0 0 0\n    outer loop")
        out += [f"      vertex {x!r} {y!r} {z!r}" for x, y, z in tri.tolist()]
        out.append("    endloop\n  endfacet")
    out.append(f"endsolid {name}\n")
    return "\n".join(out).encode()


def same_triangles(a: Mesh, vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Same triangle soup (corner coordinates, in order) regardless of vertex indexing."""
    return np.array_equal(a.vertices[a.faces], np.asarray(vertices, float)[faces])


def assert_refused(path: Path, match: str) -> str:
    """``load_mesh`` with the daemon's limits refuses ``path`` with one short line."""
    with pytest.raises(MeshReadError, match=match) as err:
        load_mesh(path, max_bytes=1 << 20, max_triangles=2_000_000)
    message = str(err.value)
    assert "\n" not in message and len(message) <= 300
    return message
