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


def _alpha(vertices, faces, width=220, height=124) -> np.ndarray:
    from slicer.thumbnail import render_png

    img = Image.open(io.BytesIO(render_png(vertices, faces, width, height)))
    assert img.size == (width, height)
    return np.asarray(img.convert("RGBA"))[:, :, 3] > 127


def _mesh(solid) -> tuple[np.ndarray, np.ndarray]:
    m = solid.to_mesh()
    return np.asarray(m.vert_properties[:, :3], dtype=np.float64), np.asarray(m.tri_verts)


def test_the_silhouette_follows_the_model_not_its_hull():
    """A mushroom and its convex hull have the same box, so they are drawn at the same
    scale and place: the mushroom's picture lies inside the hull's and misses the space
    under its cap; a cube's picture is its hull's, and differs clearly from the mushroom's."""
    from manifold3d import Manifold

    mushroom = Manifold.cylinder(30, 8, 8, 64) + Manifold.cylinder(8, 25, 25, 192).translate(
        [0, 0, 30])
    cube = Manifold.cube([50, 50, 38])
    shapes = {name: (_alpha(*_mesh(s)), _alpha(*_mesh(s.hull())))
              for name, s in {"mushroom": mushroom, "cube": cube}.items()}
    mush, mush_hull = shapes["mushroom"]
    box, box_hull = shapes["cube"]
    assert (mush & ~mush_hull).sum() <= 0.01 * mush.sum()
    assert 0.5 < mush.sum() / mush_hull.sum() < 0.95  # the cap hides most of the stem
    assert (box == box_hull).mean() > 0.99
    iou = (mush & box).sum() / (mush | box).sum()
    assert iou < 0.8, "a mushroom does not look like a box"


def test_a_box_covers_the_share_of_its_picture_its_projected_corners_enclose():
    from manifold3d import CrossSection, Manifold

    from slicer.thumbnail import AZIMUTH, ELEVATION

    alpha = _alpha(*_mesh(Manifold.cube([30, 20, 10])))
    corners = np.array([[x, y, z] for x in (0, 30) for y in (0, 20) for z in (0, 10)], float)
    c, s = np.cos(AZIMUTH), np.sin(AZIMUTH)
    x = c * corners[:, 0] - s * corners[:, 1]
    y = (s * corners[:, 0] + c * corners[:, 1]) * np.sin(ELEVATION) + corners[:, 2] * np.cos(
        ELEVATION)
    expected = CrossSection.hull_points(np.c_[x, y]).area() / (np.ptp(x) * np.ptp(y))
    rows, cols = np.flatnonzero(alpha.any(axis=1)), np.flatnonzero(alpha.any(axis=0))
    drawn = alpha.sum() / ((rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1))
    assert drawn == pytest.approx(expected, abs=0.05)


def test_a_hole_shows_what_is_behind_it_and_an_open_mesh_still_gets_a_picture():
    from manifold3d import Manifold

    washer = Manifold.cylinder(4, 15, 15, 96) - Manifold.cylinder(10, 10, 10, 96).translate(
        [0, 0, -3])
    alpha = _alpha(*_mesh(washer), 64, 64)
    assert alpha.mean() > 0.2
    assert not alpha[28:36, 28:36].any(), "the background shows through the washer's hole"
    v, f = _mesh(Manifold.cube([20, 20, 20]))
    keep = ~np.all(v[f][:, :, 2] > 19.999, axis=1)  # the lid removed: not a closed solid
    open_box = _alpha(v, f[keep], 64, 64)
    assert (open_box == _alpha(v, f, 64, 64)).mean() > 0.98


def test_the_png_writer_round_trips_through_pillow_pixel_for_pixel():
    """Thumbnails are encoded by slicer.thumbnail.png_rgba (not Pillow's PNG plugin): any
    RGBA picture, odd sizes included, decodes to exactly its pixels; a wrong size is refused."""
    from slicer.thumbnail import png_rgba

    rng = np.random.default_rng(7)
    for width, height in [(1, 1), (16, 16), (37, 5), (220, 124)]:
        pixels = rng.integers(0, 256, (height, width, 4), dtype=np.uint8)
        pixels[: height // 2, :, 3] = 0  # transparent rows, as around a model
        img = Image.open(io.BytesIO(png_rgba(pixels.tobytes(), width, height)))
        assert img.format == "PNG" and img.mode == "RGBA" and img.size == (width, height)
        assert np.array_equal(np.asarray(img), pixels)
    with pytest.raises(ValueError, match="RGBA"):
        png_rgba(b"\0" * 10, 2, 2)


def test_thumbnails_drawn_in_a_child_are_those_drawn_here_and_its_failure_is_one_line():
    """With workers other than 1, slice_mesh has the thumbnails drawn in a forked child
    beside its planning: the same text as drawn in this process; a child that fails gives a
    SliceError naming it, and stop() leaves no child behind."""
    from slicer.errors import SliceError
    from slicer.parallel import available_cpus
    from slicer.thumbnail import ThumbnailJob, thumbnail_blocks

    v, f = sphere(radius=8.0, subdivisions=3)
    sizes = [(16, 16), (220, 124)]
    here = ThumbnailJob(v, f, sizes, None, "1")
    assert here.result() == thumbnail_blocks(v, f, sizes) and here.cpu_seconds == 0.0
    child = ThumbnailJob(v, f, sizes, None, "auto")
    assert child.result() == here.result()
    if available_cpus() == 1:
        return  # nowhere to fork to: drawn here, as above
    assert child.cpu_seconds > 0, "drawn in a child, whose CPU time is counted"
    broken = ThumbnailJob(v, f, sizes, "not a solid", "2")
    try:
        with pytest.raises(SliceError, match="thumbnails failed: AttributeError"):
            broken.result()
    finally:
        broken.stop()
