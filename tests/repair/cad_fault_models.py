"""Real CAD models of tests/data and the faults CAD exporters leave in them (issue 18),
shared by tests/repair/test_cad_faults.py and the fault sweep (bench/bench_cad_faults.py).

Every fault generator takes ``(v, f, seed)`` -- vertices (mm, float (n, 3)), faces
(int (m, 3)) and a seed or a :class:`numpy.random.Generator` (a generator is used as
is, so faults applied one after another draw from one stream) -- and returns the
faulted ``(v, f)``. None removes material: each faulted model's repair should be the
intact solid (volume of :func:`intact_volume`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np

from repair.check import check_printable
from repair.io import load_mesh, write_stl
from repair.pipeline import repair_mesh

DATA = Path(__file__).resolve().parents[1] / "data"

#: The sweep's models: (file in tests/data, scale to printer size).
MODELS = {
    "part": ("cgal_part.obj", 60.0),
    "step": ("cgal_step.obj", 0.05),
    "multibody": ("trimesh_multibody.stl", 50.0),
    "cubes": ("cgal_cubes.obj", 20.0),
}

Seed = int | np.random.Generator
Mesh = tuple[np.ndarray, np.ndarray]


def real_model(name: str, scale: float) -> Mesh:
    """A model of tests/data (see ATTRIBUTION.md) scaled to printer size (mm)."""
    m = load_mesh(DATA / name)
    return np.asarray(m.vertices, np.float64) * scale, np.asarray(m.faces, np.int64)


@functools.cache
def intact_volume(name: str, scale: float) -> float:
    """The volume (mm³) of the repair of the intact model: what a faulted copy of it
    must come back to (the multibody part is written with faces flipped, the cubes share
    an edge of four faces: their repair, not the input, is the solid)."""
    r = repair_mesh(*real_model(name, scale), 0.4)
    return check_printable(r.vertices, r.faces).volume


def repaired_and_written(v: np.ndarray, f: np.ndarray, path: Path):
    """Repair, write the binary STL ``path``, read it back: returns the mesh read back,
    the exact check's verdict on those float32 coordinates and the repair's report."""
    r = repair_mesh(v, f, 0.4)
    write_stl(path, r.vertices, r.faces)
    w = load_mesh(path)
    return w, check_printable(w.vertices, w.faces), r.report


def face_areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    p = v[f]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def nearest_faces(
    v: np.ndarray, f: np.ndarray, rng: np.random.Generator, frac: float
) -> np.ndarray:
    """``frac`` of the faces, those whose centres are nearest a random face's."""
    centre = v[f].mean(axis=1)
    d = np.linalg.norm(centre - centre[rng.integers(len(f))], axis=1)
    return np.argsort(d)[: max(1, int(frac * len(f)))]


def unwelded(v: np.ndarray, f: np.ndarray, patch: np.ndarray, rng: np.random.Generator) -> Mesh:
    """The faces ``patch`` given their own copy of their vertices, moved by float noise
    (1e-6 relative), as a CAD exporter writes each surface patch."""
    used = np.unique(f[patch])
    moved = v[used] * (1 + rng.normal(0, 1e-6, (len(used), 3)))
    remap = np.arange(len(v))
    remap[used] = len(v) + np.arange(len(used))
    out = f.copy()
    out[patch] = remap[f[patch]]
    return np.vstack([v, moved]), out


def cracked(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """A patch of 10-50 % of the faces (nearest a random one) unwelded (:func:`unwelded`)."""
    rng = np.random.default_rng(seed)
    centre = v[f].mean(axis=1)
    d = np.linalg.norm(centre - centre[rng.integers(len(f))], axis=1)
    patch = np.argsort(d)[: max(1, int(rng.uniform(0.1, 0.5) * len(f)))]
    return unwelded(v, f, patch, rng)


def crack(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """:func:`cracked`, drawing the share before the patch (the sweep's order)."""
    rng = np.random.default_rng(seed)
    share, centre = rng.uniform(0.1, 0.5), v[f].mean(axis=1)
    d = np.linalg.norm(centre - centre[rng.integers(len(f))], axis=1)
    return unwelded(v, f, np.argsort(d)[: max(1, int(share * len(f)))], rng)


def flipped(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """5-30 % of the faces (nearest a random one) written the wrong way round."""
    rng = np.random.default_rng(seed)
    out = f.copy()
    patch = nearest_faces(v, f, rng, rng.uniform(0.05, 0.3))
    out[patch] = out[patch, ::-1]
    return v, out


def t_junctions(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """5-30 % of the faces (nearest a random one) each split in two at the midpoint of
    its first edge, while the neighbour across keeps the whole edge."""
    rng = np.random.default_rng(seed)
    centre = v[f].mean(axis=1)
    d = np.linalg.norm(centre - centre[rng.integers(len(f))], axis=1)
    split = np.argsort(d)[: max(1, int(rng.uniform(0.05, 0.3) * len(f)))]
    a, b, c = f[split].T
    mid = len(v) + np.arange(len(split))
    v = np.vstack([v, (v[a] + v[b]) / 2])
    f = np.vstack([np.delete(f, split, axis=0), np.stack([a, mid, c], 1), np.stack([mid, b, c], 1)])
    return v, f


def slivers(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """Zero-area slivers (a, midpoint, b) written on the first edge of 5 % of the faces."""
    rng = np.random.default_rng(seed)
    on = rng.integers(len(f), size=max(1, len(f) // 20))
    a, b, mid = f[on, 0], f[on, 1], len(v) + np.arange(len(on))
    return np.vstack([v, (v[a] + v[b]) / 2]), np.vstack([f, np.stack([a, mid, b], axis=1)])


def dup_shell(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """The whole body written twice, the copy moved by 1e-5 to 1e-3 of the model's size."""
    rng = np.random.default_rng(seed)
    off = rng.normal(0, 1, 3)
    off *= float(np.ptp(v, axis=0).max()) * 10 ** rng.uniform(-5, -3) / np.linalg.norm(off)
    return np.vstack([v, v + off]), np.vstack([f, f + len(v)])


def coplanar_copies(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """5-30 % of the faces (nearest a random one) written again, half of the copies
    turned the other way."""
    rng = np.random.default_rng(seed)
    copies = f[nearest_faces(v, f, rng, rng.uniform(0.05, 0.3))]
    turn = rng.random(len(copies)) < 0.5
    copies[turn] = copies[turn][:, ::-1]
    return v, np.vstack([f, copies])


def holes(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """2 % of the faces (at least one) deleted at random."""
    rng = np.random.default_rng(seed)
    return v, np.delete(f, rng.choice(len(f), size=max(1, len(f) // 50), replace=False), axis=0)


def split_copies(v: np.ndarray, f: np.ndarray, seed: Seed) -> Mesh:
    """A few faces (nearest a random one, 1-10 %) written again as two halves split at
    the midpoint of their first edge."""
    rng = np.random.default_rng(seed)
    pick = nearest_faces(v, f, rng, rng.uniform(0.01, 0.1))
    a, b, c = f[pick].T
    mid = len(v) + np.arange(len(pick))
    v = np.vstack([v, (v[a] + v[b]) / 2])
    return v, np.vstack([f, np.stack([a, mid, c], 1), np.stack([mid, b, c], 1)])


#: The sweep's fault kinds, in the order a combo draws them by index.
FAULTS: dict[str, Callable[[np.ndarray, np.ndarray, Seed], Mesh]] = {
    "crack": crack,
    "flip": flipped,
    "tjunction": t_junctions,
    "slivers": slivers,
    "dup_shell": dup_shell,
    "copies": coplanar_copies,
    "holes": holes,
    "split_copy": split_copies,
}


def combo_kinds(seed: int, k: int = 3) -> tuple[np.random.Generator, list[str]]:
    """The sweep's combo draw: ``k`` different fault kinds in random order, and the
    generator the faults then draw from."""
    rng = np.random.default_rng(seed)
    names = list(FAULTS)
    return rng, [names[i] for i in rng.choice(len(names), size=k, replace=False)]


def faulted(v: np.ndarray, f: np.ndarray, kinds: list[str], rng: np.random.Generator) -> Mesh:
    """``(v, f)`` with the faults ``kinds`` applied in that order, drawing from ``rng``."""
    for kind in kinds:
        v, f = FAULTS[kind](v, f, rng)
    return v, f


def multibody() -> tuple[np.ndarray, np.ndarray, float]:
    """trimesh's multibody.stl at 50x: two solids, written with some faces flipped (as
    exporters that trust the normals do), and the volume of its own repair (mm³)."""
    name, scale = MODELS["multibody"]
    return *real_model(name, scale), intact_volume(name, scale)


def copied_slivered_cracked(
    name: str, scale: float, seed: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """A model written twice, the copy 1e-5 to 1e-3 of its size apart, slivers on
    edges, then a patch cracked off (the sweep's combo dup_shell, slivers, crack); and
    the intact model's volume (mm³)."""
    rng = np.random.default_rng(seed)
    v, f = faulted(*real_model(name, scale), ["dup_shell", "slivers", "crack"], rng)
    return v, f, intact_volume(name, scale)


def needles_split_and_copied(v: np.ndarray, f: np.ndarray) -> Mesh:
    """The fault sweep's combination 1 on the part: needles (a, mid(a, b), b) on random
    edges; faces near one split at their first edge's midpoint (needles among them split
    into fans of two); faces near another written twice, half of the copies flipped."""
    rng = np.random.default_rng(1)
    rng.choice(7, size=3, replace=False)  # the old sweep's draw of the three faults
    pick = rng.integers(len(f), size=len(f) // 20)
    a, b = f[pick, 0], f[pick, 1]
    mid = len(v) + np.arange(len(pick))
    v, f = np.vstack([v, (v[a] + v[b]) / 2]), np.vstack([f, np.stack([a, mid, b], 1)])
    split = nearest_faces(v, f, rng, rng.uniform(0.05, 0.3))
    a, b, c = f[split].T
    mid = len(v) + np.arange(len(split))
    v = np.vstack([v, (v[a] + v[b]) / 2])
    f = np.vstack([np.delete(f, split, axis=0), np.stack([a, mid, c], 1), np.stack([mid, b, c], 1)])
    copies = f[nearest_faces(v, f, rng, rng.uniform(0.05, 0.3))]
    flip = rng.random(len(copies)) < 0.5
    copies[flip] = copies[flip][:, ::-1]
    return v, np.vstack([f, copies])


def swept(model: str, kinds: str, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A case of the CAD fault sweep (bench/bench_cad_faults.py): the faults ``kinds``
    applied to ``model`` in that order, drawing from ``seed`` (three kinds: the combo
    sweep's draw for ``seed``, which must be these), and the intact volume (mm³)."""
    name, scale = MODELS[model]
    rng = np.random.default_rng(seed)
    if len(kinds.split()) == 3:
        rng, drawn = combo_kinds(seed)
        if drawn != kinds.split():
            raise ValueError(f"combo seed {seed} draws {drawn}, not {kinds}")
    return *faulted(*real_model(name, scale), kinds.split(), rng), intact_volume(name, scale)
