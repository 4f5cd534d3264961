"""PNG thumbnails of the model for the printer's screen, in PrusaSlicer's G-code blocks.

The mesh (as it will be printed) is drawn with Pillow's ImageDraw, headless and with no
GPU: the triangles are turned to a fixed isometric view, back faces dropped, the rest
Lambert-shaded and sorted far to near (numpy), then filled in that order (painter's
algorithm). The picture is drawn at a few times its size and scaled down with Lanczos
filtering for smooth edges, then encoded as PNG. Meshes with more triangles than the picture
could show (``MAX_TRIANGLES``, or a few per drawn pixel) are first simplified by vertex
clustering on a grid finer than the picture's pixels, so a 200k-triangle model costs about as
much as a small one. Pillow, not matplotlib: importing matplotlib's figure machinery took
longer (~0.6 s of CPU) than slicing a small model.

Block format (what Prusa firmware, OctoPrint and the Klipper UIs read)::

    ; thumbnail begin 220x124 5284
    ; iVBORw0KGgo... (base64, 78 characters a line)
    ; thumbnail end
"""

from __future__ import annotations

import base64
import io
import math

import numpy as np

MAX_TRIANGLES = 20_000
LINE = 78
COLOUR = np.array([0.93, 0.47, 0.13])  # filament orange
LIGHT = np.array([-0.4, -0.6, 0.7])


def _cluster(v: np.ndarray, f: np.ndarray, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertex-clustering simplification: vertices in one grid cell (``cells`` along the
    longest side) merge at their mean; collapsed and repeated triangles are dropped."""
    lo = v.min(axis=0)
    step = max(float(np.ptp(v, axis=0).max()), 1e-9) / cells
    ijk = np.minimum(np.floor((v - lo) / step).astype(np.int64), cells)
    key = (ijk[:, 0] * (cells + 1) + ijk[:, 1]) * (cells + 1) + ijk[:, 2]
    _, cell, counts = np.unique(key, return_inverse=True, return_counts=True)
    centre = np.zeros((len(counts), 3))
    np.add.at(centre, cell, v)
    centre /= counts[:, None]
    g = cell[f]
    ok = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
    g = g[ok]
    srt = np.sort(g, axis=1)
    n = len(counts)
    _, first = np.unique((srt[:, 0] * n + srt[:, 1]) * n + srt[:, 2], return_index=True)
    return centre, g[np.sort(first)]


def _view(v: np.ndarray) -> np.ndarray:
    """Rotate into screen axes: x right, y up, z towards the viewer (front-right, 35° up)."""
    az, el = math.radians(-35.0), math.radians(35.0)
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0],
                   [0, 0, 1]])
    # looking along +y after rz; tilt so the camera sits above: screen y = z·cos + y·sin
    tilt = np.array([[1, 0, 0], [0, math.sin(el), math.cos(el)],
                     [0, -math.cos(el), math.sin(el)]])
    return (v - v.mean(axis=0)) @ (tilt @ rz).T


def render_png(vertices: np.ndarray, faces: np.ndarray, width: int, height: int) -> bytes:
    """A ``width`` × ``height`` PNG (RGBA, transparent background) of the mesh."""
    from PIL import Image, ImageDraw

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    scale = max(2, math.ceil(128 / min(width, height)))
    if len(f) > MAX_TRIANGLES:
        v, f = _cluster(v, f, max(48, int(0.4 * max(width, height))))
    s = _view(v)
    tri = s[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    front = normal[:, 2] > 1e-12 * np.maximum(length, 1e-300)
    tri, normal, length = tri[front], normal[front], length[front]
    unit = normal / np.maximum(length, 1e-300)[:, None]
    light = LIGHT / np.linalg.norm(LIGHT)
    shade = 0.35 + 0.65 * np.clip(unit @ light, 0.0, 1.0) * 0.8 + 0.2 * unit[:, 2]
    order = np.argsort(tri[:, :, 2].mean(axis=1))  # far first
    colours = np.clip(COLOUR[None] * np.clip(shade, 0, 1.1)[order, None], 0, 1)
    rgba = np.concatenate([colours, np.ones((len(colours), 1))], axis=1)

    px_w, px_h = width * scale, height * scale
    lo = s[:, :2].min(axis=0)
    hi = s[:, :2].max(axis=0)
    centre = (lo + hi) / 2
    half = max((hi[0] - lo[0]) / px_w, (hi[1] - lo[1]) / px_h) * 0.55 or 1.0
    # screen (x right, y up) to pixels (y down), the model's box centred, 10 % margin
    xy = (tri[order][:, :, :2] - centre) / half
    xy[:, :, 0] += px_w
    xy[:, :, 1] = px_h - xy[:, :, 1]
    xy /= 2
    fills = [tuple(c) for c in np.round(rgba * 255).astype(np.uint8).tolist()]
    img = Image.new("RGBA", (px_w, px_h), (0, 0, 0, 0))
    draw = ImageDraw.Draw(img)
    for corners, colour in zip(xy.reshape(-1, 6).tolist(), fills, strict=True):
        draw.polygon(corners, fill=colour, outline=colour)  # Pillow fills one at a time
    img = img.resize((width, height), Image.Resampling.LANCZOS)
    out = io.BytesIO()
    out.name = "thumbnail.png"  # the format from the name: Pillow loads its PNG plugin only
    img.save(out, optimize=True)
    return out.getvalue()


def thumbnail_blocks(vertices: np.ndarray, faces: np.ndarray,
                     sizes: list[tuple[int, int]]) -> str:
    """G-code comment blocks with one PNG thumbnail per (width, height), smallest first."""
    parts: list[str] = []
    for w, h in sorted(sizes):
        data = base64.b64encode(render_png(vertices, faces, w, h)).decode("ascii")
        lines = "".join(f"; {data[i:i + LINE]}\n" for i in range(0, len(data), LINE))
        parts.append(f";\n; thumbnail begin {w}x{h} {len(data)}\n{lines}; thumbnail end\n;\n")
    return "".join(parts)
