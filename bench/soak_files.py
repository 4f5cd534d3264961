"""The files the soak drops into the spool: good and broken meshes, G-code, garbage.

Every file is small (boxes of a few mm, G-code of a few hundred lines) so that repair,
slicing and printing stay quick and the soak's CPU use is dominated by the daemon's
own repair/slice children. Each kind states what the daemon may do with it:

- ``ok``: it must end printed (done), unless a fault interrupted its print or killed
  its processing too often (``interrupted`` / the attempts limit);
- ``fail``: it must be refused or failed with a reason, never printed;
- ``any``: either outcome is legitimate (a truncated STL may still hold a mesh).
"""

from __future__ import annotations

import os
import random
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from repair.io import write_stl

ROOT = Path(__file__).resolve().parents[1]
STUCK_CUBE = ROOT / "daemon" / "data" / "open_cube_stuck_to_side.stl"


@dataclass(frozen=True)
class Drop:
    """One file to drop: its spool name, its bytes, and what the daemon may do with it."""

    name: str
    kind: str
    data: bytes
    expect: str  # "ok" | "fail" | "any"


def _box(origin: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                        [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                      [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
                     dtype=np.int64)
    return origin + corners * size, faces


def _stl_bytes(tmp: Path, vertices: np.ndarray, faces: np.ndarray) -> bytes:
    write_stl(tmp, vertices, faces)
    data = tmp.read_bytes()
    tmp.unlink()
    return data


def _mesh(kind: str, rng: random.Random, tmp: Path) -> bytes:
    size = np.array([rng.uniform(3.0, 6.0) for _ in range(3)])
    vertices, faces = _box(np.zeros(3), size)
    if kind == "inverted":  # turned inside out, one face doubled: a typical broken export
        faces = np.vstack([faces[:, ::-1], faces[:1, ::-1]])
    elif kind == "holed":  # one or two triangles missing
        drop = rng.sample(range(len(faces)), rng.choice((1, 2)))
        faces = np.delete(faces, drop, axis=0)
    elif kind == "overlap":  # two boxes that intersect: self-intersections to resolve
        other_v, other_f = _box(size * 0.5, size * 0.8)
        faces = np.vstack([faces, other_f + len(vertices)])
        vertices = np.vstack([vertices, other_v])
    return _stl_bytes(tmp, vertices, faces)


def _gcode(rng: random.Random, forbidden: bool) -> bytes:
    """A small square-spiral print with heating, homing and cooldown."""
    x0, y0 = rng.uniform(20, 180), rng.uniform(20, 150)
    lines = ["; soak test print", "G21", "G90", "M82", "M140 S60", "M104 S210",
             "M190 S60", "M109 S210", "G28", "G92 E0", "G1 Z0.3 F600"]
    extruded = 0.0
    for step in range(rng.randrange(80, 300)):
        side = 1.0 + 0.05 * step
        dx, dy = [(side, 0), (0, side), (-side, 0), (0, -side)][step % 4]
        x0, y0 = x0 + dx * 0.2, y0 + dy * 0.2
        extruded += 0.02 * side
        lines.append(f"G1 X{x0:.3f} Y{y0:.3f} E{extruded:.4f} F1800")
        if step % 50 == 49:
            lines.append(f"G1 Z{0.3 + 0.3 * (step // 50 + 1):.2f} F600")
    if forbidden:
        lines.insert(rng.randrange(5, len(lines)), "M500 ; saves settings to EEPROM")
    lines += ["M104 S0", "M140 S0", "M107", "G1 Z20 F600", "M84"]
    return ("\n".join(lines) + "\n").encode()


def _garbage(rng: random.Random) -> bytes:
    size = rng.randrange(1, 4000)
    if (size - 84) % 50 == 0:  # never a size that a binary STL could have
        size += 1
    return bytes(rng.randrange(256) for _ in range(size))


#: kind -> (weight, suffix, expectation)
KINDS: dict[str, tuple[float, str, str]] = {
    "box": (20, ".stl", "ok"),
    "inverted": (10, ".stl", "ok"),
    "holed": (10, ".stl", "ok"),
    "overlap": (6, ".stl", "ok"),
    "stuck_cube": (3, ".stl", "ok"),
    "gcode": (22, ".gcode", "ok"),
    "forbidden_gcode": (4, ".gcode", "fail"),
    "garbage": (9, ".stl", "fail"),
    "garbage_obj": (3, ".obj", "fail"),
    "empty": (5, ".stl", "fail"),
    "truncated": (8, ".stl", "any"),
}


def make_drop(index: int, rng: random.Random, tmp: Path) -> Drop:
    """The ``index``-th file of the soak, its kind drawn with ``rng``."""
    names = list(KINDS)
    kind = rng.choices(names, weights=[KINDS[k][0] for k in names])[0]
    _, suffix, expect = KINDS[kind]
    if kind in ("box", "inverted", "holed", "overlap"):
        data = _mesh(kind, rng, tmp)
    elif kind == "stuck_cube":
        data = STUCK_CUBE.read_bytes()
    elif kind in ("gcode", "forbidden_gcode"):
        data = _gcode(rng, forbidden=kind == "forbidden_gcode")
    elif kind in ("garbage", "garbage_obj"):
        data = _garbage(rng)
    elif kind == "empty":
        data = b""
    else:  # truncated: a good box cut short somewhere after the header
        whole = _mesh("box", rng, tmp)
        data = whole[: rng.randrange(85, len(whole) - 1)]
    return Drop(f"soak{index:05d}-{kind}{suffix}", kind, data, expect)


def write_drop(spool: Path, drop: Drop, *, chunks: int = 1, seconds: float = 0.0) -> None:
    """Write ``drop`` into the spool through one open file: at once, or in ``chunks``
    pieces spread over ``seconds`` (a slow network copy; the file is closed once)."""
    path = spool / drop.name
    with open(path, "wb") as fh:
        if chunks <= 1 or not drop.data:
            fh.write(drop.data)
            return
        step = max(1, -(-len(drop.data) // chunks))
        for start in range(0, len(drop.data), step):
            fh.write(drop.data[start:start + step])
            fh.flush()
            os.fsync(fh.fileno())
            time.sleep(seconds / chunks)
