"""A generated scanned-like mesh for the scan cleanup tests and bench (units mm, seeded):
a finely meshed sphere with measurement noise, spikes, specks and ragged holes."""

from __future__ import annotations

import numpy as np


def noisy_scan(
    subdivisions: int = 5,
    radius: float = 20.0,
    *,
    seed: int = 0,
    spikes: int = 6,
    holes: int = 5,
    specks: int = 12,
) -> tuple[np.ndarray, np.ndarray]:
    """An icosphere (20 * 4**subdivisions faces before damage) with radial noise of
    +-5% of its edge length, ``spikes`` vertices pulled out by 0.2 radius, ``holes`` ragged holes
    (faces within a jittered radius of a centre removed) and ``specks`` loose little
    patches (1-4 triangles each) floating near the surface."""
    import trimesh

    rng = np.random.default_rng(seed)
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = np.asarray(s.vertices, dtype=np.float64)
    f = np.asarray(s.faces, dtype=np.int64)
    edge = radius * np.linalg.norm(v[f[0, 0]] - v[f[0, 1]])
    # Measurement noise: radial, up to 5% of the edge length.
    v *= radius + 0.05 * edge * rng.uniform(-1, 1, size=(len(v), 1))
    unit = v / np.linalg.norm(v, axis=1, keepdims=True)
    # Spikes: single vertices pulled far out of the surface.
    tips = rng.choice(len(v), size=spikes, replace=False)
    v[tips] += 0.2 * radius * unit[tips]
    # Ragged holes: a jittered disc of faces removed round random centres (away from tips).
    centroid = v[f].mean(axis=1)
    keep = np.ones(len(f), dtype=bool)
    for c in rng.choice(np.setdiff1d(np.arange(len(v)), tips), size=holes, replace=False):
        r = edge * rng.uniform(2.0, 4.0)
        jitter = r * (1.0 + 0.5 * rng.uniform(-1, 1, size=len(f)))
        keep &= np.linalg.norm(centroid - v[c], axis=1) > jitter
    f = f[keep]
    # Specks: tiny loose patches just off the surface.
    extra_v, extra_f = [], []
    base = len(v)
    for _ in range(specks):
        centre = rng.normal(size=3)
        centre = radius * (1.0 + rng.uniform(0.02, 0.1)) * centre / np.linalg.norm(centre)
        k = int(rng.integers(1, 5))
        ring = centre + 0.3 * edge * rng.normal(size=(k + 1, 3))
        extra_v.append(np.vstack([centre, ring]))
        fan = np.stack([np.zeros(k), np.arange(1, k + 1), np.arange(2, k + 2)], axis=1)
        extra_f.append(fan.astype(np.int64) + base)
        base += k + 2
    return np.vstack([v, *extra_v]), np.vstack([f, *extra_f])
