"""The union of closed parts, by manifold3d's robust booleans.

Two uses in the repair: the fast path for an input made only of closed, edge-manifold,
consistently oriented shells that overlap one another (a typical CAD export) --
:func:`union_of_shells`, which keeps the input's triangles, cut where the shells cross,
and says which input face each piece is of -- and the union of the solid outer hull with
the slabs, prisms and cylinders that thicken its sheets and wires
(:func:`manifold_union`). Either result is verified afterwards by the float32 check.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.clean import drop_unreferenced
from repair.intersections import intersecting_face_pairs
from repair.meshes import shell_volumes
from repair.patch_copies import covered, orphaned, two_bodies
from repair.rows import ranges, unique_ints
from repair.topology import (
    EdgeTopology,
    edge_components,
    edge_stats,
    edge_topology,
    weld_exact,
)

__all__ = ["ShellUnion", "duplicate_shells", "manifold_union", "speck_volume", "union_of_shells",
           "without_copies", "without_specks"]  # fmt: skip


#: From this many solids on, :func:`manifold_union` unites them in :data:`UNION_SHARES`
#: shares side by side on the CPUs: mikedh_soup's 162 solids took 1.13 s of CPU to unite
#: in one manifold3d batch, 0.69 s here (one share and the shares' union) and 0.5 s in
#: a child; mikedh_teapot's 534 slabs 1.03 s, 0.56 + 0.44 s.
SHARED_MIN_SOLIDS = 64
UNION_SHARES = 2
#: An open patch is looked at as a copy of another (:func:`duplicate_shells`) when it is
#: at least this many times the copy distance across.
COPY_MIN_SIZE = 10.0
#: Nearest face centroids searched for a face's copy (:func:`duplicate_shells`).
_COPY_NEIGHBOURS = 4


def speck_volume(epsilon: float) -> float:
    """The volume (mm³) below which a shell of a thickened union is a speck: a cube of
    1 % of eps on a side, far below what a nozzle of diameter eps can print."""
    return (0.01 * epsilon) ** 3


@dataclass(frozen=True)
class ShellUnion:
    """The union of shells: its ``vertices`` and ``faces``; for each face, the ``source``
    face of the input it is a piece of; the input's ``shells`` (label per input face)."""

    vertices: np.ndarray
    faces: np.ndarray
    source: np.ndarray
    shells: np.ndarray

    def shells_dropped(self) -> int:
        """Input shells no piece of which is in the union (nested inside others)."""
        seen = np.zeros(int(self.shells.max()) + 1, dtype=bool)
        seen[self.shells[self.source[self.source >= 0]]] = True
        return int(np.count_nonzero(~seen))


def _manifolds_of(
    v: np.ndarray,
    f: np.ndarray,
    labels: np.ndarray | None = None,
    *,
    keep_faces: bool = False,
    float64: bool = False,
) -> list | None:
    """One manifold3d solid per edge-connected component of ``(v, f)`` (or per label of
    ``labels``), or None if manifold3d rejects one. Much faster than
    ``Manifold.decompose`` on many pieces. ``keep_faces``: give each triangle its own
    face id (its row in ``f``), so that manifold3d keeps the input's triangles (cutting
    them where needed) instead of merging coplanar ones. ``float64``: the coordinates
    as they are (manifold3d's Mesh64) rather than rounded to float32."""
    import manifold3d as m3d

    lab = edge_components(f) if labels is None else labels
    order = np.argsort(lab, kind="stable")
    cuts = np.r_[0, np.flatnonzero(np.diff(lab[order])) + 1, len(lab)]
    mesh_type, real, index = (
        (m3d.Mesh64, np.float64, np.uint64) if float64 else (m3d.Mesh, np.float32, np.uint32)
    )
    vr = np.ascontiguousarray(v, dtype=real)
    out = []
    for i in range(len(cuts) - 1):
        rows = order[cuts[i] : cuts[i + 1]]
        used, inv = unique_ints(f[rows].reshape(-1), return_inverse=True)
        ids = {"face_id": rows.astype(index)} if keep_faces else {}
        solid = m3d.Manifold(
            mesh_type(
                vert_properties=np.ascontiguousarray(vr[used]),
                tri_verts=np.ascontiguousarray(inv.reshape(-1, 3), dtype=index),
                **ids,
            )
        )
        if solid.status() != m3d.Error.NoError:
            return None
        out.append(solid)
    return out


def duplicate_shells(
    v: np.ndarray, f: np.ndarray, gamma: float, *, patches: bool = False
) -> np.ndarray:
    """Which faces of ``(v, f)`` belong to a body written twice: True on every face of
    a closed shell (each edge used by an even number of its faces) that is a copy of
    an earlier one -- each of its points within ``gamma`` (mm) of its own point of the
    earlier shell, one to one, and its faces those of the earlier shell on the
    matching points, turned the same way.

    The union of a body with its copy moved by noise (a micrometre) is the body with
    steps a few float32 ulps wide along its edges: rounded for writing, their faces
    fold into the solid or out of it (cgal_part written twice 0.9 um apart: needles
    10 mm long of 2e-8 mm^2 failing the two-sided winding test). One copy is the body;
    dropping the other moves no surface farther than ``gamma``. A copy turned the
    other way round (a void of no thickness) is not one.

    ``patches``: open patches too (edge-connected, any edges), those at least
    :data:`COPY_MIN_SIZE` gamma across: a cracked body written twice is two copies of
    each of its patches, and the stitch would join each copy's rims to the other's as
    readily as to its own. A smaller patch (a soup's triangle) is left alone."""
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    if len(f) < 2:
        return np.zeros(len(f), dtype=bool)
    topology = edge_topology(f)
    labels = topology.shells
    n = topology.n_shells
    gone = np.zeros(n, dtype=bool)
    if n < 2:
        return gone[labels]
    if np.bincount(np.bincount(labels, minlength=n)).max() < 2:
        # No two shells of as many faces: no copy, unless cut differently.
        return (_face_copies(v, f, topology, gamma) if patches else gone)[labels]
    closed = np.ones(n, dtype=bool)
    if not patches:
        closed[labels[np.flatnonzero(topology.counts[topology.eid] % 2) // 3]] = False
    order = np.argsort(labels, kind="stable")
    cuts = np.r_[0, np.cumsum(np.bincount(labels, minlength=n))]
    twin = np.arange(len(v))
    wide = COPY_MIN_SIZE * gamma if patches else 0.0
    for a, b in _copy_candidates(v, f, labels, closed, gamma, wide):
        if not gone[a] and not gone[b]:
            fa, fb = (f[order[cuts[s] : cuts[s + 1]]] for s in (a, b))
            match = _is_copy(v, fa, fb, gamma)
            if match is not None:
                gone[b] = True
                twin[match[0]] = match[1]
    if patches and gone.any() and orphaned(v, topology, gone, twin, gamma):
        gone[:] = False
    if patches and not gone.any():
        gone = _face_copies(v, f, topology, gamma)
    return gone[labels]


def _face_copies(v: np.ndarray, f: np.ndarray, topology: EdgeTopology, gamma: float) -> np.ndarray:
    """Per patch of ``topology``: whether it is an open patch of a body written twice
    whose crack cut the copies differently (one copy's patch a face more than the
    other's): each of its faces has a copy in another patch -- corners within ``gamma``
    (mm), turned the same way -- every patch it shares a face with is so covered as
    well, and one of them comes first. The earliest patches of each such body are kept;
    none is dropped when a face kept would still have its copy kept."""
    n = topology.n_shells
    gone = np.zeros(n, dtype=bool)
    is_open = np.zeros(n, dtype=bool)
    is_open[topology.shells[np.flatnonzero(topology.counts[topology.eid] == 1) // 3]] = True
    if is_open.sum() < 4:
        return gone  # two copies, each cut in two at least
    from scipy.spatial import cKDTree

    at = np.flatnonzero(is_open[topology.shells])
    labels = topology.shells[at]
    corner = v[f[at]]
    centre = corner.mean(axis=1)
    # A copy's face is among the nearest few (its centroid moved by the copy's shift).
    dist, near = cKDTree(centre).query(centre, k=_COPY_NEIGHBOURS, distance_upper_bound=gamma)
    i, j = np.nonzero(np.isfinite(dist))
    pairs = np.c_[i, near[i, j]]
    pairs = pairs[labels[pairs[:, 0]] != labels[pairs[:, 1]]]
    a, b = corner[pairs[:, 0]], corner[pairs[:, 1]]
    same = np.zeros(len(pairs), dtype=bool)
    for r in range(3):  # the copy's corners in the same cyclic order
        same |= np.linalg.norm(a - np.roll(b, r, axis=1), axis=2).max(axis=1) <= gamma
    pairs = pairs[same]
    copied = np.zeros(len(at), dtype=bool)
    copied[pairs.reshape(-1)] = True
    full = np.bincount(labels, weights=~copied, minlength=n) == 0
    link = np.vstack([labels[pairs], labels[pairs[:, ::-1]]])  # (patch, partner)
    all_full = np.ones(n, dtype=bool)
    np.logical_and.at(all_full, link[:, 0], full[link[:, 1]])
    first = np.full(n, n)
    np.minimum.at(first, link[:, 0], link[:, 1])
    gone = full & all_full & (first < np.arange(n)) & is_open
    if not gone[labels[pairs]].any(axis=1).all():
        gone[:] = False  # a copy would be left: only some of its patches were copies
    if gone.any() and not covered(pairs, labels, gone):
        # A patch's faces also written again within its own body (coplanar copies the
        # crack cut apart) made a later copy's patch look first: the two bodies apart.
        gone = two_bodies(pairs, labels, is_open)
    return gone


def without_copies(
    v: np.ndarray, f: np.ndarray, pairs: np.ndarray, segments: np.ndarray, gamma: float,
    *, patches: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(faces, pairs, segments)``: ``f`` without the shells :func:`duplicate_shells`
    finds (the input arrays themselves when there are none), its crossing face
    ``pairs`` (k, 2) renumbered, and the wires ``segments`` (k, 2, 3) mm without those
    whose two ends are points of the dropped shells only (degenerate faces of the
    copy: they lie on it, a hair off the body kept). ``patches``: open patches'
    copies too (:func:`duplicate_shells`)."""
    dup = duplicate_shells(v, f, gamma, patches=patches)
    if not dup.any():
        return f, pairs, segments
    kept = np.cumsum(~dup) - 1
    pairs = kept[pairs[~dup[pairs].any(axis=1)]].reshape(-1, 2)
    if len(segments):
        gone = np.setdiff1d(f[dup], f[~dup])
        rows = np.vstack([v[gone], segments.reshape(-1, 3)])
        inv = np.unique(rows, axis=0, return_inverse=True)[1].reshape(-1)
        on_gone = np.isin(inv[len(gone) :], inv[: len(gone)]).reshape(-1, 2).all(axis=1)
        segments = segments[~on_gone]
    return f[~dup], pairs, segments


def _copy_candidates(
    v: np.ndarray, f: np.ndarray, labels: np.ndarray, closed: np.ndarray, gamma: float,
    wide: float = 0.0,
) -> list[tuple[int, int]]:
    """Pairs ``(a, b)``, a < b, of ``closed`` shells (mask per label) at least ``wide``
    (mm) across, with as many faces and points as each other and bounding boxes whose
    corners lie within ``gamma`` (mm) of each other's."""
    n = len(closed)
    faces = np.bincount(labels, minlength=n)
    # The points of each shell, once each, in order of shell.
    key = unique_ints(np.repeat(labels, 3) * len(v) + f.reshape(-1))
    shell, point = np.divmod(key, len(v))
    points = np.bincount(shell, minlength=n)
    first = np.r_[0, np.cumsum(points)[:-1]]
    lo = np.minimum.reduceat(v[point], first, axis=0)
    hi = np.maximum.reduceat(v[point], first, axis=0)
    closed = closed & ((hi - lo).max(axis=1) >= wide)
    # Shells sorted by signature (faces, points), then least x: a shell's candidates
    # follow it, of its signature, their least x within gamma of its own.
    sig = unique_ints(faces * (int(points.max()) + 1) + points, return_inverse=True)[1]
    order = np.flatnonzero(closed)
    order = order[np.lexsort((lo[order, 0], sig[order]))]
    n = len(order)
    x = lo[order, 0]
    start = np.searchsorted(sig[order], sig[order], side="left")
    # Each signature's x shifted past the previous one's (a sorted key for searchsorted).
    shift = x - x[start] + sig[order] * (float(np.ptp(lo[:, 0])) + 4.0 * gamma + 1.0)
    end = np.searchsorted(shift, shift + 1.01 * gamma, side="right")
    after = np.arange(1, n + 1)
    count = np.maximum(end - after, 0)
    i = np.repeat(np.arange(n), count)
    pairs = np.sort(np.c_[order[i], order[ranges(after, count)]], axis=1)
    box = np.c_[lo, hi]
    near = np.abs(box[pairs[:, 0]] - box[pairs[:, 1]]).max(axis=1) <= gamma
    pairs = pairs[near]
    return [(int(a), int(b)) for a, b in pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]]


def _is_copy(
    v: np.ndarray, fa: np.ndarray, fb: np.ndarray, gamma: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """When the faces ``fb`` are the faces ``fa`` on points of ``v`` moved by at most
    ``gamma`` (mm), one to one, each turned the same way: the points of ``fb`` and
    their own points of ``fa``; else None."""
    from scipy.spatial import cKDTree

    pa, pb = np.unique(fa), np.unique(fb)
    if len(pa) != len(pb):
        return None
    # Matched after taking out the mean shift: a copy moved by more than the distance
    # between two of its points (a CAD step's sliver: 3e-5 mm wide) is still matched
    # point to point.
    shift = v[pb].mean(axis=0) - v[pa].mean(axis=0)
    dist, near = cKDTree(v[pa]).query(v[pb] - shift, distance_upper_bound=gamma)
    if not np.all(np.isfinite(dist)) or len(np.unique(near)) != len(pb):
        return None
    if np.linalg.norm(v[pb] - v[pa[near]], axis=1).max() > gamma:
        return None
    to_a = np.zeros(int(pb.max()) + 1, dtype=np.int64)
    to_a[pb] = pa[near]
    if not np.array_equal(_cyclic_rows(fa), _cyclic_rows(to_a[fb])):
        return None
    return pb, pa[near]


def _cyclic_rows(f: np.ndarray) -> np.ndarray:
    """Faces each rotated to start at its smallest corner (orientation kept), sorted."""
    start = np.argmin(f, axis=1)[:, None]
    rot = np.take_along_axis(f, (start + np.arange(3)) % 3, axis=1)
    return rot[np.lexsort(rot.T[::-1])]


def union_of_shells(
    v: np.ndarray,
    f: np.ndarray,
    pairs: np.ndarray | None = None,
    census: tuple[int, int, int, int, np.ndarray | None] | None = None,
) -> ShellUnion | None:
    """Exact union of closed, edge-manifold, consistently oriented shells that intersect
    only one another (never themselves), by manifold3d, which keeps the input's
    triangles, cut where the shells cross, and says which each piece is of. None when
    not applicable. ``pairs``: the intersecting face pairs of ``(v, f)`` if known;
    ``census``: :func:`repair.topology.edge_stats` of ``f`` if known."""
    if len(f) == 0:
        return None
    # Every edge used by exactly two faces, in opposite directions; and the shells.
    if census is None or census[4] is None or len(census[4]) != len(f):
        census = edge_stats(f)
    boundary, nonmanifold, misoriented, n, labels = census
    if boundary or nonmanifold or misoriented:
        return None
    if pairs is None:
        pairs = intersecting_face_pairs(v, f)
    if len(pairs) and np.any(labels[pairs[:, 0]] == labels[pairs[:, 1]]):
        return None  # a shell intersects itself: needs the exact arrangement
    vol = shell_volumes(v, f, labels, n)
    if np.any(vol == 0.0):
        return None
    f = f.copy()
    inv = vol[labels] < 0
    f[inv] = f[inv][:, ::-1]
    if n == 1 and len(pairs) == 0:  # one closed shell, crossing nothing: it is the union
        uv, uf = drop_unreferenced(v, f)
        return ShellUnion(uv, uf, np.arange(len(uf)), labels)
    try:
        parts = _manifolds_of(v, f, labels, keep_faces=True)
        if not parts:
            return None
        res = _sum_of(parts).to_mesh64()
    except Exception:  # noqa: BLE001 - any failure means: take the exact path
        return None
    rv, rf = _arrays_of(res)
    if len(rf) == 0:
        return None
    source = np.asarray(res.face_id, dtype=np.int64).reshape(-1)
    if len(source) != len(rf) or source.min() < 0 or source.max() >= len(f):
        return None  # provenance lost: take the exact path rather than guess
    return ShellUnion(*weld_exact(rv, rf), source, labels)


def manifold_union(
    parts: list[tuple[np.ndarray, np.ndarray]], *, collapse: bool = True,
    min_volume: float = 0.0, shells: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Union of closed oriented pieces -- the solid outer hull first (welded here), then
    sheet slabs, ledge prisms and wire cylinders (each already an indexed closed solid)
    -- by manifold3d's robust booleans; None if manifold3d rejects a piece. The result
    is verified (and resolved exactly if need be) by the caller's float32 check.
    ``collapse``: simplify away slivers and sub-ulp features (moves the surface by up to
    2^-17 of the part's size); off, the faces the union did not cut stay as they were,
    and the result keeps manifold3d's float64 coordinates for the caller to round.
    ``min_volume`` (mm³): shells of the result enclosing less than that, solid or
    cavity, are left out (see :func:`without_specks`). ``shells``: the solid of each face
    of the first part, where its edge-connected components are not (closed shells that
    share an edge: one manifold3d solid each, not one non-manifold piece)."""
    solids = []
    try:
        for i, (v, f) in enumerate(parts):
            if len(f) == 0:
                continue
            # The solid hull is welded; slabs, prisms and cylinders are each indexed
            # closed solids -- welding would fuse coincident corners of different ones.
            labels = shells if i == 0 else None
            pieces = _manifolds_of(*drop_unreferenced(*(weld_exact(v, f) if i == 0 else (v, f))),
                                   labels)  # fmt: skip
            if pieces is None:
                return None
            solids.extend(pieces)
        if not solids:
            return None
        out = _sum_of(solids) if len(solids) < SHARED_MIN_SOLIDS else _sum_in_shares(solids)
        # Collapse what float32 cannot hold apart anyway: slivers and sub-ulp features.
        if collapse:
            size = max(float(np.abs(np.asarray(p[0])).max()) for p in parts if len(p[1]))
            out = out.simplify(size * 2.0**-17)
        res = out.to_mesh() if collapse else out.to_mesh64()
    except Exception:  # noqa: BLE001 - any failure means: take the exact path
        return None
    rv, rf = _arrays_of(res)
    if len(rf) == 0:
        return None
    return without_specks(*weld_exact(rv, rf), min_volume)


def without_specks(
    v: np.ndarray, f: np.ndarray, min_volume: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(v, f)`` without its edge-connected shells of |volume| below ``min_volume`` (mm³).

    A union of many overlapping eps-blocks leaves specks where their corners nearly
    meet: islands of 1e-10..1e-7 mm³ in the cavities between blocks, and inverted
    slivers on the surface, which rounding to float32 turns into separate outer
    components. No printer can print or leave empty anything that small. A shell
    nested in another encloses less than it, so a dropped shell takes whatever lies
    inside it along. ``min_volume`` 0 keeps everything."""
    if min_volume <= 0 or len(f) == 0:
        return v, f
    labels = edge_components(f)
    n = int(labels.max()) + 1
    if n == 1:
        return v, f
    keep = np.abs(shell_volumes(v, f, labels, n)) >= min_volume
    if keep.all() or not keep.any():
        return v, f
    return drop_unreferenced(v, f[keep[labels]])


def _sum_in_shares(solids: list):
    """:func:`_sum_of` many solids as the union of the unions of :data:`UNION_SHARES`
    shares of them (neighbours, about equal in triangles), taken side by side on the
    CPUs (:func:`repair.workers.map_forked`). Each share's union comes back as its float64
    mesh, one solid (its cavity shells with it), whatever the CPUs: the same output for
    any number of them."""
    from repair.workers import balanced_shares, cpu_workers, map_forked

    # Shares of neighbouring solids (cut across the longest side of their boxes' centres):
    # two halves of a thickened surface side by side meet along one cut, not everywhere.
    box = np.array([s.bounding_box() for s in solids], dtype=np.float64).reshape(-1, 2, 3)
    centre = box.mean(axis=1)
    order = np.argsort(centre[:, np.argmax(np.ptp(centre, axis=0))], kind="stable")
    tris = np.cumsum(np.array([s.num_tri() for s in solids])[order])
    cut = np.searchsorted(tris, tris[-1] * np.arange(1, UNION_SHARES) / UNION_SHARES)
    groups = [g.tolist() for g in np.split(order, cut) if len(g)]
    if len(groups) < 2:  # one solid holds most triangles: nothing to share
        return _sum_of(solids)

    def unite(share: list[int]) -> tuple[np.ndarray, np.ndarray]:
        mesh = _sum_of([solids[i] for i in share]).to_mesh64()
        return np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts)

    jobs = balanced_shares([1] * len(groups), min(cpu_workers(), len(groups)))  # CPUs
    parts = []
    for v, f in map_forked(unite, groups, jobs):
        if len(f):
            part = _manifolds_of(v, f, np.zeros(len(f), dtype=np.int64), float64=True)
            if part is None:
                raise ValueError("manifold3d rejected a share's union")
            parts.extend(part)
    if not parts:
        raise ValueError("the union is empty")
    return _sum_of(parts)


def _sum_of(solids: list):
    """The boolean union of manifold3d solids (at least one)."""
    import manifold3d as m3d

    return m3d.Manifold.batch_boolean(solids, m3d.OpType.Add) if len(solids) > 1 else solids[0]


def _arrays_of(mesh) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices float64 (n, 3), faces int64 (m, 3))`` of a manifold3d mesh."""
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    return verts, np.asarray(mesh.tri_verts, dtype=np.int64)
