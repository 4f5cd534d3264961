"""slice_file reads meshes through repair.io: binary and ASCII STL slice alike; junk is refused."""

from __future__ import annotations

import pytest
import trimesh

from slicer.engine import SliceError, slice_file
from slicer.profile import Profile


def test_binary_and_ascii_stl_slice_identically(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=6.0)
    binary = tmp_path / "b.stl"
    ascii_ = tmp_path / "a.stl"
    mesh.export(binary)
    ascii_.write_text(trimesh.exchange.stl.export_stl_ascii(mesh))
    profile = Profile.for_printer()
    sb = slice_file(binary, tmp_path / "b.gcode", profile)
    sa = slice_file(ascii_, tmp_path / "a.gcode", profile)
    assert sb["layers"] == sa["layers"] == 60
    assert sb["filament_mm"] == pytest.approx(sa["filament_mm"], rel=1e-3)


def test_junk_is_not_a_mesh(tmp_path):
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    with pytest.raises(SliceError, match="PNG"):
        slice_file(junk, tmp_path / "j.gcode", Profile.for_printer())
    with pytest.raises(SliceError):
        slice_file(tmp_path / "missing.stl", tmp_path / "x.gcode", Profile.for_printer())
    assert not (tmp_path / "x.gcode").exists()
    assert not (tmp_path / "j.gcode").exists()
