"""G-code into the polylines of each layer, for the layer preview.

Each line goes through :func:`printer.gcode.lex` (the one lexer). Tracked: absolute or
relative positioning (G90/G91, E included, as Marlin), extrusion (M82/M83), G92 resets and
the slicer's ``;TYPE:`` comments (PrusaSlicer, OrcaSlicer, Cura). A move that extrudes
(E grows) is drawn at its Z; travels, retractions and Z hops are not. Arcs (G2/G3) are
drawn as their chord.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable
from typing import TYPE_CHECKING

from printer.gcode import lex

if TYPE_CHECKING:
    from daemon.web.previews import Layers

MOVES = frozenset({"G0", "G1", "G2", "G3"})
Z_STEP = 1e-3  # mm: moves within this of a layer's height are on it


class _Reader:
    def __init__(self, layers: Layers) -> None:
        self.out = layers
        self.pos = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        self.relative = False
        self.relative_e = False
        self.type = 0
        self.layer_of: dict[int, int] = {}
        self.open: list[float] | None = None  # the end of the polyline being extended
        self.open_layer = -1
        self.bounds = [math.inf, math.inf, -math.inf, -math.inf]

    def comment(self, raw: str) -> None:
        name = raw.strip()[len(";TYPE:"):].strip() or "extrusion"
        types = self.out.types
        if name not in types:
            types.append(name)
        self.type = types.index(name)
        self.open = None

    def command(self, raw: str) -> None:
        line = lex(raw)
        word = line.word
        if word in MOVES:
            self.move(line)
        elif word in ("G90", "G91"):  # as Marlin: E follows, until M82/M83
            self.relative = self.relative_e = word == "G91"
        elif word == "M82":
            self.relative_e = False
        elif word == "M83":
            self.relative_e = True
        elif word == "G92":
            for axis in "XYZE":
                value = line.value(axis)
                if value is not None:
                    self.pos[axis] = value

    def move(self, line) -> None:
        old = dict(self.pos)
        for axis in "XYZ":
            value = line.value(axis)
            if value is not None:
                self.pos[axis] = old[axis] + value if self.relative else value
        e = line.value("E")
        extruded = 0.0
        if e is not None:
            extruded = e if self.relative_e else e - old["E"]
            self.pos["E"] = old["E"] + e if self.relative_e else e
        moved = (self.pos["X"], self.pos["Y"]) != (old["X"], old["Y"])
        if extruded <= 0 or not moved:
            self.open = None
            return
        self.draw(old["X"], old["Y"])

    def draw(self, x0: float, y0: float) -> None:
        x, y, z = self.pos["X"], self.pos["Y"], self.pos["Z"]
        key = round(z / Z_STEP)
        index = self.layer_of.get(key)
        if index is None:
            index = self.layer_of[key] = len(self.out.z)
            self.out.z.append(z)
            self.out.paths.append([])
            self.open = None
        if self.open is None or self.open[-2:] != [x0, y0] or self.open_layer != index:
            pts = array("f", (x0, y0))
            self.out.paths[index].append((self.type, pts))
            self.open, self.open_layer = [x0, y0], index
        self.out.paths[index][-1][1].extend((x, y))
        self.open = [x, y]
        b = self.bounds
        b[0], b[1] = min(b[0], x0, x), min(b[1], y0, y)
        b[2], b[3] = max(b[2], x0, x), max(b[3], y0, y)


def read_layers(lines: Iterable[str]) -> Layers:
    """The layers of the G-code ``lines``, sorted by height."""
    from daemon.web.previews import Layers

    reader = _Reader(Layers())
    for raw in lines:
        head = raw.lstrip()[:1]
        if head in ("G", "g", "M", "m", "N"):
            reader.command(raw)
        elif head == ";" and raw.lstrip().startswith(";TYPE:"):
            reader.comment(raw)
    out = reader.out
    order = sorted(range(len(out.z)), key=out.z.__getitem__)
    out.z = [out.z[i] for i in order]
    out.paths = [out.paths[i] for i in order]
    if math.isfinite(reader.bounds[0]):
        out.bounds = reader.bounds
    return out
