"""Measure printed holes and bosses in G-code, as a machinist's gauges would.

The G-code is replayed by the tests' own interpreter (tests/slicer/gcode_replay.py, which
knows nothing of the slicer). At the layer nearest ``z``, the external-perimeter moves are
chained into loops; the loop around a requested centre is the hole's (or boss's) outermost
bead, the one that forms the printed surface.

Definitions (units mm, coordinates as in the G-code, i.e. after the slicer placed the part;
``bed_xy`` maps design coordinates there):

- the loop's centre is the least-squares circle fitted to its centreline, resampled evenly
  along its length so long and short moves weigh by their length;
- a hole's effective diameter is that of the largest pin that passes through it: twice the
  smallest distance from the centre to the bead's centreline, minus one bead width (the bead
  reaches half a width towards the hole);
- a boss's effective diameter is that of the smallest ring that slides over it: twice the
  largest distance from the centre to the centreline, plus one bead width;
- the bead width is the width of the rectangle of the bead's cross-section area
  (``bead_width``): a rounded-rectangle bead of line width w and height h has area
  h·(w − h·(1 − π/4)), and a slicer (ours, PrusaSlicer) spaces the external perimeter from
  the surface by half that width, so the surface it prints is where this width puts it.

A coarsely faceted hole is undersized by these definitions (its flats lie inside the design
circle), and so it should be: a pin of the design diameter would not pass.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent / "slicer"))

from gcode_replay import Replay, replay  # noqa: E402

EXTERNAL = "External perimeter"
BEAD_SHAPE = 1.0 - np.pi / 4.0
#: resampling step along a loop's centreline
STEP = 0.005
#: a loop's fitted centre must lie this close to the requested centre
CENTRE_SLACK = 0.5


def bed_xy(points_xy: Sequence[Sequence[float]], vertices: np.ndarray,
           build_volume: Sequence[float]) -> np.ndarray:
    """Design XY points mapped where the slicer prints them: the model's bounding box centred
    on the bed (the placement ``slicer.geometry.place_on_bed`` promises, orient="keep")."""
    v = np.asarray(vertices, dtype=float)
    middle = (v[:, :2].min(0) + v[:, :2].max(0)) / 2
    return np.asarray(points_xy, dtype=float) + np.asarray(build_volume[:2], float) / 2 - middle


def bead_width(line_width: float, layer_height: float) -> float:
    """Width of the rectangle with the cross-section area of a rounded-rectangle bead."""
    return line_width - layer_height * BEAD_SHAPE


def loops_at(gcode: str | Replay, z: float) -> tuple[float, list[np.ndarray]]:
    """(layer z, closed external-perimeter loops as (n, 2) XY polylines) of the layer nearest
    ``z``."""
    rp = replay(gcode) if isinstance(gcode, str) else gcode
    layers = rp.layers(rp.part & rp.labelled(EXTERNAL))
    if not layers:
        raise ValueError("the G-code has no external perimeters")
    zs = np.array(sorted(layers))
    layer_z = float(zs[np.argmin(np.abs(zs - z))])
    idx = layers[layer_z]
    loops: list[np.ndarray] = []
    breaks = np.flatnonzero(np.diff(idx) != 1) + 1
    for run in np.split(idx, breaks):
        pts = np.vstack([rp.start[run[0], :2], rp.end[run, :2]])
        # consecutive moves without a travel between them, but a jump means a new chain
        gaps = np.flatnonzero(np.hypot(*(rp.start[run[1:], :2] - rp.end[run[:-1], :2]).T) > 1e-6)
        for piece in np.split(pts, gaps + 1):
            if len(piece) > 3 and np.hypot(*(piece[0] - piece[-1])) < 0.5:
                loops.append(piece)
    return layer_z, loops


def _resampled(loop: np.ndarray) -> np.ndarray:
    closed = np.vstack([loop, loop[:1]])
    seg = np.diff(closed, axis=0)
    length = np.hypot(*seg.T)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = np.arange(0.0, cum[-1], STEP)
    return np.column_stack([np.interp(s, cum, closed[:, k]) for k in range(2)])


def fit_circle(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre, radius) of the algebraic least-squares circle through ``points`` (n, 2)."""
    a = np.column_stack([2 * points, np.ones(len(points))])
    b = (points**2).sum(1)
    (cx, cy, c), *_ = np.linalg.lstsq(a, b, rcond=None)
    return np.array([cx, cy]), float(np.sqrt(c + cx * cx + cy * cy))


def _loop_around(loops: list[np.ndarray], centre: np.ndarray) -> np.ndarray:
    best, best_r = None, np.inf
    for loop in loops:
        pts = _resampled(loop)
        c, r = fit_circle(pts)
        if np.hypot(*(c - centre)) < CENTRE_SLACK and r < best_r:
            best, best_r = pts, r
    if best is None:
        raise ValueError(f"no external-perimeter loop around ({centre[0]:.2f}, {centre[1]:.2f})")
    return best


def _distances(gcode: str | Replay, centres_xy, z: float) -> list[np.ndarray]:
    _, loops = loops_at(gcode, z)
    out = []
    for centre in np.asarray(centres_xy, dtype=float).reshape(-1, 2):
        pts = _loop_around(loops, centre)
        c, _ = fit_circle(pts)
        out.append(np.hypot(*(pts - c).T))
    return out


def hole_diameters(gcode: str | Replay, centres_xy, z: float, bead_width: float) -> list[float]:
    """Effective (pin-gauge) diameter of the hole around each G-code XY centre at layer ``z``."""
    return [float(2 * d.min() - bead_width) for d in _distances(gcode, centres_xy, z)]


def boss_diameters(gcode: str | Replay, centres_xy, z: float, bead_width: float) -> list[float]:
    """Effective (ring-gauge) diameter of the boss around each G-code XY centre at ``z``."""
    return [float(2 * d.max() + bead_width) for d in _distances(gcode, centres_xy, z)]


def mean_diameters(gcode: str | Replay, centres_xy, z: float) -> list[float]:
    """Diameter of the least-squares circle of each loop's centreline (no bead width)."""
    return [float(2 * d.mean()) for d in _distances(gcode, centres_xy, z)]
