"""Travel ordering within a layer: role groups in print order, nearest neighbour inside each.

Closed loops may start at any vertex (the nearest one is chosen); open paths may be reversed.
Each step of the greedy search is one vectorised numpy pass over the candidate points.
"""

from __future__ import annotations

import numpy as np

from slicer.planner import Path

ROLE_ORDER = ("skirt", "brim", "support", "support_interface", "perimeter",
              "external_perimeter", "thin_wall", "bridge_infill", "solid_infill",
              "top_solid_infill", "sparse_infill")


def _nearest_neighbour(
    paths: list[Path], pos: np.ndarray, rear_seam: bool = False, aligner=None
) -> tuple[list[tuple[np.ndarray, Path]], np.ndarray]:
    """Order ``paths`` greedily from ``pos``; returns (oriented points, path) and the end pos.

    With ``rear_seam``, closed loops start at their rearmost vertex (largest y, then
    smallest x) instead of the nearest one, so that seams line up at the back of the part.
    """
    if len(paths) == 1:
        return _only_path(paths[0], pos, rear_seam, aligner)
    ends_only = [p.points if p.closed or len(p.points) == 2 else p.points[[0, -1]]
                 for p in paths]
    counts = np.fromiter((len(a) for a in ends_only), dtype=np.int64, count=len(paths))
    pts = np.concatenate(ends_only)
    px = np.ascontiguousarray(pts[:, 0])
    py = np.ascontiguousarray(pts[:, 1])
    ends = np.cumsum(counts)
    begins = ends - counts
    pid = np.repeat(np.arange(len(paths)), counts)
    vidx = np.arange(len(pts)) - begins[pid]
    dead = np.zeros(len(pts))
    gap, dy = np.empty(len(pts)), np.empty(len(pts))  # reused: no allocation per step
    out: list[tuple[np.ndarray, Path]] = []
    x, y = float(pos[0]), float(pos[1])
    table = _gap_table(px, py, len(paths)) if aligner is None else None
    here = -1  # the candidate point the nozzle stands on (-1: none, or no table)
    for _ in range(len(paths)):
        if here < 0:
            np.subtract(px, x, out=gap)
            np.multiply(gap, gap, out=gap)
            np.subtract(py, y, out=dy)
            np.multiply(dy, dy, out=dy)
            gap += dy
            gap += dead
        else:
            np.add(table[here], dead, out=gap)
        j = int(gap.argmin())
        i = int(pid[j])
        dead[begins[i]:ends[i]] = np.inf
        p = paths[i]
        k = int(vidx[j])
        if p.closed:
            if aligner is not None:
                out.append((aligner.ring(p.points), p))
            else:
                if rear_seam:
                    k = int(np.lexsort((p.points[:, 0], -p.points[:, 1]))[0])
                out.append((np.concatenate([p.points[k:], p.points[:k + 1]]), p))
        else:
            out.append((p.points if k == 0 else p.points[::-1], p))
        last = out[-1][0][-1]
        x, y = float(last[0]), float(last[1])
        if table is not None:  # a path ends on one of its own candidates: its row is known
            here = int(begins[i]) + (k if p.closed else 1 - min(k, 1))
    return out, np.array([x, y])


def _gap_table(px: np.ndarray, py: np.ndarray, n_paths: int) -> np.ndarray | None:
    """The squared distances between all candidate points (the same arithmetic as one step of
    the search), when the table costs less than the steps it saves (few points per path)."""
    if len(px) ** 2 > 300 * n_paths:
        return None
    table = np.subtract(px[None, :], px[:, None])
    np.multiply(table, table, out=table)
    dy = np.subtract(py[None, :], py[:, None])
    np.multiply(dy, dy, out=dy)
    table += dy
    return table


def _only_path(p: Path, pos: np.ndarray, rear_seam: bool, aligner
               ) -> tuple[list[tuple[np.ndarray, Path]], np.ndarray]:
    """``_nearest_neighbour`` of a group of one path (a third of all groups: one skirt, one
    outer loop, one island's solid infill...), without its tables: the same squared
    distances, so the same start."""
    if p.closed and (aligner is not None or rear_seam):
        k = 0
    else:
        cand = p.points if p.closed or len(p.points) == 2 else p.points[[0, -1]]
        gap = cand[:, 0] - float(pos[0])
        gap *= gap
        dy = cand[:, 1] - float(pos[1])
        dy *= dy
        gap += dy
        k = int(gap.argmin())
    if p.closed:
        if aligner is not None:
            oriented = aligner.ring(p.points)
        else:
            if rear_seam:
                k = int(np.lexsort((p.points[:, 0], -p.points[:, 1]))[0])
            oriented = np.concatenate([p.points[k:], p.points[:k + 1]])
    else:
        oriented = p.points if k == 0 else p.points[::-1]
    last = oriented[-1]
    return [(oriented, p)], np.array([float(last[0]), float(last[1])])


def order_paths(paths: list[Path], pos: np.ndarray, seam: str = "rear", aligner=None
                ) -> tuple[list[tuple[np.ndarray, Path]], np.ndarray]:
    """All paths of one layer in print order as (oriented points, path) pairs, plus end pos.

    ``seam``: "rear" starts external perimeters at their rearmost vertex, "nearest" at the
    vertex nearest to the nozzle, "aligned" where ``aligner`` (a slicer.travel.SeamAligner,
    kept across layers) says."""
    groups: dict[str, list[Path]] = {}
    for p in paths:
        groups.setdefault(p.role, []).append(p)
    result: list[tuple[np.ndarray, Path]] = []
    for role in ROLE_ORDER:
        group = groups.get(role)
        if not group:
            continue
        outer = role == "external_perimeter"
        oriented, pos = _nearest_neighbour(
            group, pos, rear_seam=seam == "rear" and outer,
            aligner=aligner if seam == "aligned" and outer else None)
        result.extend(oriented)
    if aligner is not None:
        aligner.next_layer()
    return result, pos
