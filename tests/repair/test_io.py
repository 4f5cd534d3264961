"""Mesh readers and the STL writer on real files: the corpus, files written here, bad files."""

from __future__ import annotations

import csv
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from io_files import ascii_stl, assert_refused, cube, same_triangles, write_3mf

from repair.check import check_printable, round_to_float32
from repair.io import MeshReadError, load_mesh, write_stl

REPO = Path(__file__).resolve().parents[2]
CORPUS = REPO.parent / "shared" / "corpus"
DATA = REPO / "tests" / "data"


def _corpus_rows() -> list[dict[str, str]]:
    manifest = CORPUS / "manifest.tsv"
    if not manifest.is_file():
        return []
    with open(manifest, newline="") as fh:
        return list(csv.DictReader(fh, delimiter="\t"))


# --------------------------------------------------------------------------- helpers


# --------------------------------------------------------------------------- corpus


@pytest.mark.parametrize("row", _corpus_rows(), ids=lambda r: r["file"])
def test_every_corpus_file_loads(row):
    mesh = load_mesh(CORPUS / row["file"])
    assert mesh.triangles == int(row["triangles"])
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
    assert np.isfinite(mesh.vertices).all()
    assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)
    assert mesh.unit_scale == 1.0


def test_corpus_present_or_skipped():
    if not CORPUS.is_dir():
        pytest.skip("corpus not present")
    files = {p.name for p in CORPUS.iterdir() if p.suffix.lower() in (".stl", ".obj", ".ply")}
    assert files == {r["file"] for r in _corpus_rows()}


@pytest.mark.skipif(not CORPUS.is_dir(), reason="corpus not present")
def test_corpus_defects_match_the_manifest():
    # Independent measurements in manifest.tsv; these files need no welding beyond STL's.
    expected = {
        "mikedh_wallhole.obj": {"degenerate_faces": 11, "intersecting_pairs": 50},
        "mikedh_bunny.ply": {"nonmanifold_edges": 150, "duplicate_faces": 87},
        "admesh_fill-holes-bad.stl": {"boundary_edges": 3, "intersecting_pairs": 0},
        "mikedh_counter.unitsmm.STL": {"intersecting_pairs": 2272, "components": 6},
        "DragonAceNL_1004825.stl": {"intersecting_pairs": 531, "components": 10},
    }
    for fname, counts in expected.items():
        m = load_mesh(CORPUS / fname)
        p = check_printable(m.vertices, m.faces).to_dict()
        assert {k: p[k] for k in counts} == counts, fname


# --------------------------------------------------------------------------- tests/data


def test_bundled_broken_model():
    m = load_mesh(DATA / "open_cube_stuck_to_side.stl")
    assert m.source_format == "stl-ascii" and m.triangles == 22
    p = check_printable(m.vertices, m.faces)
    assert not p.ok
    assert p.boundary_edges == 4 and p.intersecting_pairs == 15  # as in the manifest


def test_bundled_good_3mf():
    m = load_mesh(DATA / "cube_20mm.3mf")
    assert m.source_format == "3mf" and m.triangles == 12
    p = check_printable(m.vertices, m.faces)
    assert p.ok, p.failures()
    assert p.volume == pytest.approx(8000.0)
    assert np.allclose(m.vertices.min(axis=0), 0) and np.allclose(m.vertices.max(axis=0), 20)


# --------------------------------------------------------------------------- STL


def test_binary_round_trip(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=12.3456789)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    out = tmp_path / "sphere.stl"
    write_stl(out, v, f)
    assert out.stat().st_size == 84 + 50 * len(f)
    assert not out.read_bytes().startswith(b"solid")
    m = load_mesh(out)
    assert m.source_format == "stl-binary"
    assert m.triangles == len(f) and len(m.vertices) == len(v)  # shared corners re-welded
    assert same_triangles(m, round_to_float32(v), f)
    assert check_printable(m.vertices, m.faces).ok
    # per-face normals are stored, unit length, pointing outward on a sphere
    raw = np.frombuffer(
        out.read_bytes()[84:], dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]
    )
    assert np.allclose(np.linalg.norm(raw["n"], axis=1), 1.0, atol=1e-6)
    assert np.all(np.einsum("ij,ij->i", raw["n"], raw["v"].mean(axis=1)) > 0)
    # no temporary files left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sphere.stl"]


def test_binary_stl_whose_header_starts_with_solid(tmp_path):
    v, f = cube()
    out = tmp_path / "cad.stl"
    write_stl(out, v, f)
    data = bytearray(out.read_bytes())
    data[:80] = b"solid part exported by some CAD tool".ljust(80, b" ")
    out.write_bytes(bytes(data))
    m = load_mesh(out)
    assert m.source_format == "stl-binary"
    assert same_triangles(m, v, f)


def test_ascii_stl(tmp_path):
    v, f = cube(3.5)
    out = tmp_path / "a.stl"
    out.write_bytes(ascii_stl(v, f, name="cube 7 with numbers 1 2 3"))
    m = load_mesh(out)
    assert m.source_format == "stl-ascii"
    assert same_triangles(m, v, f) and len(m.vertices) == 8
    assert check_printable(m.vertices, m.faces).ok
    # upper case keywords and CRLF line ends are common in old exporters
    out.write_bytes(ascii_stl(v, f).upper().replace(b"\n", b"\r\n"))
    assert same_triangles(load_mesh(out), v, f)
    # a UTF-8 byte order mark and leading blank lines
    out.write_bytes(b"\xef\xbb\xbf\n\n" + ascii_stl(v, f))
    assert same_triangles(load_mesh(out), v, f)
    # "vertex" in the solid's name is not a vertex; deep indentation and tabs are fine
    text = ascii_stl(v, f, name="vertex 1 2 3").replace(
        b"      vertex", b"\t" + b" " * 30 + b"vertex"
    )
    out.write_bytes(text)
    assert same_triangles(load_mesh(out), v, f)


def test_ascii_stl_keeps_degenerate_triangles(tmp_path):
    v = np.array([[0, 0, 0], [0, 0, 40.0], [0, 0, 0]])
    out = tmp_path / "line.stl"
    out.write_bytes(ascii_stl(v, np.array([[0, 1, 2]])))
    m = load_mesh(out)
    assert m.triangles == 1 and len(m.vertices) == 2
    assert m.faces[0, 0] == m.faces[0, 2]


def test_truncated_binary_stl(tmp_path):
    v, f = cube()
    out = tmp_path / "t.stl"
    write_stl(out, v, f)
    out.write_bytes(out.read_bytes()[:-70])
    with pytest.raises(MeshReadError) as err:
        load_mesh(out)
    msg = str(err.value)
    assert "truncated" in msg and "12 triangles" in msg and str(84 + 50 * 12 - 70) in msg
    assert "\n" not in msg


def test_nan_coordinates(tmp_path):
    v, f = cube()
    out = tmp_path / "nan.stl"
    write_stl(out, v, f)
    data = bytearray(out.read_bytes())
    data[84 + 50 * 5 + 12 : 84 + 50 * 5 + 16] = struct.pack("<f", float("nan"))
    out.write_bytes(bytes(data))
    with pytest.raises(MeshReadError, match=r"NaN or infinite .* in 1 triangle\(s\), first is #5"):
        load_mesh(out)
    # ASCII, with inf
    text = ascii_stl(v, f).replace(b"vertex 20.0", b"vertex inf", 1)
    out.write_bytes(text)
    with pytest.raises(MeshReadError, match="infinite"):
        load_mesh(out)
    # OBJ
    obj = tmp_path / "nan.obj"
    obj.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshReadError, match="NaN"):
        load_mesh(obj)


def test_not_a_mesh(tmp_path):
    rng = np.random.default_rng(5)
    cases = {
        "random.stl": rng.bytes(5000),
        "photo.stl": b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + rng.bytes(3000),
        "notes.stl": b"Shopping list\n- filament\n- glue stick\n" * 20,
        "random.obj": rng.bytes(2000),
        "notes.obj": b"this is a text file, not a model\n",
        "random.ply": rng.bytes(2000),
        "points.ply": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
        b"property float y\nproperty float z\nend_header\n0 0 0\n",
        "random.3mf": rng.bytes(2000),
        "photo.3mf": b"\x89PNG\r\n\x1a\n" + rng.bytes(100),
        "short.stl": b"hello",
    }
    for fname, data in cases.items():
        (tmp_path / fname).write_bytes(data)
        with pytest.raises(MeshReadError) as err:
            load_mesh(tmp_path / fname)
        msg = str(err.value)
        assert msg.startswith(fname) and "\n" not in msg, msg
    with pytest.raises(MeshReadError, match="JPEG"):
        load_mesh(tmp_path / "photo.stl")
    with pytest.raises(MeshReadError, match="text file"):
        load_mesh(tmp_path / "notes.stl")
    with pytest.raises(MeshReadError, match="not a mesh"):
        load_mesh(tmp_path / "random.stl")


def test_empty_and_missing_files(tmp_path):
    for fname in ("e.stl", "e.obj", "e.ply", "e.3mf"):
        (tmp_path / fname).write_bytes(b"")
        with pytest.raises(MeshReadError, match="empty"):
            load_mesh(tmp_path / fname)
    (tmp_path / "ws.stl").write_bytes(b" \n\n ")
    with pytest.raises(MeshReadError, match="empty"):
        load_mesh(tmp_path / "ws.stl")
    with pytest.raises(MeshReadError, match="no such file"):
        load_mesh(tmp_path / "missing.stl")
    zero = tmp_path / "zero.stl"
    zero.write_bytes(b"\0" * 80 + struct.pack("<I", 0))
    with pytest.raises(MeshReadError, match="0 triangles"):
        load_mesh(zero)


def test_unsupported_extension(tmp_path):
    p = tmp_path / "part.iges"  # STEP is read (repair/io/step.py); IGES is not
    p.write_text("S      1\n")
    with pytest.raises(MeshReadError, match="unsupported"):
        load_mesh(p)
    # MeshReadError is a ValueError, as the contract says
    assert issubclass(MeshReadError, ValueError)


def test_size_and_triangle_caps(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2)  # 320 triangles
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    stl = tmp_path / "s.stl"
    write_stl(stl, v, f)
    size = stl.stat().st_size
    assert load_mesh(stl, max_bytes=size, max_triangles=320).triangles == 320
    with pytest.raises(MeshReadError, match="limit") as err:
        load_mesh(stl, max_bytes=size - 1)
    assert "\n" not in str(err.value)
    with pytest.raises(MeshReadError, match="320 triangles.*319"):
        load_mesh(stl, max_triangles=319)
    (tmp_path / "s_ascii.stl").write_bytes(ascii_stl(v, f))
    with pytest.raises(MeshReadError, match="limit"):
        load_mesh(tmp_path / "s_ascii.stl", max_triangles=100)
    obj = tmp_path / "s.obj"
    obj.write_text(trimesh.exchange.obj.export_obj(sphere))
    assert load_mesh(obj).triangles == 320
    with pytest.raises(MeshReadError, match="limit"):
        load_mesh(obj, max_triangles=100)
    ply = tmp_path / "s.ply"
    ply.write_bytes(trimesh.exchange.ply.export_ply(sphere))
    with pytest.raises(MeshReadError, match="limit"):
        load_mesh(ply, max_triangles=100)
    mf = tmp_path / "s.3mf"
    write_3mf(mf, v, f)
    assert load_mesh(mf).triangles == 320
    with pytest.raises(MeshReadError, match="limit"):
        load_mesh(mf, max_triangles=100)


# --------------------------------------------------------------------------- OBJ / PLY


def test_obj_polygons_negative_indices_and_lines(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text(
        "# a unit square as one quad, written with relative indices and v/vt/vn\n"
        "o square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\nvt 0 0\nvn 0 0 1\n"
        "f -4/1/1 -3/1/1 -2/1/1 -1/1/1\n"
        "v 0 0 5\n"
        "l 1 5\n"
        "f 1//1 2//1 \\\n 5//1\n"
    )
    m = load_mesh(p)
    assert m.source_format == "obj"
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 4], [0, 4, 4]]
    assert m.vertices[4].tolist() == [0, 0, 5]


def test_ply_ascii_and_binary(tmp_path):
    torus = trimesh.creation.torus(10, 3, major_sections=24, minor_sections=12)
    for enc in ("ascii", "binary"):
        p = tmp_path / f"t_{enc}.ply"
        p.write_bytes(trimesh.exchange.ply.export_ply(torus, encoding=enc))
        m = load_mesh(p)
        assert m.source_format == "ply"
        assert m.faces.tolist() == torus.faces.tolist()
        assert np.allclose(m.vertices, torus.vertices, atol=1e-5)
        assert check_printable(m.vertices, m.faces).ok
    bad = tmp_path / "cut.ply"
    bad.write_bytes((tmp_path / "t_binary.ply").read_bytes()[:-100])
    with pytest.raises(MeshReadError):
        load_mesh(bad)


def test_ply_polygons_are_triangulated(tmp_path):
    p = tmp_path / "q.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n4 0 1 2 3\n3 0 1 4\n"
    )
    m = load_mesh(p)
    assert m.triangles == 3
    assert {frozenset(t) for t in m.faces.tolist()} >= {frozenset((0, 1, 4))}
    # a file of quads only is triangulated too
    q = tmp_path / "quads.ply"
    q.write_text(
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n5 0 1 2 3 4\n"
    )
    assert load_mesh(q).faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4]]
    # the quad's two triangles cover its area (1 mm²)
    tri = m.vertices[m.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert area.sum() == pytest.approx(1.5)


def test_obj_comments_and_mixed_index_styles(tmp_path):
    p = tmp_path / "m.obj"
    p.write_text(
        "v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nv 0 0 1 0.5 0.5 0.5\nvt 0 0\nvn 0 0 1\n"
        "f 1/1 3/1 2/1\nf 1//1 2//1 4//1\nf 2/1/1 3/1/1 4/1/1 # comment\nf 1 4 3\n"
    )
    m = load_mesh(p)
    assert m.faces.tolist() == [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]
    assert check_printable(m.vertices, m.faces).ok


# --------------------------------------------------------------------------- fuzz finds
# Inputs the mesh fuzzer (tests/fuzz/targets_mesh.py) found that ended in an exception
# other than MeshReadError, or in a hang; each must now be a one-line refusal.

def test_fuzz_obj_one_point_polyline(tmp_path):
    # numpy's min() of the empty face list raised ValueError
    p = tmp_path / "line.obj"
    p.write_bytes(b"v 0.0 0.0 0.0\nl 1\n")
    assert_refused(p, "no faces")


def test_every_os_error_is_a_refusal(tmp_path):
    """load_mesh's only error is MeshReadError, also for paths the OS cannot stat: a
    symlink loop (ELOOP) and a name too long (ENAMETOOLONG) escaped as OSError."""
    loop = tmp_path / "loop.stl"
    loop.symlink_to(loop)
    assert_refused(loop, "loop.stl: cannot read: Too many levels of symbolic links")
    long_name = tmp_path / ("x" * 252 + ".3mf")  # one over NAME_MAX (255)
    assert_refused(long_name, "cannot read: File name too long")


def test_fuzz_obj_empty_polyline_record(tmp_path):
    # an ``l`` with no points: the segment mask was indexed at -1 of an empty array
    p = tmp_path / "empty_l.obj"
    p.write_bytes(b"v 99.0 inf 0.0\nv -64.1342544555664 -0.0 -64.1342544555664\n"
                  b"v 17.244144439697266 0.0 -inf\nv -inf 1e+300 0.0\nv -inf 16.0 1e+300\nl ")
    assert_refused(p, "no faces")
    p.write_bytes(b"v 0 0 0\nv 1 0 0\nl\t\nl 1 2\n")  # an empty record beside a real one
    assert load_mesh(p).faces.tolist() == [[0, 1, 1]]


def test_fuzz_obj_index_beyond_int64(tmp_path):
    # the float -> int64 cast overflowed (RuntimeWarning) and produced an arbitrary index
    p = tmp_path / "huge.obj"
    p.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9223372036854775807\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_refused(p, "missing vertex")
