"""Close the small holes of almost-closed shells (Bøhn & Wozny's shell closure).

An open scan or a sloppy export is often a closed shell with a few small holes. Attene's
algorithm would treat the whole open shell as a zero-thickness sheet and thicken all of
it; a user expects the holes to be filled instead, after which the shell is solid and the
exact path keeps it exactly. Genuine open surfaces (an open-topped box, a fin, a single
sheet) are left alone: only a shell whose boundary is a small fraction of its edges, and
whose holes all have a perimeter small against the shell's size, gets its holes closed --
all of them, so it comes out closed (lidding some holes of a shell that stays open would
only add surface to a sheet). Triangles dangling off an edge of such a shell next to its
holes (flaps, as scanners leave them: an open edge plus an edge of three or more faces)
are removed, or the holes beside them would not be simple loops.

Each closed hole gets a lid: one triangle for a 3-edge hole, otherwise a fan from the
loop's centroid (one new vertex). The lid is oriented against the hole's rim faces, so a
consistently oriented shell stays consistently oriented. Lids may cross the shell where
a hole is strongly non-planar; the exact self-intersection resolution that follows
repairs such crossings.

Units are mm. Arrays: vertices float64 (n, 3), faces int64 (m, 3). Pure functions;
the edge bookkeeping is vectorised, the only Python loop runs once per boundary vertex
to trace loops (boundaries are small by construction: at most a few percent of edges).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.topology import edge_components, edge_ids, half_edges

__all__ = [
    "MAX_BOUNDARY_FRACTION",
    "MAX_PERIMETER_FRACTION",
    "HolesClosed",
    "boundary_loops",
    "close_small_holes",
    "flap_faces",
]

#: A shell is "almost closed" when at most this fraction of its edges are boundary edges.
MAX_BOUNDARY_FRACTION = 0.03
#: A hole is "small" when its perimeter is at most this fraction of the shell's bounding
#: box diagonal. The rim of a flat sheet is at least twice as long as the sheet is wide,
#: and a bowl's rim (pi d) is longer than its diagonal, so neither is ever "small".
MAX_PERIMETER_FRACTION = 0.5


@dataclass(frozen=True)
class HolesClosed:
    """What :func:`close_small_holes` did: ``count`` holes closed, ``area`` mm² of lid
    added, ``lid_triangles`` triangles added, ``max_perimeter`` mm of the largest hole
    closed and ``max_lid_radius`` mm, a bound on how far any lid point lies from its rim
    (hence from the input surface); ``flaps_removed`` faces (``flap_area`` mm²) dangling
    off the shell next to a hole were removed so the hole could be closed."""

    count: int = 0
    area: float = 0.0
    lid_triangles: int = 0
    max_perimeter: float = 0.0
    max_lid_radius: float = 0.0
    flaps_removed: int = 0
    flap_area: float = 0.0

    def to_dict(self) -> dict[str, float | int]:
        return {
            "count": int(self.count),
            "area": round(float(self.area), 9),
            "lid_triangles": int(self.lid_triangles),
            "max_perimeter": float(self.max_perimeter),
            "max_lid_radius": float(self.max_lid_radius),
            "flaps_removed": int(self.flaps_removed),
            "flap_area": round(float(self.flap_area), 9),
        }


def boundary_loops(faces: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Closed loops of boundary edges (edges used by exactly one face).

    Returns the loops, each an int64 array of vertex indices ordered *against* the rim
    faces' orientation (the order a lid needs to continue that orientation), and the face
    component label (edge-connected) of each loop's rim. Where several boundary edges
    meet at a vertex (two holes touching at a corner, as when two deleted triangles share
    a vertex), each arriving edge continues with the one reached by turning round the
    vertex through the rim's faces (:func:`_successors_at_forks`), so each hole is its
    own loop; a loop that cannot be followed so (an edge of three or more faces on the
    way round) is not returned: such a hole is left to the sheet thickening.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return [], np.zeros(0, dtype=np.int64)
    he = half_edges(f)  # (3m, 2) a->b
    eid, cnt = edge_ids(f)
    comp = edge_components(f, eid)
    bnd = np.flatnonzero(cnt[eid] == 1)
    if len(bnd) == 0:
        return [], np.zeros(0, dtype=np.int64)
    # A lid edge runs b->a for the rim's a->b.
    src, dst = he[bnd, 1], he[bnd, 0]
    n_v = int(f.max()) + 1
    out_deg = np.bincount(src, minlength=n_v)
    in_deg = np.bincount(dst, minlength=n_v)
    # Successor (index into bnd) of each lid edge: the lid edge leaving its end.
    leaving = np.full(n_v, -1, dtype=np.int64)
    leaving[src] = np.arange(len(bnd))
    simple = (out_deg[dst] == 1) & (in_deg[dst] == 1)
    succ = np.where(simple, leaving[dst], -1)
    fork = np.flatnonzero(~simple)
    if len(fork):
        succ[fork] = _successors_at_forks(f, he, eid, cnt, bnd, fork, len(leaving))
    rim_comp = comp[bnd // 3]
    loops: list[np.ndarray] = []
    labels: list[int] = []
    seen = np.zeros(len(bnd), dtype=bool)
    succ_l = succ.tolist()
    for start in range(len(bnd)):
        if seen[start]:
            continue
        loop = [start]
        seen[start] = True
        cur = succ_l[start]
        ok = True
        while cur != start:
            if cur < 0 or seen[cur]:
                ok = False
                break
            seen[cur] = True
            loop.append(cur)
            cur = succ_l[cur]
        if ok:
            for part in _simple_loops(src[np.asarray(loop, dtype=np.int64)].tolist()):
                loops.append(np.asarray(part, dtype=np.int64))
                labels.append(int(rim_comp[start]))
    return loops, np.asarray(labels, dtype=np.int64)


def _simple_loops(loop: list[int]) -> list[list[int]]:
    """A closed walk through vertices split where it passes a vertex again (a hole
    that touches itself at a corner) into closed walks that do not: each gets its own
    lid, which then never uses an edge twice. Walks of fewer than three vertices (an
    edge there and back) need no lid."""
    out: list[list[int]] = []
    stack: list[int] = []
    where: dict[int, int] = {}
    for x in loop:
        if x in where:
            p = where[x]
            part = stack[p:]
            for y in part[1:]:
                del where[y]
            del stack[p + 1 :]
            if len(part) >= 3:
                out.append(part)
            continue
        where[x] = len(stack)
        stack.append(x)
    if len(stack) >= 3:
        out.append(stack)
    return out


def _successors_at_forks(
    f: np.ndarray, he: np.ndarray, eid: np.ndarray, cnt: np.ndarray, bnd: np.ndarray,
    fork: np.ndarray, n: int,
) -> np.ndarray:
    """For each lid edge in ``fork`` (indices into ``bnd``) that ends at a vertex where
    several boundary edges meet: the lid edge (index into ``bnd``) that continues its
    hole, found by turning round the vertex from the rim face through two-face edges
    until the next boundary edge; -1 where that turn meets an edge of three or more
    faces. One short Python walk per such edge (they are few)."""
    # Twin of every half-edge on a two-face edge at the fork vertices.
    x_all = he[bnd[fork], 0]
    near = np.isin(he[:, 0], x_all) | np.isin(he[:, 1], x_all)
    idx = np.flatnonzero(near)
    keys = (he[idx, 0] * np.int64(n) + he[idx, 1]).tolist()
    by_dir = dict(zip(keys, idx.tolist(), strict=True))
    bnd_pos = {int(h): i for i, h in enumerate(bnd.tolist())}
    out = np.full(len(fork), -1, dtype=np.int64)
    for j, i in enumerate(fork.tolist()):
        h = int(bnd[i])  # rim half-edge x->y; the lid edge y->x arrives at x
        x = int(he[h, 0])
        for _ in range(len(f)):
            face, k = divmod(h, 3)
            arriving = 3 * face + (k + 2) % 3  # w->x in the same face
            if cnt[eid[arriving]] == 1:
                # The boundary edge w->x: its lid edge x->w leaves x and continues.
                out[j] = bnd_pos[arriving]
                break
            if cnt[eid[arriving]] != 2:
                break
            w = int(he[arriving, 0])
            h = by_dir.get(x * n + w, -1)  # the twin x->w
            if h < 0:
                break
    return out


def _shells(
    v: np.ndarray, f: np.ndarray, max_boundary_fraction: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per face: edge-connected component and the use count of each of its 3 edges
    (m, 3); per component: "almost closed" flag and bounding-box diagonal (mm)."""
    eid, cnt = edge_ids(f)
    comp = edge_components(f, eid)
    n = int(comp.max()) + 1
    # Each undirected edge belongs to one component (its faces are edge-connected).
    edge_comp = np.empty(len(cnt), dtype=np.int64)
    edge_comp[eid] = np.repeat(comp, 3)
    n_edges = np.bincount(edge_comp, minlength=n)
    n_bnd = np.bincount(edge_comp[cnt == 1], minlength=n)
    order = np.argsort(np.repeat(comp, 3), kind="stable")
    corner = v[f.reshape(-1)[order]]
    start = np.searchsorted(np.repeat(comp, 3)[order], np.arange(n))
    diag = np.linalg.norm(
        np.maximum.reduceat(corner, start, axis=0) - np.minimum.reduceat(corner, start, axis=0),
        axis=1,
    )
    almost_closed = n_bnd <= max_boundary_fraction * n_edges
    return comp, cnt[eid].reshape(-1, 3), almost_closed, diag


def flap_faces(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    max_boundary_fraction: float = MAX_BOUNDARY_FRACTION,
) -> np.ndarray:
    """Mask of the *flaps* of almost-closed shells: faces with an open edge and an edge
    shared by more than two faces (a triangle dangling off, or folded over, an edge of
    the shell, as scanners leave them), no larger than 4x the median face area.

    Such a flap keeps the hole next to it from being a simple loop; removing it lets the
    hole be closed. Flaps of shells that are not almost closed are not flagged (those
    are sheets, and sheets are thickened).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=bool)
    comp, use, almost_closed, _ = _shells(v, f, max_boundary_fraction)
    flap = (use == 1).any(axis=1) & (use > 2).any(axis=1) & almost_closed[comp]
    if not flap.any():
        return flap
    p = v[f]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return flap & (area <= 4.0 * np.median(area))


def _lid(
    v: np.ndarray, loop: np.ndarray, perim: float, centre_index: int
) -> tuple[np.ndarray, np.ndarray | None, float, float]:
    """The lid of a hole (``loop``: its vertices in lid order, ``perim`` mm round it):
    one triangle for three vertices, else a fan from the loop's centroid, which becomes
    vertex ``centre_index``. Returns ``(triangles, centroid or None, area mm², radius)``;
    every lid point lies within ``radius`` mm of the rim."""
    p = v[loop]
    if len(loop) == 3:
        area = 0.5 * float(np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0])))
        # Any point of a triangle lies within its inradius (2 area / perimeter) of an edge.
        radius = float(np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))) / perim
        return loop[None, :], None, area, radius
    centre = p.mean(axis=0)
    k = len(loop)
    tris = np.stack([loop, np.roll(loop, -1), np.full(k, centre_index)], axis=1)
    radius = float(np.linalg.norm(p - centre, axis=1).max())
    cr = np.cross(p - centre, np.roll(p, -1, axis=0) - centre)
    return tris, centre, 0.5 * float(np.linalg.norm(cr, axis=1).sum()), radius


def close_small_holes(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    max_boundary_fraction: float = MAX_BOUNDARY_FRACTION,
    max_perimeter_fraction: float = MAX_PERIMETER_FRACTION,
) -> tuple[np.ndarray, np.ndarray, HolesClosed]:
    """Fill the small holes of almost-closed shells with lids.

    A hole (a simple loop of boundary edges) is *small* when its shell (edge-connected
    component) has at most ``max_boundary_fraction`` of its edges on the boundary and the
    loop's perimeter is at most ``max_perimeter_fraction`` of the shell's bounding-box
    diagonal (mm). A shell's holes are closed only when all of them are small, so the
    shell comes out closed; otherwise it is left as it is (a sheet). Flaps
    (:func:`flap_faces`) of such shells are removed first, and stay removed only when
    their shell had its holes closed. Vertices are kept (same indices;
    lid centroids are appended); faces keep their order except that the flaps kept move
    after the others; lid faces are appended.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or not np.any(edge_ids(f)[1] == 1):
        return v, f, HolesClosed()  # no open edge: nothing to close
    flaps = flap_faces(v, f, max_boundary_fraction=max_boundary_fraction)
    flap_f = f[flaps]
    f = f[~flaps]
    loops, labels = boundary_loops(f)
    if not loops:
        return v, np.vstack([f, flap_f]), HolesClosed()
    comp, use, almost_closed, diag = _shells(v, f, max_boundary_fraction)
    # Lids only where they close the shell: every boundary edge of it is on a small hole.
    # Closing some holes of a shell that stays open would not make it solid (it is still a
    # sheet, and is thickened), the lids would only add surface.
    n_bnd = np.bincount(comp, weights=(use == 1).sum(axis=1), minlength=len(diag))
    perims = np.array(
        [np.linalg.norm(np.roll(v[lp], -1, axis=0) - v[lp], axis=1).sum() for lp in loops]
    )
    small = almost_closed[labels] & (perims <= max_perimeter_fraction * diag[labels])
    sizes = np.array([len(lp) for lp in loops], dtype=np.float64)
    covered = np.bincount(labels[small], weights=sizes[small], minlength=len(diag))
    closable = (covered == n_bnd) & (n_bnd > 0)

    new_v: list[np.ndarray] = []
    new_f: list[np.ndarray] = []
    closed_in: list[int] = []
    area = max_perim = max_radius = 0.0
    for loop, c, perim in zip(loops, labels.tolist(), perims.tolist(), strict=True):
        if not closable[c]:
            continue
        tris, centre, lid_area, radius = _lid(v, loop, perim, len(v) + len(new_v))
        if centre is not None:
            new_v.append(centre[None, :])
        area += lid_area
        new_f.append(tris)
        closed_in.append(c)
        max_perim = max(max_perim, perim)
        max_radius = max(max_radius, radius)
    count, lid_tris = len(new_f), sum(len(t) for t in new_f)
    # A flap stays removed only when its shell had holes closed (the shell is a scan with
    # holes, its flaps scanner noise next to them); the others go back (fins are sheets).
    gone = np.zeros(len(flap_f), dtype=bool)
    if len(flap_f) and new_f:
        lidded = np.zeros(len(v), dtype=bool)
        lidded[f[np.isin(comp, np.asarray(closed_in, dtype=np.int64))].reshape(-1)] = True
        gone = lidded[flap_f].any(axis=1)
    n_flaps = int(np.count_nonzero(gone))
    p = v[flap_f[gone]]
    flap_area = 0.5 * float(
        np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    )
    out_v = np.vstack([v, *new_v]) if new_v else v
    out_f = np.vstack([f, flap_f[~gone], *new_f])
    return (
        out_v,
        out_f,
        HolesClosed(count, area, lid_tris, max_perim, max_radius, n_flaps, flap_area),
    )
