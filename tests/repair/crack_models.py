"""Generated cracked surfaces for the stitching tests (units mm)."""

from __future__ import annotations

import numpy as np


def hemisphere(
    radius: float, segments: int, rings: int, upper: bool
) -> tuple[np.ndarray, np.ndarray]:
    """An open UV hemisphere, outward oriented: ``segments`` vertices round its rim (the
    equator, z = 0) and a pole; ``rings`` rings of quads between them."""
    phi = np.linspace(0.0, 0.5 * np.pi, rings + 1)[:-1]  # from the equator, pole apart
    theta = 2 * np.pi * np.arange(segments) / segments
    r = radius * np.cos(phi)[:, None]
    z = radius * np.sin(phi)[:, None] * np.ones_like(theta)
    ring_v = np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=-1).reshape(-1, 3)
    v = np.vstack([ring_v, [0.0, 0.0, radius]])
    pole = len(v) - 1
    idx = np.arange(rings * segments).reshape(rings, segments)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = idx[1:], np.roll(idx[1:], -1, axis=1)
    quads = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])  # fmt: skip
    top = np.stack([idx[-1], np.roll(idx[-1], -1), np.full(segments, pole)], axis=1)
    f = np.vstack([quads, top])
    if not upper:
        v = v * [1.0, 1.0, -1.0]
        f = f[:, ::-1]
    return v, f


def cracked_sphere(
    radius: float = 10.0, offset: float = 0.03, segments: tuple[int, int] = (48, 40)
) -> tuple[np.ndarray, np.ndarray]:
    """A sphere made of two hemispheres with a crack between them at the equator: their
    rims have different vertex counts (not matching one to one) and the lower half is
    moved down by ``offset`` mm and turned a little."""
    vu, fu = hemisphere(radius, segments[0], 12, upper=True)
    vl, fl = hemisphere(radius, segments[1], 12, upper=False)
    turn = 0.5 * np.pi / segments[1] * 0.3
    rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    vl = vl @ rot.T - [0.0, 0.0, offset]
    return np.vstack([vu, vl]), np.vstack([fu, fl + len(vu)])
