"""3MF reading: units, transforms, components, production parts, zip bombs, damage."""

from __future__ import annotations

import struct
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from io_files import assert_refused, cube, write_3mf

from repair.check import check_printable
from repair.io import MeshReadError, load_mesh

REPO = Path(__file__).resolve().parents[2]
FUZZ_DATA = REPO / "tests" / "data" / "fuzz"


def test_3mf_attribute_order_extra_attributes_and_two_objects(tmp_path):
    v, f = cube(1.0)
    # vertices with attributes in another order, triangles with colour properties
    vs = "".join(f'<vertex z="{z}" y="{y}" x="{x}"/>' for x, y, z in v.tolist())
    ts = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}" pid="2" p1="0"/>' for a, b, c in f.tolist())
    ts_reordered = "".join(f'<triangle v3="{c}" v1="{a}" v2="{b}"/>' for a, b, c in f.tolist())
    core = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
    model = (
        f'<?xml version="1.0"?><model unit="millimeter" xmlns="{core}"><resources>'
        f'<object id="1" type="model"><mesh><vertices>{vs}</vertices>'
        f"<triangles>{ts}</triangles></mesh></object>"
        f'<object id="2" type="model"><mesh><vertices>{vs}</vertices>'
        f"<triangles>{ts_reordered}</triangles></mesh></object></resources>"
        '<build><item objectid="1"/><item objectid="2" transform="1 0 0 0 1 0 0 0 1 3 0 0"/>'
        "</build></model>"
    )
    p = tmp_path / "two.3mf"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("3D/3dmodel.model", model)
    m = load_mesh(p)
    assert m.triangles == 24
    assert np.allclose(m.vertices[m.faces[:12]], v[f])
    assert np.allclose(m.vertices[m.faces[12:]], v[f] + [3, 0, 0])
    assert check_printable(m.vertices, m.faces).ok
    with pytest.raises(MeshReadError, match="limit"):
        load_mesh(p, max_triangles=20)


def test_3mf_production_extension_parts(tmp_path):
    # Slicer project files keep meshes in separate model parts referenced by p:path.
    v, f = cube(5.0)
    vs = "".join(f'<vertex x="{x}" y="{y}" z="{z}"/>' for x, y, z in v.tolist())
    ts = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in f.tolist())
    core = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
    prod = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
    part = (
        f'<?xml version="1.0"?><model unit="millimeter" xmlns="{core}"><resources>'
        f'<object id="7" type="model"><mesh><vertices>{vs}</vertices>'
        f"<triangles>{ts}</triangles></mesh></object></resources><build/></model>"
    )
    root = (
        f'<?xml version="1.0"?><model unit="centimeter" xmlns="{core}" xmlns:p="{prod}">'
        '<resources><object id="1" type="model"><components>'
        '<component p:path="/3D/Objects/part.model" objectid="7"/>'
        '<component p:path="/3D/Objects/part.model" objectid="7" '
        'transform="1 0 0 0 1 0 0 0 1 10 0 0"/>'
        '</components></object></resources><build><item objectid="1"/></build></model>'
    )
    p = tmp_path / "project.3mf"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("3D/3dmodel.model", root)
        zf.writestr("3D/Objects/part.model", part)
    m = load_mesh(p)
    assert m.triangles == 24 and m.unit_scale == 10.0
    assert np.allclose(m.vertices.min(axis=0), 0) and np.allclose(
        m.vertices.max(axis=0), [150, 50, 50]
    )
    assert check_printable(m.vertices, m.faces).ok


@pytest.mark.parametrize(
    "unit,scale",
    [("micron", 0.001), ("millimeter", 1.0), ("centimeter", 10.0), ("inch", 25.4),
     ("foot", 304.8), ("meter", 1000.0)],
)  # fmt: skip
def test_3mf_units(tmp_path, unit, scale):
    v, f = cube(1.0)
    p = tmp_path / f"{unit}.3mf"
    write_3mf(p, v, f, unit=unit)
    m = load_mesh(p)
    assert m.source_format == "3mf" and m.unit_scale == scale
    assert np.allclose(m.vertices[m.faces], v[f] * scale)
    assert check_printable(m.vertices, m.faces).volume == pytest.approx(scale**3)


def test_3mf_inch_cube_is_scaled(tmp_path):
    v, f = cube(1.0)
    p = tmp_path / "inch.3mf"
    write_3mf(p, v, f, unit="inch")
    m = load_mesh(p)
    assert m.unit_scale == 25.4
    assert np.allclose(m.vertices.max(axis=0) - m.vertices.min(axis=0), 25.4)


def test_3mf_transforms(tmp_path):
    v, f = cube(2.0)
    # component: rotate 90° about z (x -> y, y -> -x), then item: translate (10, 20, 30).
    rot = "0 1 0 -1 0 0 0 0 1 0 0 0"
    p = tmp_path / "t.3mf"
    write_3mf(p, v, f, component_transform=rot, item_transform="1 0 0 0 1 0 0 0 1 10 20 30")
    m = load_mesh(p)
    expected = np.c_[-v[:, 1], v[:, 0], v[:, 2]] + [10, 20, 30]
    assert np.allclose(m.vertices[m.faces], expected[f])
    # a mirroring transform keeps the file's winding: the loader does not "fix" it
    write_3mf(p, v, f, item_transform="-1 0 0 0 1 0 0 0 1 0 0 0")
    assert check_printable(load_mesh(p).vertices, load_mesh(p).faces).volume < 0


def _bomb_3mf(path: Path, padding: int) -> None:
    """A valid 20 mm cube 3MF whose model XML carries ``padding`` bytes of whitespace
    (which deflate compresses about 1000:1)."""
    v, f = cube()
    write_3mf(path, v, f)
    with zipfile.ZipFile(path) as zf:
        entries = [(i.filename, zf.read(i)) for i in zf.infolist()]
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for fname, body in entries:
            if fname != "3D/3dmodel.model":
                zf.writestr(fname, body)
                continue
            head, tail = body.split(b"<resources>")
            with zf.open(fname, "w", force_zip64=True) as fh:
                fh.write(head + b"<resources>")
                block = b" " * (1 << 20)
                for _ in range(padding >> 20):
                    fh.write(block)
                fh.write(tail)


def test_3mf_zip_bomb_is_refused_without_exhausting_memory(tmp_path):
    p = tmp_path / "bomb.3mf"
    _bomb_3mf(p, 256 << 20)  # 256 MiB of XML in a file of ~250 KiB
    assert p.stat().st_size < 2 << 20
    tracemalloc.start()
    try:
        with pytest.raises(MeshReadError, match="zip bomb"):
            load_mesh(p, max_bytes=4 << 20)  # cap: 20 x 4 MiB = 80 MiB decompressed
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 << 20


def test_3mf_zip_bomb_with_a_lying_size_header(tmp_path):
    # Declared uncompressed size patched down to 1000 bytes: the declared-size check
    # passes, inflation must still stop (Python's zipfile stops at the declared size and
    # the CRC no longer matches) and be reported in one line, with memory bounded.
    p = tmp_path / "liar.3mf"
    _bomb_3mf(p, 64 << 20)
    data = bytearray(p.read_bytes())
    name = b"3D/3dmodel.model"
    patched = 0
    for sig, size_off, name_off in ((b"PK\x01\x02", 24, 46), (b"PK\x03\x04", 22, 30)):
        start = 0
        while (i := data.find(sig, start)) >= 0:
            start = i + 4
            if data[i + name_off : i + name_off + len(name)] == name:
                size = struct.unpack_from("<I", data, i + size_off)[0]
                if size != 0xFFFFFFFF:
                    struct.pack_into("<I", data, i + size_off, 1000)
                    patched += 1
    p.write_bytes(bytes(data))
    assert patched >= 1
    tracemalloc.start()
    try:
        with pytest.raises(MeshReadError) as err:
            load_mesh(p, max_decompressed=8 << 20)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "\n" not in str(err.value)
    assert peak < 64 << 20


def test_3mf_padded_but_honest_file_loads_under_the_cap(tmp_path):
    p = tmp_path / "padded.3mf"
    _bomb_3mf(p, 8 << 20)
    assert load_mesh(p).triangles == 12  # default cap is 1 GiB
    with pytest.raises(MeshReadError, match="zip bomb"):
        load_mesh(p, max_decompressed=4 << 20)


def test_3mf_malformed(tmp_path):
    p = tmp_path / "bad.3mf"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("3D/3dmodel.model", "<model><resources><object id='1'>")
    with pytest.raises(MeshReadError, match="3MF"):
        load_mesh(p)
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("readme.txt", "no model here")
    with pytest.raises(MeshReadError, match="no 3D model"):
        load_mesh(p)


# --------------------------------------------------------------------------- fuzz finds


@pytest.mark.parametrize("name, match", [
    ("rels_seek_einval.3mf", "corrupt 3MF"),  # OSError EINVAL escaped from .rels
    ("rels_bad_crc.3mf", "corrupt 3MF"),  # BadZipFile escaped from .rels
    ("model_invalid_deflate_block.3mf", "corrupt 3MF"),  # zlib.error escaped
])
def test_fuzz_damaged_3mf_archives(name, match):
    assert_refused(FUZZ_DATA / name, match)


def test_fuzz_3mf_error_quoting_file_bytes_stays_one_short_line(tmp_path):
    # a local header whose name length is 256 too long: zipfile's error quoted 272 bytes
    # of the archive, a refusal of 825 characters
    p = tmp_path / "cube.3mf"
    write_3mf(p, *cube())
    data = bytearray(p.read_bytes())
    at = data.index(b"PK\x03\x04", data.index(b"3D/3dmodel.model") - 40)
    data[at + 27] += 1  # high byte of the file-name length
    p.write_bytes(bytes(data))
    message = assert_refused(p, "corrupt 3MF archive: File name in directory")
    assert message.endswith("\u2026")  # cut, not 825 characters


def _components_3mf(path: Path, objects: str, build: str) -> None:
    ns = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
    tri = ('<object id="1"><mesh><vertices><vertex x="0" y="0" z="0"/><vertex x="1" y="0" '
           'z="0"/><vertex x="0" y="1" z="0"/></vertices><triangles><triangle v1="0" v2="1" '
           'v3="2"/></triangles></mesh></object>')
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("3D/3dmodel.model", f'<model xmlns="{ns}"><resources>{tri}{objects}'
                                        f"</resources><build>{build}</build></model>")


def test_fuzz_3mf_component_fan_out_is_capped(tmp_path):
    # 30 levels of two components each: 2**30 instances of the triangle; this hung
    levels = "".join(
        f'<object id="{k}"><components><component objectid="{k - 1}"/>'
        f'<component objectid="{k - 1}"/></components></object>' for k in range(2, 32))
    p = tmp_path / "fan.3mf"
    _components_3mf(p, levels, '<item objectid="31"/>')
    assert_refused(p, "more than 16384 object instances")


def test_fuzz_3mf_component_cycle(tmp_path):
    p = tmp_path / "cycle.3mf"
    _components_3mf(p, '<object id="2"><components><component objectid="3"/></components>'
                       '</object><object id="3"><components><component objectid="2"/>'
                       "</components></object>", '<item objectid="2"/>')
    assert_refused(p, "contains itself")


@pytest.mark.parametrize("doctype", [
    '<!DOCTYPE model [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
    '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;"><!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">]>',
    '<!DOCTYPE model [<!ENTITY ext SYSTEM "file:///etc/passwd">]>',
])
def test_3mf_with_a_dtd_is_refused(tmp_path, doctype):
    """Entity expansion and external entities never reach the parser's expansion: 3MF
    (an OPC package) forbids DTDs, so any DTD is refused."""
    ns = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
    p = tmp_path / "dtd.3mf"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("3D/3dmodel.model", f'<?xml version="1.0"?>{doctype}<model xmlns="{ns}">'
                                        "<metadata>&d;&ext;</metadata></model>")
    assert_refused(p, "DTD")
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("_rels/.rels", f"<?xml version='1.0'?>{doctype}<Relationships/>")
        zf.writestr("3D/3dmodel.model", "<model/>")
    assert_refused(p, "DTD")
