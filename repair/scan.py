"""Cleaning of scanned meshes (Centin & Signoroni's RameshCleaner, STAG 2015), before the
repair proper: a scan is dense and mostly right, with local damage that the exact repair
would otherwise keep exactly (spikes) or thicken (ragged open boundaries, specks).

Steps, in the paper's order (Sec. 4), each vectorised over the whole mesh per round:

1. collapse near-degenerate edges (Sec. 3.6): *zero* edges shorter than 0.1 x the mean
   edge length, *skinny* ones shorter than 0.25 x their local mean with an opposite angle
   under 10 degrees; an independent set per round (each the shortest candidate at both
   its ends) whose ends share exactly the neighbours an edge collapse allows (the link
   condition);
2. relax spiked vertices (Sec. 3.7, Eq. 2): a vertex whose largest dihedral angle exceeds
   ``a`` = 60 degrees moves by ``w * L(v)`` (uniform Laplacian, ``w`` rising from 0 at
   ``a`` to 1 at ``b`` = 120 degrees), 10 rounds;
3. remove unrelaxable spikes (Sec. 3.8): the faces round vertices still above ``b``;
4. clean ragged boundaries (Sec. 3.3): faces at a *bad* boundary vertex (in one face
   only -- an ear --, with more than two boundary edges, or on a boundary edge whose
   dihedral angle exceeds 120 degrees) go, up to 30 rounds;
5. remove small components (Sec. 3.2): edge-connected patches of area below
   ``SPECK_AREA * eps**2`` (what a nozzle of diameter eps cannot print), the largest kept.

Hole filling (Sec. 3.4) is the repair's shell closure (:mod:`repair.holes` with every
boundary allowed, lids from :mod:`repair.closure`: minimal-area patches), refined and
faired as the paper's are (Liepa 2003, :mod:`repair.fair`): a faired patch that would
cross a face keeps its minimal-area lid.

Units are mm. Arrays: vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from repair.scan_edges import ScanEdges, edge_topology_of
from repair.topology import EdgeTopology, connected_labels

__all__ = ["SPECK_AREA", "ScanCleaned", "clean_scan", "looks_like_scan", "scan_cleanup"]

#: Components of less area than this many eps² are specks (eps = the nozzle).
SPECK_AREA = 25.0
#: Dihedral angles (radians) of Eq. 2: relaxation starts above A and is full above B.
SPIKE_A, SPIKE_B = np.radians(20.0), np.radians(90.0)
#: A boundary edge sharper than this makes its vertices bad (Sec. 3.3).
BOUNDARY_DIHEDRAL = np.radians(120.0)
#: "Looks like a scan": at least this many faces, and this many boundary loops or small
#: components, and at most this fraction of sharp (> 60 degree) edges.
SCAN_MIN_FACES = 20_000
SCAN_MIN_PIECES = 8
SCAN_MAX_SHARP = 0.01
#: ...and at most this fraction of flat (coplanar, < 1e-4 rad) edges: a CAD or generated
#: tessellation (UV spheres, tori, cylinders, plates: planar quads cut in two) has many,
#: a measured surface with its noise has almost none.
SCAN_MAX_FLAT = 0.05


@dataclass(frozen=True)
class ScanCleaned:
    """What :func:`clean_scan` did (counts of items; areas mm²)."""

    why: str = ""
    collapsed_edges: int = 0
    relaxed_vertices: int = 0
    spike_faces_removed: int = 0
    boundary_faces_removed: int = 0
    components_removed: int = 0
    component_area_removed: float = 0.0
    #: The :class:`repair.topology.EdgeTopology` of the cleaned faces (not reported):
    #: the next stages need not sort their edges again.
    topology: EdgeTopology | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, float | int | str]:
        return {
            "why": self.why,
            "collapsed_edges": int(self.collapsed_edges),
            "relaxed_vertices": int(self.relaxed_vertices),
            "spike_faces_removed": int(self.spike_faces_removed),
            "boundary_faces_removed": int(self.boundary_faces_removed),
            "components_removed": int(self.components_removed),
            "component_area_removed": round(float(self.component_area_removed), 6),
        }


def _normals(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (zero for degenerate faces) and areas of the faces. Column by column:
    the products and sums of ``np.cross`` and ``np.linalg.norm``, in their order (the
    same bits), without their (m, 3, 3) gathers."""
    p0 = np.take(v, f[:, 0], axis=0)
    u, w = np.take(v, f[:, 1], axis=0) - p0, np.take(v, f[:, 2], axis=0) - p0
    n = np.empty_like(u)
    n[:, 0] = u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1]
    n[:, 1] = u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2]
    n[:, 2] = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
    length = np.sqrt(n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2])
    n /= np.maximum(length, 1e-300)[:, None]
    return n, 0.5 * length


def _dots(n: np.ndarray, e: ScanEdges) -> np.ndarray:
    """Cosine of the dihedral angle of each paired edge (``n``: the faces' unit normals),
    the same bits as :func:`_dihedrals` takes the arccos of."""
    # np.take: a row gather several times faster than fancy indexing, the same values.
    return np.einsum("ij,ij->i", np.take(n, e.h1 // 3, axis=0), np.take(n, e.h2 // 3, axis=0))


def _sharper(dot: np.ndarray, angle: float, below: bool = False) -> np.ndarray:
    """Mask of the dihedral angles ``arccos(dot)`` above ``angle`` (``below``: under it),
    exactly as that arccos says, taken only where ``dot`` is within 1e-9 of the
    threshold's cosine (elsewhere the cosine alone decides)."""
    c = np.cos(angle)
    out = dot > c + 1e-9 if below else dot < c - 1e-9
    near = np.flatnonzero(np.abs(dot - c) <= 1e-9)
    theta = np.arccos(np.clip(dot[near], -1.0, 1.0))
    out[near] = theta < angle if below else theta > angle
    return out


def _dihedrals(
    v: np.ndarray, f: np.ndarray, h1: np.ndarray, h2: np.ndarray, n: np.ndarray | None = None
) -> np.ndarray:
    """Angle between the normals of the faces of half-edges h1 and h2 (0 flat, pi folded);
    ``n``: the faces' unit normals, if known."""
    if n is not None or 2 * len(h1) > len(f):  # most faces: one normal each
        n = _normals(v, f)[0] if n is None else n
        n1, n2 = n[h1 // 3], n[h2 // 3]
    else:
        n1, _ = _normals(v, f[h1 // 3])
        n2, _ = _normals(v, f[h2 // 3])
    return np.arccos(np.clip(np.einsum("ij,ij->i", n1, n2), -1.0, 1.0))


def _vertex_max(n_vertices: int, ends: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Per vertex, the largest ``value`` of the edges (``ends`` (k, 2)) at it (0 if none)."""
    out = np.zeros(n_vertices)
    np.maximum.at(out, ends[:, 0], value)
    np.maximum.at(out, ends[:, 1], value)
    return out


def looks_like_scan(vertices: np.ndarray, faces: np.ndarray, eps: float) -> str:
    """Why the mesh looks like a scan, or "" when it does not: dense (at least
    ``SCAN_MIN_FACES`` faces), ragged (at least ``SCAN_MIN_PIECES`` boundary loops or
    specks), smooth (at most ``SCAN_MAX_SHARP`` of its edges sharper than 60 degrees,
    which CAD models with their crisp edges exceed) and noisy (at most ``SCAN_MAX_FLAT``
    of its edges exactly flat, which smooth CAD tessellations exceed)."""
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    if len(f) < SCAN_MIN_FACES:
        return ""
    e = ScanEdges.of(f)
    normals, area = _normals(v, f)
    return _scan_signs(f, e, eps, _dots(normals, e), area, e.components())


def _scan_signs(
    f: np.ndarray, e: ScanEdges, eps: float, dot: np.ndarray, area: np.ndarray, comp: np.ndarray
) -> str:
    """The signs of :func:`looks_like_scan`, from the paired edges' dihedral cosines
    ``dot`` and the faces' ``area`` and edge-connected component ``comp``."""
    paired = max(len(e.h1), 1)
    sharp = np.count_nonzero(_sharper(dot, np.radians(60.0))) / paired
    flat = np.count_nonzero(_sharper(dot, 1e-4, below=True)) / paired
    if sharp > SCAN_MAX_SHARP or flat > SCAN_MAX_FLAT:
        return ""
    specks = int(np.count_nonzero(np.bincount(comp, weights=area) < SPECK_AREA * eps**2))
    # Boundary loops: the connected pieces of the boundary edges.
    b = e.ends[np.bincount(e.eid, minlength=len(e.ends)) == 1]
    on, local = np.unique(b, return_inverse=True)
    loops = int(connected_labels(len(on), *local.reshape(-1, 2).T).max()) + 1 if len(b) else 0
    if max(loops, specks) < SCAN_MIN_PIECES:
        return ""
    return (
        f"looks like a scan: {len(f)} faces, {loops} boundary loops, {specks} specks, "
        f"{100 * sharp:.2f}% sharp edges"
    )


def _adjacency(n: int, ends: np.ndarray):
    """Sparse symmetric vertex adjacency (CSR) of the edges."""
    from scipy.sparse import coo_matrix

    rows, cols = ends.reshape(-1), ends[:, ::-1].reshape(-1)
    return coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()


def _collapse(
    v: np.ndarray, e: ScanEdges, area: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One round of near-degenerate edge collapses: an independent set of zero and skinny
    edges (each the shortest candidate at both its ends) passing the link condition, as
    the vertices kept ``a`` and those merged into them ``b``. ``area``: of each face
    (mm²)."""
    n = len(v)
    used = np.bincount(e.eid, minlength=len(e.ends)) > 0
    ends = e.ends
    length = np.where(used, _lengths(v, ends), np.inf)
    live = np.where(used, length, 0.0)
    vert_sum = np.bincount(ends.reshape(-1), weights=np.repeat(live, 2), minlength=n)
    vert_cnt = np.maximum(np.bincount(ends[used].reshape(-1), minlength=n), 1)
    local = 0.5 * (vert_sum[ends[:, 0]] / vert_cnt[ends[:, 0]]
                   + vert_sum[ends[:, 1]] / vert_cnt[ends[:, 1]])  # fmt: skip
    # Skinny: short against its neighbourhood with a small angle opposite it (the angle
    # looked at only in the faces of the short edges).
    short = length < 0.25 * local
    eid = e.eid.reshape(-1, 3)  # edge k runs corner k -> k+1
    at_short = np.flatnonzero(short[eid].any(axis=1))
    e_len = length[eid[at_short]]
    # Angle opposite edge k: sin = 2 area / (product of the other two sides).
    other = e_len[:, [1, 2, 0]] * e_len[:, [2, 0, 1]]
    small_angle = 2 * area[at_short, None] / np.maximum(other, 1e-300) < np.sin(np.radians(10.0))
    skinny = np.zeros(len(ends), dtype=bool)
    skinny[eid[at_short][small_angle]] = True
    mean = live.sum() / max(int(np.count_nonzero(used)), 1)
    c = np.flatnonzero((length < 0.1 * mean) | (short & skinny))
    none = np.zeros(0, dtype=np.int64)
    if len(c) == 0:
        return none, none
    best = np.full(n, np.inf)
    np.minimum.at(best, ends[c, 0], length[c])
    np.minimum.at(best, ends[c, 1], length[c])
    c = c[(best[ends[c, 0]] == length[c]) & (best[ends[c, 1]] == length[c])]
    # Link condition: the ends share exactly the vertices opposite the edge (1 or 2).
    a, b = ends[c, 0], ends[c, 1]
    at_ab = np.zeros(n, dtype=bool)
    at_ab[a], at_ab[b] = True, True
    adj = _adjacency(n, ends[at_ab[ends].any(axis=1)])  # the rows of a and b only
    common = np.asarray(adj[a].multiply(adj[b]).sum(axis=1)).ravel()
    ok = common == np.bincount(e.eid, minlength=len(ends))[c]
    a, b = a[ok], b[ok]
    hit = np.bincount(np.r_[a, b], minlength=n)  # ties of length: a vertex in two edges
    single = (hit[a] == 1) & (hit[b] == 1)
    return a[single], b[single]


def _lengths(v: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Length of each edge (the bits of ``np.linalg.norm(..., axis=1)``)."""
    d = np.take(v, ends[:, 0], axis=0) - np.take(v, ends[:, 1], axis=0)
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])


@dataclass
class _Surface:
    """The mesh being cleaned with what is kept up to date through the steps: its edges,
    the faces' unit normals and areas (re-taken only for the faces whose corners moved)."""

    v: np.ndarray
    f: np.ndarray
    e: ScanEdges
    normals: np.ndarray
    area: np.ndarray

    def keep(self, keep: np.ndarray) -> None:
        """Only the faces ``keep`` (bool per face) stay."""
        self.f, self.e = self.f[keep], self.e.subset(keep)
        self.normals, self.area = self.normals[keep], self.area[keep]

    def moved(self, vertices: np.ndarray) -> None:
        """The faces at ``vertices`` (bool per vertex) have new corners: new normals."""
        t = np.flatnonzero(vertices[self.f].any(axis=1))
        self.normals[t], self.area[t] = _normals(self.v, self.f[t])

    def merge(self, a: np.ndarray, b: np.ndarray) -> None:
        """Collapse the edges ``a[i] b[i]`` onto their midpoints (at ``a``)."""
        n = len(self.v)
        self.v = self.v.copy()
        self.v[a] = 0.5 * (self.v[a] + self.v[b])
        remap = np.arange(n)
        remap[b] = a
        f = remap[self.f]
        keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
        self.e = self.e.collapsed(n, remap, keep)
        self.f, self.normals, self.area = f[keep], self.normals[keep], self.area[keep]
        at_a = np.zeros(n, dtype=bool)
        at_a[a] = True
        self.moved(at_a)


def _vertex_theta(n: int, f: np.ndarray, e: ScanEdges, faces: np.ndarray, pairs: np.ndarray,
                  angle: np.ndarray) -> np.ndarray:
    """θ(v): the largest dihedral angle of the edges of the faces round each vertex (its
    star and its link: a tall spike's sharpest edges are round its base), from the
    ``angle`` of the paired edges ``pairs`` (indices into ``e.h1``), over ``faces``."""
    edge_angle = np.zeros(len(e.ends))
    edge_angle[e.eid[e.h1[pairs]]] = angle
    face_theta = edge_angle[e.eid.reshape(-1, 3)[faces]].max(axis=1)
    out = np.zeros(n)
    np.maximum.at(out, f[faces].reshape(-1), np.repeat(face_theta, 3))
    return out


def _relax_spikes(v: np.ndarray, f: np.ndarray, e: ScanEdges, dot: np.ndarray, rounds: int = 20):
    """Eq. 2 on the spiked vertices, ``rounds`` times, the sharpest first: each round moves
    the spiked vertices whose umbrella vector (relative to their mean edge length) is the
    largest among their neighbours, so a spike's tip goes down before its base rises.
    ``dot``: the paired edges' dihedral cosines. Only the faces round the first spiked
    vertices are looked at again. Returns the new vertices, the mask of those moved and
    the mask of those still spiked above ``SPIKE_B``."""
    n = len(v)
    # θ(v) > A: a face round v has an edge sharper than A.
    sharp_edge = np.zeros(len(e.ends), dtype=bool)
    sharp_edge[e.eid[e.h1[_sharper(dot, SPIKE_A)]]] = True
    near = np.zeros(n, dtype=bool)
    near[f[sharp_edge[e.eid.reshape(-1, 3)].any(axis=1)].reshape(-1)] = True
    if not near.any():
        return v, near, near
    local_e = e.ends[near[e.ends].any(axis=1)]
    adj = _adjacency(n, local_e)  # complete rows for the vertices near a spike
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1)
    local_f = near[f].any(axis=1)
    pairs = np.flatnonzero(local_f[e.h1 // 3] | local_f[e.h2 // 3])
    local_f = np.flatnonzero(local_f)
    edge_len = _lengths(v, local_e)
    mean_len = np.bincount(local_e.reshape(-1), weights=np.repeat(edge_len, 2), minlength=n)
    mean_len = np.maximum(mean_len / deg, 1e-300)
    moved = np.zeros(n, dtype=bool)
    v = v.copy()
    for _ in range(rounds):
        angle = _dihedrals(v, f, e.h1[pairs], e.h2[pairs])
        theta = _vertex_theta(n, f, e, local_f, pairs, angle)
        w = np.clip((theta - SPIKE_A) / (SPIKE_B - SPIKE_A), 0.0, 1.0)
        s = np.flatnonzero(w > 0)
        if len(s) == 0:
            break
        lap = adj[s] @ v / deg[s][:, None] - v[s]
        size = np.zeros(n)
        size[s] = np.linalg.norm(lap, axis=1) / mean_len[s]
        top = _vertex_max(n, local_e, size[local_e].max(axis=1))
        first = size[s] >= top[s]
        v[s[first]] += w[s[first]][:, None] * lap[first]
        moved[s[first]] = True
    angle = _dihedrals(v, f, e.h1[pairs], e.h2[pairs])
    theta = _vertex_theta(n, f, e, local_f, pairs, angle)
    return v, moved, theta > SPIKE_B


def _clean_boundaries(
    f: np.ndarray, e: ScanEdges, sharp_vertex: np.ndarray, rounds: int = 30
) -> tuple[np.ndarray, int]:
    """Sec. 3.3: the faces to keep (bool) once those at bad boundary vertices are
    dropped, round after round until none is left, and how many went. Faces are only
    removed, so the edge ids stay valid: counts are re-taken per round (no sort)."""
    n = len(sharp_vertex)
    alive = np.ones(len(f), dtype=bool)
    use = np.bincount(e.eid, minlength=len(e.ends))  # kept up to date as faces go
    face_count = np.bincount(f.reshape(-1), minlength=n)
    for _ in range(rounds):
        bnd = use == 1
        if not bnd.any():
            break
        b_count = np.bincount(e.ends[bnd].reshape(-1), minlength=n)
        bad = (b_count > 0) & ((face_count == 1) | (b_count > 2) | sharp_vertex)
        drop = np.flatnonzero(alive & bad[f].any(axis=1))
        if len(drop) == 0:
            break
        alive[drop] = False
        use -= np.bincount(e.eid.reshape(-1, 3)[drop].reshape(-1), minlength=len(use))
        face_count -= np.bincount(f[drop].reshape(-1), minlength=n)
    return alive, int(np.count_nonzero(~alive))


def _specks(
    e: ScanEdges, area: np.ndarray, eps: float, comp: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Sec. 3.2: mask of the faces (of ``area`` mm² each) of components under
    ``SPECK_AREA * eps**2`` mm² (the largest component always stays), and their area.
    ``comp``: the faces' edge-connected components, if known."""
    if len(area) == 0:
        return np.zeros(0, dtype=bool), 0.0
    comp = e.components() if comp is None else comp
    comp_area = np.bincount(comp, weights=area)
    speck = comp_area < SPECK_AREA * eps**2
    speck[np.argmax(comp_area)] = False
    return speck[comp], float(comp_area[speck].sum())


def clean_scan(
    vertices: np.ndarray, faces: np.ndarray, eps: float, why: str = "asked"
) -> tuple[np.ndarray, np.ndarray, ScanCleaned]:
    """RameshCleaner's steps 1-5 (see the module doc) on a welded mesh; ``why`` is said in
    the report (asked for, or why the mesh looked like a scan). Returns new vertices
    (some moved: relaxed spikes, collapsed edges), faces (a subset, re-indexed onto kept
    vertex indices) and what was done."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    return _clean(v, f, ScanEdges.of(f), eps, why)


def scan_cleanup(
    vertices: np.ndarray, faces: np.ndarray, eps: float, mode: str,
    topology: EdgeTopology | None = None,
) -> tuple[np.ndarray, np.ndarray, ScanCleaned | None]:
    """The mesh cleaned as a scan when ``mode`` is "scan", or is "auto" and it looks like
    one (:func:`looks_like_scan`); else as it was, and None. ``topology``: the
    :func:`repair.topology.edge_topology` of ``faces``, if known."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if mode == "none" or len(f) == 0 or (mode == "auto" and len(f) < SCAN_MIN_FACES):
        return v, f, None
    e = ScanEdges.of(f, topology)
    normals, area = _normals(v, f)
    comp = topology.shells if topology is not None and topology.of(f) else e.components()
    if mode == "scan":
        why = "asked (clean = scan)"
    else:
        why = _scan_signs(f, e, eps, _dots(normals, e), area, comp)
    if not why:
        return v, f, None
    return _clean(v, f, e, eps, why, normals, area, comp)


def _clean(
    v: np.ndarray, f: np.ndarray, e: ScanEdges, eps: float, why: str,
    normals: np.ndarray | None = None, area: np.ndarray | None = None,
    comp: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, ScanCleaned]:
    if len(f) == 0:
        return v, f, ScanCleaned(why)
    if normals is None or area is None:
        normals, area = _normals(v, f)
    s = _Surface(v, f, e, normals, area)
    speck, speck_area = _specks(e, area, eps, comp)
    s.keep(~speck)
    a, b = _collapse(s.v, s.e, s.area)
    if len(a):
        s.merge(a, b)
    s.v, moved, spiked = _relax_spikes(s.v, s.f, s.e, _dots(s.normals, s.e))
    s.moved(moved)
    # Sec. 3.8: what relaxing could not flatten goes (its hole is filled later).
    spike = spiked[s.f].any(axis=1)
    s.keep(~spike)
    sharp = np.zeros(len(s.v), dtype=bool)
    sharp[s.e.ends[s.e.eid[s.e.h1[_sharper(_dots(s.normals, s.e), BOUNDARY_DIHEDRAL)]]]] = True
    alive, boundary_removed = _clean_boundaries(s.f, s.e, sharp)
    s.keep(alive)
    comp = s.e.components()
    more, more_area = _specks(s.e, s.area, eps, comp)
    f = s.f[~more]
    return s.v, f, ScanCleaned(
        why, len(a), int(np.count_nonzero(moved)), int(np.count_nonzero(spike)),
        boundary_removed, int(np.count_nonzero(speck)) + int(np.count_nonzero(more)),
        speck_area + more_area, edge_topology_of(f, s.e.subset(~more), comp[~more]),
    )
