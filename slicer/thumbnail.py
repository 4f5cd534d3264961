"""PNG thumbnails of the model for the printer's screen, in PrusaSlicer's G-code blocks.

The model is drawn the way it will be printed, as a stack of layers: manifold3d slices the
solid at up to ``MAX_LAYERS`` heights (each section simplified within a quarter pixel), and
Pillow's ImageDraw fills each layer's section, seen from the front right and 35° above,
bottom layer first, each a shade lighter than the one below and outlined darker. Seen from
above, whatever hides a point of a layer lies higher up, so drawing bottom to top is a
correct painter's order; the layers are drawn under a pixel of the picture apart, so the
stacked outlines show the walls and the last layer drawn over a pixel shows the top faces.
The Python loop is over layers (a few hundred at most), never over triangles: the slicing is
manifold3d's, the filling Pillow's. A layer with holes (a cup's rim, a ring) is filled
through a mask, so what is below shows through its holes. The picture is drawn at a few
times its size and scaled down by block averaging for smooth edges, then encoded as PNG.

The slicer passes the solid it has built; given only a mesh, the solid is built here (about
a microsecond a triangle): over ``MAX_TRIANGLES``, from a copy simplified by vertex
clustering on a grid finer than the picture's pixels when that copy is still a closed solid;
a mesh that is not a closed solid is drawn as its convex hull. Pillow, not matplotlib:
importing matplotlib's figure machinery took longer (~0.6 s of CPU) than slicing a small
model.

Block format (what Prusa firmware, OctoPrint and the Klipper UIs read)::

    ; thumbnail begin 220x124 5284
    ; iVBORw0KGgo... (base64, 78 characters a line)
    ; thumbnail end
"""

from __future__ import annotations

import functools
import math
import struct
from dataclasses import dataclass

import numpy as np

MAX_TRIANGLES = 20_000
MAX_LAYERS = 400
LINE = 78
COLOUR = np.array([0.93, 0.47, 0.13])  # filament orange
AZIMUTH, ELEVATION = math.radians(-35.0), math.radians(35.0)  # front-right, 35° up
LAYER_PX = 1.6  # drawn layers at most this many pixels apart in the (2x or more) oversized picture


@dataclass(frozen=True)
class _Stack:
    """The model's layers, bottom first, projected to the screen (mm, x right, y up): all
    rings' points in one array, ring ``i`` being ``points[starts[i]:starts[i + 1]]`` of
    layer ``layer[i]``, with its signed area in the section's plane (outer rings positive,
    holes negative); each layer's shade (0 bottom .. 1 top) and whether it has holes; and the
    screen box of the whole model (x0, y0, x1, y1)."""

    points: np.ndarray
    starts: np.ndarray
    layer: np.ndarray
    area: np.ndarray
    shade: np.ndarray
    holed: np.ndarray
    box: tuple[float, float, float, float]
    step: float  # screen distance (mm) from one layer to the next

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


def _closed_solid(v: np.ndarray, f: np.ndarray):
    """The manifold3d solid of the mesh, turned right way out; None if it is not one."""
    from manifold3d import Manifold, Mesh

    if len(f) == 0:
        return None
    man = Manifold(Mesh(vert_properties=np.ascontiguousarray(v, dtype=np.float32),
                        tri_verts=np.ascontiguousarray(f, dtype=np.uint32)))
    if str(man.status()) != "Error.NoError" or man.is_empty():
        return None
    if man.volume() < 0:  # inside out: the same solid, its triangles turned
        return _closed_solid(v, f[:, ::-1])
    return man if man.volume() > 0 else None


def _solid(v: np.ndarray, f: np.ndarray, cells: int):
    """What to draw: the (simplified, when large and still closed) solid, else its hull."""
    from manifold3d import Manifold

    man = None
    if len(f) > MAX_TRIANGLES:
        man = _closed_solid(*_cluster(v, f, cells))
    if man is None:
        man = _closed_solid(v, f)
    return man if man is not None else Manifold.hull_points(np.ascontiguousarray(v))


def _screen(xy: np.ndarray, z: np.ndarray | float) -> np.ndarray:
    """Model axes to screen (x right, y up): turned by AZIMUTH about the vertical, seen
    from ELEVATION above the horizon."""
    c, s = math.cos(AZIMUTH), math.sin(AZIMUTH)
    depth = s * xy[:, 0] + c * xy[:, 1]  # away from the viewer
    return np.stack([c * xy[:, 0] - s * xy[:, 1],
                     depth * math.sin(ELEVATION) + z * math.cos(ELEVATION)], axis=1)


def _screen_box(vertices: np.ndarray) -> tuple[float, float, float, float]:
    scr = _screen(vertices[:, :2], vertices[:, 2])
    return (*scr.min(axis=0).tolist(), *scr.max(axis=0).tolist())  # type: ignore[return-value]


def _stack(vertices: np.ndarray, man, layers: int, tolerance: float) -> _Stack:
    """Slice the solid ``man`` at ``layers`` (at most MAX_LAYERS) heights; the sections
    simplified within ``tolerance`` (mm; a fraction of a pixel: fewer points to draw)."""
    v = np.asarray(vertices, dtype=np.float64)
    box = _screen_box(v)
    lo, hi = float(v[:, 2].min()), float(v[:, 2].max())
    n = int(min(max(layers, 1), MAX_LAYERS))
    dz = (hi - lo) / n
    tops = lo + dz * np.arange(1, n + 1)
    rings, layer = [], []
    for i, top in enumerate(tops):
        polys = man.slice(float(top - dz / 2)).simplify(tolerance).to_polygons()
        rings.extend(polys)
        layer.extend([i] * len(polys))
    if not rings:
        rings, layer = [np.zeros((0, 2))], [0]
    sizes = np.array([len(r) for r in rings])
    starts = np.concatenate([[0], np.cumsum(sizes)])
    flat = np.concatenate(rings).astype(np.float64)
    layer_of = np.asarray(layer)
    # shoelace area of every ring at once: the cross product of each point with the next
    nxt = np.arange(len(flat)) + 1
    nxt[starts[1:] - 1] = starts[:-1]
    cross = flat[:, 0] * flat[nxt, 1] - flat[nxt, 0] * flat[:, 1]
    area = np.add.reduceat(cross, starts[:-1]) / 2 if len(flat) else np.zeros(len(sizes))
    holed = np.zeros(n, dtype=bool)
    holed[layer_of[area < 0]] = True
    return _Stack(_screen(flat, np.repeat(tops[layer_of], sizes)), starts, layer_of, area,
                  np.linspace(0.0, 1.0, n) if n > 1 else np.ones(1), holed, box,
                  dz * math.cos(ELEVATION))


def _scale(width: int, height: int) -> int:
    return max(2, math.ceil(128 / min(width, height)))


def _pixels_per_mm(box: tuple[float, float, float, float], px_w: int, px_h: int) -> float:
    """The model's screen box fills the picture but for a 10 % margin."""
    span_x, span_y = box[2] - box[0], box[3] - box[1]
    half = max(span_x / px_w, span_y / px_h) * 0.55 or 1.0
    return 1.0 / (2.0 * half)


def _finest(vertices: np.ndarray, sizes: list[tuple[int, int]]) -> tuple[int, float]:
    """Layers so that, in the largest picture, drawn layers are LAYER_PX apart at most; and
    the length (mm) of a quarter of that picture's pixels."""
    v = np.asarray(vertices, dtype=np.float64)
    box = _screen_box(v)
    ppm = max(_pixels_per_mm(box, w * _scale(w, h), h * _scale(w, h)) for w, h in sizes)
    height = float(np.ptp(v[:, 2]))
    return max(1, math.ceil(height * math.cos(ELEVATION) * ppm / LAYER_PX)), 0.25 / ppm


def _fill_with_holes(img, rings: list[np.ndarray], area: np.ndarray, fill: tuple) -> None:
    """Fill a layer whose rings include holes: the rings, largest first, paint a mask
    (outer rings on, holes off) over the layer's box; the colour goes through the mask."""
    from PIL import Image, ImageDraw

    pts = np.concatenate(rings)
    x0, y0 = (np.floor(pts.min(axis=0)) - 1).astype(int).tolist()
    x1, y1 = (np.ceil(pts.max(axis=0)) + 2).astype(int).tolist()
    mask = Image.new("L", (x1 - x0, y1 - y0), 0)
    pen = ImageDraw.Draw(mask)
    for i in np.argsort(np.abs(area))[::-1]:
        pen.polygon((rings[i] - [x0, y0]).ravel().tolist(), fill=255 if area[i] > 0 else 0)
    img.paste(fill, (x0, y0, x1, y1), mask)


def _draw(stack: _Stack, width: int, height: int) -> bytes:
    """A ``width`` × ``height`` PNG (RGBA, transparent background) of the layer stack."""
    from PIL import Image, ImageDraw

    k = _scale(width, height)
    px_w, px_h = width * k, height * k
    ppm = _pixels_per_mm(stack.box, px_w, px_h)
    centre = np.array([(stack.box[0] + stack.box[2]) / 2, (stack.box[1] + stack.box[3]) / 2])
    n = len(stack.shade)
    # screen (x right, y up) to pixels (y down), the model's box centred
    px = (stack.points - centre) * [ppm, -ppm] + [px_w / 2, px_h / 2]
    flat = px.ravel().tolist()
    step_px = stack.step * ppm
    drawn = np.zeros(n, dtype=bool)
    drawn[range(n - 1, -1, -max(1, int(LAYER_PX / max(step_px, 1e-12))))] = True  # top kept
    shade = COLOUR[None] * (0.5 + 0.5 * stack.shade[:, None]) * 255
    fills = [(*c, 255) for c in np.round(shade).astype(int).tolist()]
    edges = [(*c, 255) for c in np.round(shade * 0.6).astype(int).tolist()]
    img = Image.new("RGBA", (px_w, px_h), (0, 0, 0, 0))
    draw = ImageDraw.Draw(img)
    starts = (2 * stack.starts).tolist()
    layer = stack.layer.tolist()
    i, count = 0, len(layer)
    while i < count:  # one layer's rings at a time
        j = i + 1
        while j < count and layer[j] == layer[i]:
            j += 1
        lay = layer[i]
        if drawn[lay]:
            rings = [flat[starts[r]:starts[r + 1]] for r in range(i, j)]
            if stack.holed[lay]:
                _fill_with_holes(img, [px[stack.starts[r]:stack.starts[r + 1]]
                                       for r in range(i, j)], stack.area[i:j], fills[lay])
            for ring in rings:
                if len(ring) >= 6:
                    draw.polygon(ring, fill=None if stack.holed[lay] else fills[lay],
                                 outline=edges[lay])
        i = j
    img = img.reduce(k)  # each pixel the mean of its k × k block: the supersampling's filter
    return png_rgba(img.tobytes(), width, height)


def _chunk(kind: bytes, data: bytes) -> bytes:
    import zlib  # here, like base64 below: the drawing is mostly done in a forked child

    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data)))


def png_rgba(pixels: bytes, width: int, height: int) -> bytes:
    """A PNG file of ``width`` × ``height`` 8-bit RGBA ``pixels`` (rows top first). Written
    here rather than by Pillow's PNG plugin, whose import alone cost ~15 ms of CPU per slice;
    every row unfiltered (filter 0), which on these flat-shaded pictures deflates smaller
    than Pillow's own choice."""
    stride = 4 * width
    if len(pixels) != stride * height:
        raise ValueError(f"{len(pixels)} bytes are not {width}x{height} RGBA pixels")
    rows = np.zeros((height, stride + 1), dtype=np.uint8)  # each row: filter byte 0, pixels
    rows[:, 1:] = np.frombuffer(pixels, dtype=np.uint8).reshape(height, stride)
    import zlib

    header = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)  # 8 bits, RGBA
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 9)) + _chunk(b"IEND", b""))


def render_png(vertices: np.ndarray, faces: np.ndarray, width: int, height: int) -> bytes:
    """A ``width`` × ``height`` PNG (RGBA, transparent background) of the mesh."""
    return _pngs(vertices, faces, [(width, height)], None)[0]


def _pngs(vertices: np.ndarray, faces: np.ndarray, sizes: list[tuple[int, int]],
          solid) -> list[bytes]:
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if solid is None:
        cells = max(48, int(0.4 * max(max(w, h) for w, h in sizes)))
        solid = _solid(v, np.asarray(faces, dtype=np.int64).reshape(-1, 3), cells)
    stack = _stack(v, solid, *_finest(v, sizes))
    return [_draw(stack, w, h) for w, h in sizes]


def thumbnail_blocks(vertices: np.ndarray, faces: np.ndarray, sizes: list[tuple[int, int]],
                     solid=None) -> str:
    """G-code comment blocks with one PNG thumbnail per (width, height), smallest first.
    ``solid``: the mesh's manifold3d Manifold when the caller has it (the slicer does),
    which saves building it again (about a microsecond a triangle)."""
    import base64

    if not sizes:
        return ""
    sizes = sorted(sizes)
    parts: list[str] = []
    for (w, h), png in zip(sizes, _pngs(vertices, faces, sizes, solid), strict=True):
        data = base64.b64encode(png).decode("ascii")
        lines = "".join(f"; {data[i:i + LINE]}\n" for i in range(0, len(data), LINE))
        parts.append(f";\n; thumbnail begin {w}x{h} {len(data)}\n{lines}; thumbnail end\n;\n")
    return "".join(parts)


class ThumbnailJob:
    """The thumbnail blocks being drawn. Where the slice may use more than one process
    (``workers`` not "1") and this one may run on more than one CPU, they are drawn in a
    forked child (the solid inherited, nothing pickled on the way in) beside the slicer's
    planning, which otherwise leaves the second core idle: Pillow's import and the drawing
    were ~35 ms of a small model's serial time. Else, or where no child can be forked, they
    are drawn here and now. :meth:`result` gives the text (SliceError if the child failed);
    :meth:`stop` ends and reaps a child still running (call it on every way out)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, sizes: list[tuple[int, int]],
                 solid=None, workers: str = "1") -> None:
        self.cpu_seconds = 0.0  #: the child's, once reaped (not in the slice's summary)
        self._worker = None
        self._text = ""
        if not sizes:
            return
        draw = functools.partial(thumbnail_blocks, vertices, faces, sizes, solid)
        if _may_fork(workers):
            from slicer.parallel import Worker

            try:
                self._worker = Worker(draw, "thumbnails")
                return
            except OSError:  # no memory or process left for a child: draw them here
                pass
        self._text = draw()

    def result(self) -> str:
        if self._worker is not None:
            from slicer.errors import SliceError
            from slicer.parallel import WorkerError

            worker, self._worker = self._worker, None
            try:
                self._text = worker.result()
            except WorkerError as exc:
                raise SliceError(str(exc)) from None
            finally:
                self.cpu_seconds = worker.cpu_seconds
        return self._text

    def stop(self) -> None:
        if self._worker is not None:
            self._worker.stop()
            self.cpu_seconds = self._worker.cpu_seconds
            self._worker = None


def _may_fork(workers: str) -> bool:
    from slicer.parallel import available_cpus, parse_workers

    try:
        return parse_workers(workers) != 1 and available_cpus() > 1
    except ValueError:  # refused with its own message when the layers' workers are chosen
        return False
