"""γ-stitching of cracks (Attene 2018, Sec. 5.2): boundaries of different patches that run
within γ of each other are joined before the outer hull is computed, so a cracked closed
surface comes out closed with its intended genus instead of thickened along the crack.

Three steps, on boundary (lamina) edges and vertices of different edge-connected patches:

1. *snap rims*: a boundary edge matched with one of another patch running the other way
   within γ (each the other's closest such edge) has its ends merged with that edge's
   (the lower index is kept, so coordinates stay those of the input: float32 values
   stay float32 values). Edges, not vertices: two vertices of the intact surface may lie
   closer together than a crack's noise, and only the right copies share a rim edge;
2. *snap*: a boundary vertex still on the boundary whose nearest boundary vertex of
   another patch (within γ) has it as its nearest too is merged with it (corners where
   three patches meet, patches exported flipped);
3. *split*: every boundary vertex still on the boundary that lies within γ of the inside
   of a boundary edge of another patch is inserted into that edge: the edge's face is
   split into a fan from its opposite corner, keeping its orientation. Both sides of a
   crack then run through the same vertices and share their edges. So is a T-junction
   inside one patch: a vertex where the boundary runs straight on, lying on a boundary
   edge of its own patch up to the rounding of its coordinates.

No vertex moves by more than γ and every new triangle lies within γ of the face it
replaces, so the deviation D of the stitch is at most γ. Vectorised: candidate pairs from
a KD-tree (``scipy.spatial.cKDTree``), the rest numpy. Units are mm; vertices float64
(n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from repair.stitch_layers import one_layer, unpaired_edges, without_caps, without_flaps
from repair.topology import (
    EdgeTopology,
    connected_labels,
    edge_topology,
    half_edges,
    paired_half_edges,
)

__all__ = ["Stitched", "stitch_cracks", "without_caps"]

#: How many rounds of edge splitting at most (a face with points on two of its edges
#: needs two; each round splits one edge per face).
_SPLIT_ROUNDS = 3
#: A boundary vertex this close (relative to the coordinates' size) to the inside of a
#: boundary edge of its own patch is a T-junction (float32 rounding leaves ~1e-7).
_T_JUNCTION = 1e-6
#: How many rounds of vertex snapping at most (a corner where k patches meet needs k - 1).
_SNAP_ROUNDS = 4


@dataclass(frozen=True)
class Stitched:
    """What :func:`stitch_cracks` did: ``gamma`` mm, ``snapped`` vertex pairs merged,
    ``inserted`` vertices put into a boundary edge of another patch, ``boundary_before``
    and ``boundary_after`` boundary edges; ``declined`` when the stitch was undone because
    it would have made edges of more than two faces or misoriented ones; ``moved``
    (k, 2): each merged vertex and the vertex it became (whose coordinates it took)."""

    gamma: float = 0.0
    snapped: int = 0
    inserted: int = 0
    boundary_before: int = 0
    boundary_after: int = 0
    declined: bool = False
    moved: np.ndarray = field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64), compare=False
    )

    def to_dict(self) -> dict[str, float | int]:
        return {
            "gamma": float(self.gamma),
            "snapped": int(self.snapped),
            "inserted": int(self.inserted),
            "boundary_edges_before": int(self.boundary_before),
            "boundary_edges_after": int(self.boundary_after),
            "declined": bool(self.declined),
        }


def _boundary(f: np.ndarray, topology: EdgeTopology) -> tuple[np.ndarray, np.ndarray]:
    """Boundary half-edge ids (used by one face only) and each face's patch label
    (``topology``: that of ``f`` when it describes them)."""
    t = topology if topology.of(f) else edge_topology(f)
    return np.flatnonzero(t.counts[t.eid] == 1), t.shells


def _boundary_vertices(
    f: np.ndarray, bnd: np.ndarray, patch: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The vertices on boundary half-edges ``bnd`` (either end: where a patch was
    exported flipped, a rim vertex may start none of them) and a patch of each."""
    he = half_edges(f)
    ends = he[bnd].T.reshape(-1)
    bv, first = np.unique(ends, return_index=True)
    return bv, patch[np.tile(bnd, 2)[first] // 3]


def _snap(
    v: np.ndarray, f: np.ndarray, gamma: float, topology: EdgeTopology, patch: np.ndarray,
    matched: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray | None]:
    """Faces with mutually nearest boundary vertices of different patches merged, each
    face's ``patch`` label (carried through), and how many pairs were merged. Two
    vertices both ``matched`` (merged by :func:`_snap_rims`: each has found its copy)
    are not: left on the boundary, they are the ends of a crack that runs on, and their
    nearest is a vertex of another shell (a body written twice, shifted). Last, the
    vertex each vertex became (None when none was merged)."""
    bnd = _boundary(f, topology)[0]
    bv, bpatch = _boundary_vertices(f, bnd, patch)
    if len(bv) < 2:
        return f, patch, 0, None
    from scipy.spatial import cKDTree

    k = min(8, len(bv))
    dist, nb = cKDTree(v[bv]).query(v[bv], k=k, distance_upper_bound=gamma)
    dist, nb = dist.reshape(len(bv), k), nb.reshape(len(bv), k)
    found = np.isfinite(dist)
    other = found & (bpatch[np.minimum(nb, len(bv) - 1)] != bpatch[:, None])
    has = other.any(axis=1)
    nearest = np.where(has, nb[np.arange(len(bv)), np.argmax(other, axis=1)], -1)
    i = np.flatnonzero(has)
    mutual = i[nearest[nearest[i]] == i]
    a, b = mutual, nearest[mutual]
    sel = (a < b) & ~(matched[bv[a]] & matched[bv[b]])
    a, b = a[sel], b[sel]
    if len(a) == 0:
        return f, patch, 0, None
    out, ok, to = _merged(len(v), f, bv[a], bv[b])
    return out[ok], patch[ok], len(a), to


def _merged(
    n: int, f: np.ndarray, a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``f`` with the vertices joined by pairs ``a[i] -- b[i]`` (of ``n``) merged into the
    lowest index of each group, which faces keep three distinct corners, and the
    vertex each of the ``n`` became."""
    labels = connected_labels(n, a, b)
    keep = np.full(labels.max() + 1, n)
    np.minimum.at(keep, labels, np.arange(n))
    to = keep[labels]
    out = to[f]
    ok = (out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 2] != out[:, 0])
    return out, ok, to


def _snap_rims(
    v: np.ndarray, f: np.ndarray, gamma: float, topology: EdgeTopology, patch: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces with the ends of matched rim edges merged, which vertices were merged, and
    the vertex each vertex became.

    A boundary half-edge ``s -> e`` of one patch matches one ``e' -> s'`` of another
    (opposite direction, as the two sides of a crack of a consistently oriented surface
    run) with ``|s - s'|`` and ``|e - e'|`` within γ; each takes the match of least summed
    distance, and mutual matches are kept. Where two vertices of the intact surface lie
    closer than the crack's noise (a CAD step's sliver: 3e-5 mm apart, noise 1e-4 mm),
    nearest vertices are the wrong copies but only the right ones are joined by a rim
    edge. A group of merged vertices that would collapse a face is left apart."""
    bnd = _boundary(f, topology)[0]
    none, kept = np.zeros(len(v), dtype=bool), np.arange(len(v))
    if len(bnd) < 2:
        return f, none, kept
    from scipy.spatial import cKDTree

    rim_patch = patch[bnd // 3]
    if rim_patch.min() == rim_patch.max():
        return f, none, kept
    rim = half_edges(f)[bnd]
    s, e = v[rim[:, 0]], v[rim[:, 1]]
    i, j = cKDTree(0.5 * (s + e)).query_pairs(gamma, output_type="ndarray").T
    i, j = i[rim_patch[i] != rim_patch[j]], j[rim_patch[i] != rim_patch[j]]
    # Running the other way (the sides of a crack), else the same way (a patch written
    # flipped): only an edge with no partner of the first kind takes one of the second.
    ds, de = np.linalg.norm(s[i] - e[j], axis=1), np.linalg.norm(e[i] - s[j], axis=1)
    ss, ee = np.linalg.norm(s[i] - s[j], axis=1), np.linalg.norm(e[i] - e[j], axis=1)
    opposite = (ds <= gamma) & (de <= gamma)
    same = ~opposite & (ss <= gamma) & (ee <= gamma)
    sel = opposite | same
    if not sel.any():
        return f, none, kept
    cost = np.where(opposite, ds + de, ss + ee + 4 * gamma)[sel]
    i, j, same = i[sel], j[sel], same[sel]
    i, j, same, cost = np.r_[i, j], np.r_[j, i], np.tile(same, 2), np.tile(cost, 2)
    order = np.lexsort((cost, i))
    i, j, same = i[order], j[order], same[order]
    first = np.r_[True, i[1:] != i[:-1]]
    best = np.full(len(bnd), -1)
    best[i[first]] = j[first]
    flipped = np.zeros(len(bnd), dtype=bool)
    flipped[i[first]] = same[first]
    m = np.flatnonzero(best >= 0)
    m = m[(best[best[m]] == m) & (m < best[m])]
    if len(m) == 0:
        return f, none, kept
    other = rim[best[m]]
    other[~flipped[m]] = other[~flipped[m], ::-1]
    a = np.concatenate([rim[m, 0], rim[m, 1]])
    b = np.concatenate([other[:, 0], other[:, 1]])
    # Only one-to-one joins: a group of three or more (two copies of a sliver's ends
    # drawn to one vertex, a corner of several patches) is left to vertex snapping, as
    # is one that would collapse a face.
    labels = connected_labels(len(v), a, b)
    bad = np.bincount(labels, minlength=labels.max() + 1) > 2
    out, ok, to = _merged(len(v), f, a, b)
    bad[labels[f[~ok][out[~ok] == np.roll(out[~ok], -1, axis=1)]]] = True
    if bad.any():
        good = ~bad[labels[a]]
        a, b = a[good], b[good]
        out, _, to = _merged(len(v), f, a, b)
    merged = np.zeros(len(v), dtype=bool)
    merged[a] = merged[b] = True
    return (out, merged, to) if len(a) else (f, merged, kept)


def _split_candidates(
    v: np.ndarray, f: np.ndarray, gamma: float, topology: EdgeTopology, own_only: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(half-edge, vertex, t)``: boundary vertices within γ of the inside of a boundary
    edge of another patch, or on one of their own patch (T-junctions, see the module
    docstring; ``own_only``: those only); each vertex with its nearest such edge, ``t``
    in (0, 1) the position along the half-edge."""
    bnd, patch = _boundary(f, topology)
    he = half_edges(f)
    none = np.zeros(0, dtype=np.int64)
    if len(bnd) == 0:
        return none, none, np.zeros(0)
    bv, bpatch = _boundary_vertices(f, bnd, patch)
    a, b = v[he[bnd, 0]], v[he[bnd, 1]]
    length = np.linalg.norm(b - a, axis=1)
    from scipy.spatial import cKDTree

    hits = cKDTree(v[bv]).query_ball_point(0.5 * (a + b), 0.5 * length + gamma)
    counts = np.fromiter((len(h) for h in hits), dtype=np.int64, count=len(hits))
    if counts.sum() == 0:
        return none, none, np.zeros(0)
    e = np.repeat(np.arange(len(bnd)), counts)
    p = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits if h])
    other = bpatch[p] != patch[bnd[e] // 3]
    # Of its own patch only a vertex where the boundary runs straight on (most hits are
    # neighbours round the same hole): a T-junction's slit passes straight through it.
    sel = (other & (not own_only)) | _straight(v, he[bnd])[bv[p]]
    e, p, other = e[sel], p[sel], other[sel]
    ab = b[e] - a[e]
    t = np.einsum("ij,ij->i", v[bv[p]] - a[e], ab) / np.maximum(length[e] ** 2, 1e-300)
    d = np.linalg.norm(a[e] + t[:, None] * ab - v[bv[p]], axis=1)
    margin = 1e-6
    # A T-junction: a vertex of the same patch on the edge, up to the rounding of its
    # coordinates (an exporter split a face at a point of its neighbour's edge).
    tight = _T_JUNCTION * np.maximum(np.abs(np.hstack([a, b])).max(axis=1), 1.0)  # per edge
    keep = (d <= gamma) & (t > margin) & (t < 1 - margin) & (other | (d <= tight[e]))
    e, p, t, d = e[keep], p[keep], t[keep], d[keep]
    if len(e) == 0:
        return none, none, np.zeros(0)
    # Each vertex goes into its nearest edge only.
    order = np.lexsort((d, p))
    e, p, t = e[order], p[order], t[order]
    one = np.r_[True, p[1:] != p[:-1]]
    return bnd[e[one]], bv[p[one]], t[one]


def _straight(v: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """Per vertex: whether a boundary half-edge of ``rim`` (k, 2) comes into it and
    another leaves it in the same direction (up to the rounding of its coordinates),
    every in/out pair at a vertex looked at."""
    order = np.argsort(rim[:, 0], kind="stable")
    first = np.searchsorted(rim[order, 0], np.arange(len(v)))
    count = np.bincount(rim[:, 0], minlength=len(v))[rim[:, 1]]  # out-edges at each end
    i = np.repeat(np.arange(len(rim)), count)
    j = order[np.repeat(first[rim[:, 1]], count) + np.arange(len(i))
              - np.repeat(np.cumsum(count) - count, count)]  # fmt: skip
    u = v[rim[i, 1]] - v[rim[i, 0]]
    w = v[rim[j, 1]] - v[rim[j, 0]]
    # The corner's distance from the line joining its neighbours, against the rounding
    # of its coordinates (:data:`_T_JUNCTION`).
    gap = np.linalg.norm(np.cross(u, w), axis=1) / np.maximum(np.linalg.norm(u + w, axis=1), 1e-300)
    size = np.maximum(np.abs(v[rim[i, 1]]).max(axis=1), 1.0)
    ok = (gap <= _T_JUNCTION * size) & (np.einsum("ij,ij->i", u, w) > 0)
    out = np.zeros(len(v), dtype=bool)
    out[rim[i[ok], 1]] = True
    return out


def _split_faces(f: np.ndarray, h: np.ndarray, p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Faces with points ``p`` inserted into half-edges ``h`` at ``t`` (one split half-edge
    per face: points on a face's other edges wait for the next round)."""
    face = h // 3
    first_edge = np.full(len(f), -1)
    np.maximum.at(first_edge, face, h)  # one half-edge per face: the last listed
    sel = first_edge[face] == h
    h, p, t = h[sel], p[sel], t[sel]
    order = np.lexsort((t, h))
    h, p = h[order], p[order]
    k = h % 3
    fa = f[h // 3, k]
    fb = f[h // 3, (k + 1) % 3]
    fc = f[h // 3, (k + 2) % 3]
    start = np.r_[True, h[1:] != h[:-1]]
    last = np.r_[h[1:] != h[:-1], True]
    prev = np.where(start, fa, np.r_[-1, p[:-1]])
    fans = np.stack([prev, p, fc], axis=1)
    ends = np.stack([p[last], fb[last], fc[last]], axis=1)
    drop = np.zeros(len(f), dtype=bool)
    drop[h // 3] = True
    return np.vstack([f[~drop], fans, ends])


def stitch_cracks(
    vertices: np.ndarray, faces: np.ndarray, gamma: float,
    topology: EdgeTopology | None = None,
) -> tuple[np.ndarray, Stitched]:
    """Stitch the boundaries of different patches that lie within ``gamma`` mm of each
    other. Returns the new faces (on the same vertices; no vertex moves, merged ones
    take the coordinates of the lower index) and what was done. Faces away from the
    cracks keep their order and come first."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or gamma <= 0:
        return f, Stitched(gamma=float(gamma))
    topo = topology if topology is not None and topology.of(f) else edge_topology(f)
    if topo.boundary == 0:
        return f, Stitched(gamma=float(gamma))
    out = _stitched(v, f, gamma, topo, tees_first=False)
    if out[1].declined:
        # A body written twice within γ, each copy split differently at T-junctions:
        # rims of one copy's slits match the other copy's, and joining them joins the
        # copies. Each slit closed first (no crack: a face split at its neighbour's
        # edge), the copies are closed shells, and what remains is stitched.
        again = _stitched(v, f, gamma, topo, tees_first=True)
        if not again[1].declined:
            return again
    return out


def _stitched(
    v: np.ndarray, f: np.ndarray, gamma: float, topo: EdgeTopology, tees_first: bool
) -> tuple[np.ndarray, Stitched]:
    """:func:`stitch_cracks` of ``f`` (``topo`` its topology, with a boundary); with
    ``tees_first``, T-junctions inside one patch are split into their edges before
    anything is snapped."""
    b0, nonmanifold, misoriented = topo.boundary, unpaired_edges(topo), topo.misoriented
    original = f
    inserted = 0
    if tees_first:
        for _ in range(_SPLIT_ROUNDS):
            h, p, t = _split_candidates(v, f, gamma, topo, own_only=True)
            if len(h) == 0:
                break
            n = len(f)
            f = _split_faces(f, h, p, t)
            inserted += len(f) - n
        if f is original:
            return f, Stitched(float(gamma), boundary_before=b0, boundary_after=b0,
                               declined=True)  # fmt: skip
        topo = edge_topology(f)
    # Where three or more patches meet at a corner (a cracked-off patch touching two
    # others), its copies are merged a mutual pair per round; the patches keep their
    # input labels, so a copy left over still finds the patch it was cut from.
    patch = topo.shells
    f, matched, became = _snap_rims(v, f, gamma, topo, patch)
    snapped = 0 if f is original else len(np.unique(original)) - len(np.unique(f))
    topo_f = edge_topology(f) if snapped else topo
    for _ in range(_SNAP_ROUNDS):
        f, patch, merged, to = _snap(v, f, gamma, topo_f, patch, matched)
        snapped += merged
        if to is None:
            break
        became = to[became]
        topo_f = edge_topology(f)
    for _ in range(_SPLIT_ROUNDS):
        h, p, t = _split_candidates(v, f, gamma, topo)
        if len(h) == 0:
            break
        n = len(f)
        f = _split_faces(f, h, p, t)
        inserted += len(f) - n
    if f is not original:
        f = one_layer(v, without_flaps(v, f, gamma), gamma)
    after = topo if topo.of(f) else edge_topology(f)
    b1, nonmanifold_after, misoriented_after = (
        after.boundary, unpaired_edges(after), after.misoriented
    )
    if misoriented_after > misoriented and nonmanifold_after <= nonmanifold and misoriented:
        # An export with faces flipped (STL normals ignored): its patches meet
        # misoriented once stitched, no worse when each can be turned to match its
        # neighbours without folding back onto them. Not so for consistent patches: two
        # shells facing the same way (a shell written twice, shifted) would be joined
        # back to back at their holes.
        misoriented_after = misoriented + _worse_oriented(v, f, original, gamma)
    if nonmanifold_after > nonmanifold or misoriented_after > misoriented or b1 >= b0:
        # Not a crack between consistent patches (crossing triangles of a soup, patches
        # facing the same way): stitching would make the surface worse; leave it.
        return original, Stitched(float(gamma), boundary_before=b0, boundary_after=b0,
                                  declined=True)  # fmt: skip
    moved = np.flatnonzero(became != np.arange(len(v)))
    return f, Stitched(float(gamma), snapped, inserted, b0, b1,
                       moved=np.column_stack([moved, became[moved]]))  # fmt: skip


def _worse_oriented(v: np.ndarray, f: np.ndarray, original: np.ndarray, gamma: float) -> int:
    """Whether ``f``, every patch oriented consistently where it can be
    (:func:`repair.thicken.orient_patches`), has more edges used twice the same way or
    more faces folded back onto each other (:func:`_folds`: a stitch joining two shells
    back to back) than the ``original`` faces so oriented (1 or 0)."""
    from repair.thicken import orient_patches

    now, before = orient_patches(f)[0], orient_patches(original)[0]
    return int(edge_topology(now).misoriented > edge_topology(before).misoriented
               or _folds(v, now, gamma) > _folds(v, before, gamma))  # fmt: skip


def _folds(v: np.ndarray, f: np.ndarray, gamma: float) -> int:
    """Edges of two faces whose unit normals are within ~8° of opposite: the faces lie
    back to back. Only faces wider than ``gamma`` mm (each corner's distance from the
    line of the opposite edge) count: the stitch moves vertices by up to γ, so the
    normal of a sliver narrower than that is noise (a CAD step's sliver between
    vertices 3e-5 mm apart, its copy moved by 1e-4 mm, faces any way)."""
    h1, h2, _ = paired_half_edges(edge_topology(f).eid)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    twice_area = np.linalg.norm(n, axis=1)
    n /= np.maximum(twice_area, 1e-300)[:, None]
    longest = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2).max(axis=1)
    wide = twice_area > gamma * longest
    back = np.einsum("ij,ij->i", n[h1 // 3], n[h2 // 3]) < -0.99
    return int(np.count_nonzero(back & wide[h1 // 3] & wide[h2 // 3]))
