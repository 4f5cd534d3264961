"""Thumbnails: PrusaSlicer-style `; thumbnail begin WxH LEN` blocks that decode as PNGs of the
stated sizes, with the model drawn in view (not blank, clear of the edges)."""

from __future__ import annotations

import base64
import io
import re

import numpy as np
import pytest
from PIL import Image
from slice_checks import cup, sphere

from slicer.engine import slice_mesh
from slicer.profile import Profile, ProfileError

BASE = Profile.for_printer(nozzle_diameter=0.4, build_volume=(200, 200, 180))
BLOCK = re.compile(r"^; thumbnail begin (\d+)x(\d+) (\d+)\n((?:; [A-Za-z0-9+/=]+\n)+)"
                   r"; thumbnail end$", re.MULTILINE)


def _thumbnails(gcode: str) -> list[tuple[int, int, Image.Image, list[str]]]:
    out = []
    for m in BLOCK.finditer(gcode):
        w, h, length = (int(g) for g in m.groups()[:3])
        lines = [ln[2:] for ln in m.group(4).splitlines()]
        data = "".join(lines)
        assert len(data) == length
        img = Image.open(io.BytesIO(base64.b64decode(data, validate=True)))
        assert img.format == "PNG"
        out.append((w, h, img, lines))
    return out


@pytest.mark.parametrize("model", [sphere, lambda: cup(flipped=False)], ids=["sphere", "cup"])
def test_thumbnails_decode_at_their_sizes_and_show_the_model(model):
    v, f = model()
    result = slice_mesh(v, f, BASE.with_overrides({"thumbnails": "16x16,220x124"}))
    gcode = result.gcode
    thumbs = _thumbnails(gcode)
    assert [(w, h) for w, h, _, _ in thumbs] == [(16, 16), (220, 124)]
    assert result.summary["thumbnails"] == ["16x16", "220x124"]
    # before any command: printers read them from the head of the file
    assert gcode.index("; thumbnail end") < gcode.index("\nG28")
    for w, h, img, lines in thumbs:
        assert img.size == (w, h)
        assert all(len(ln) <= 78 for ln in lines) and all(len(ln) == 78 for ln in lines[:-1])
        px = np.asarray(img.convert("RGBA"), dtype=float)
        alpha = px[:, :, 3] > 0
        assert 0.1 < alpha.mean() < 0.95, "the model fills part of the picture"
        assert px[alpha, :3].std(axis=0).max() > 5, "shaded, not one flat colour"
        if w >= 64:  # in view: the drawing keeps clear of the picture's edges
            edge = np.concatenate([alpha[0], alpha[-1], alpha[:, 0], alpha[:, -1]])
            assert not edge.any()


def test_thumbnails_can_be_turned_off_and_bad_sizes_are_refused():
    v, f = sphere(radius=5.0, subdivisions=2)
    result = slice_mesh(v, f, BASE.with_overrides({"thumbnails": ""}))
    assert "thumbnail begin" not in result.gcode and "thumbnails" not in result.summary
    with pytest.raises(ProfileError, match="thumbnails"):
        BASE.with_overrides({"thumbnails": "220by124"})


def test_a_200k_triangle_mesh_is_drawn_from_a_simplified_copy():
    import trimesh

    from slicer.thumbnail import MAX_TRIANGLES, render_png

    s = trimesh.creation.icosphere(subdivisions=7, radius=20.0)
    assert len(s.faces) > 200_000 > MAX_TRIANGLES
    img = Image.open(io.BytesIO(render_png(s.vertices, s.faces, 220, 124)))
    alpha = np.asarray(img.convert("RGBA"))[:, :, 3] > 0
    # a sphere seen from anywhere is a disc: about π/4 of its bounding square
    rows, cols = np.flatnonzero(alpha.any(axis=1)), np.flatnonzero(alpha.any(axis=0))
    box = (rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1)
    assert alpha.sum() / box == pytest.approx(np.pi / 4, abs=0.05)
