"""Thumbnail benchmark: seconds to draw the G-code thumbnails (16×16 and 220×124) of meshes
from 1k to 330k triangles, and that time as a share of slicing the same mesh in the same
process (the embedded slicer, default profile, thumbnails off). "thumb s" is a call with the
mesh alone (the solid is built from it); "in slicer s" one given the manifold3d solid, as the
slicer calls it (it has built the solid already).

Run: .venv/bin/python bench/bench_thumbnail.py [--repeat N]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _meshes():
    import trimesh

    for sub in (4, 6, 7):
        s = trimesh.creation.icosphere(subdivisions=sub, radius=20.0)
        yield f"icosphere/{sub}", s.vertices, s.faces
    t = trimesh.creation.torus(30.0, 8.0, major_sections=400, minor_sections=250)
    yield "torus", t.vertices, t.faces


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    t0 = time.perf_counter()
    import PIL.ImageDraw  # noqa: F401
    print(f"Pillow import: {time.perf_counter() - t0:.3f} s")

    from slicer.engine import _to_manifold, slice_mesh
    from slicer.profile import Profile
    from slicer.thumbnail import thumbnail_blocks

    profile = Profile.for_printer().with_overrides({"thumbnails": ""})
    print(f"{'mesh':<14}{'triangles':>10}{'thumb s':>9}{'in slicer s':>12}{'slice s':>9}"
          f"{'share':>8}{'bytes':>8}")
    sizes = [(16, 16), (220, 124)]
    for name, v, f in _meshes():
        solid = _to_manifold(v, f)
        best = given = float("inf")
        for _ in range(args.repeat):
            t = time.perf_counter()
            text = thumbnail_blocks(v, f, sizes)
            best = min(best, time.perf_counter() - t)
            t = time.perf_counter()
            thumbnail_blocks(v, f, sizes, solid=solid)
            given = min(given, time.perf_counter() - t)
        t = time.perf_counter()
        slice_mesh(v, f, profile)
        sliced = time.perf_counter() - t
        print(f"{name:<14}{len(f):>10}{best:>9.3f}{given:>12.3f}{sliced:>9.2f}"
              f"{given / sliced:>8.1%}{len(text):>8}")


if __name__ == "__main__":
    main()
