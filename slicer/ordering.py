"""Travel ordering within a layer: role groups in print order, nearest neighbour inside each.

Closed loops may start at any vertex (the nearest one is chosen); open paths may be reversed.
Each step of the greedy search is one vectorised numpy pass over the candidate points.
"""

from __future__ import annotations

import numpy as np

from slicer.planner import Path

ROLE_ORDER = ("skirt", "perimeter", "external_perimeter", "thin_wall", "solid_infill",
              "sparse_infill")


def _nearest_neighbour(
    paths: list[Path], pos: np.ndarray
) -> tuple[list[tuple[np.ndarray, Path]], np.ndarray]:
    """Order ``paths`` greedily from ``pos``; returns (oriented points, path) and the end pos."""
    pts_list, pid_list, idx_list = [], [], []
    for i, p in enumerate(paths):
        n = len(p.points)
        if p.closed:
            pts_list.append(p.points)
            pid_list.append(np.full(n, i))
            idx_list.append(np.arange(n))
        else:
            pts_list.append(p.points[[0, -1]])
            pid_list.append(np.array([i, i]))
            idx_list.append(np.array([0, -1]))
    pts = np.concatenate(pts_list)
    pid = np.concatenate(pid_list)
    vidx = np.concatenate(idx_list)
    alive = np.ones(len(pts), dtype=bool)
    # point ranges per path, for killing a whole path at once
    counts = np.array([len(a) for a in pts_list])
    ends = np.cumsum(counts)
    begins = ends - counts
    out: list[tuple[np.ndarray, Path]] = []
    for _ in range(len(paths)):
        d2 = np.einsum("ij,ij->i", pts - pos, pts - pos)
        d2[~alive] = np.inf
        j = int(np.argmin(d2))
        i = int(pid[j])
        alive[begins[i]:ends[i]] = False
        p = paths[i]
        if p.closed:
            k = int(vidx[j])
            ring = np.concatenate([p.points[k:], p.points[:k + 1]]) if k else \
                np.concatenate([p.points, p.points[:1]])
            out.append((ring, p))
        else:
            out.append((p.points if vidx[j] == 0 else p.points[::-1], p))
        pos = out[-1][0][-1]
    return out, pos


def order_paths(paths: list[Path], pos: np.ndarray) -> tuple[list[tuple[np.ndarray, Path]],
                                                             np.ndarray]:
    """All paths of one layer in print order as (oriented points, path) pairs, plus end pos."""
    groups: dict[str, list[Path]] = {}
    for p in paths:
        groups.setdefault(p.role, []).append(p)
    result: list[tuple[np.ndarray, Path]] = []
    for role in ROLE_ORDER:
        group = groups.get(role)
        if not group:
            continue
        oriented, pos = _nearest_neighbour(group, pos)
        result.extend(oriented)
    return result, pos
