"""Shell closure (Bøhn & Wozny): which holes of a shell get lids.

An open scan or a sloppy export is often a closed shell with a few holes. Attene's
algorithm would treat the whole open shell as a zero-thickness sheet and thicken all of
it; a user expects the holes to be filled instead, after which the shell is solid and the
exact path keeps it exactly. Genuine open surfaces (an open-topped box, a fin, a single
sheet) are left alone. The boundary (lamina) edges are traced into loops (Jordan curves
once they are simple); a shell gets lids when every one of its holes is *small* (the
shell's boundary is a small fraction of its edges and the hole's perimeter small against
the shell's size) or *a missing piece of a planar facet* (the loop is planar and a rim
face lies in its plane, facing the same way) -- all of them, so it comes out closed
(lidding some holes of a shell that stays open would only add surface to a sheet).
Triangles dangling off an edge of such a shell next to its holes (flaps, as scanners
leave them: an open edge plus an edge of three or more faces) are removed, or the holes
beside them would not be simple loops.

Lids are made by :mod:`repair.closure` (planar loops: an exact planar triangulation on
the loop's own vertices; others a minimal-area one; very long loops a centroid fan),
oriented against the hole's rim faces, so a consistently oriented shell stays
consistently oriented. A scan's non-planar lids are then refined and faired
(:mod:`repair.fair`, Liepa's patches); planar ones, and every lid of a mesh not cleaned
as a scan (CAD: its holes stay minimal-area or exact planar lids), are kept as made.
Lids may cross the shell where a hole is strongly non-planar; the exact
self-intersection resolution that follows repairs such crossings.

Units are mm. Arrays: vertices float64 (n, 3), faces int64 (m, 3). Pure functions;
the edge bookkeeping is vectorised, the only Python loop runs once per boundary vertex
to trace loops and once per loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from repair.closure import Lid, loop_lid, loop_planarity
from repair.loops import boundary_loops, traced_loops
from repair.thicken import orient_patches
from repair.topology import EdgeTopology, edge_topology

__all__ = [
    "MAX_BOUNDARY_FRACTION",
    "MAX_LID_AREA_FRACTION",
    "MAX_LIDS_AREA_FRACTION",
    "MAX_MISSING_TRIANGLES",
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
#: A shell's holes are also "small" when a lid over each of them (a centroid fan: an
#: upper bound on the smallest lid) adds at most this fraction of the shell's area, and
#: lids over all of them at most :data:`MAX_LIDS_AREA_FRACTION`. A coarse CAD export has
#: few, long faces: one missing triangle is several percent of its edges and its
#: perimeter longer than the part's diagonal, yet its lid is a sliver of the surface.
#: An open-topped box's top is 20 % of it, a bowl's 50 %, a sheet's 100 %.
MAX_LID_AREA_FRACTION = 0.02
#: A hole's lid is a sliver when its area is at most this share of its perimeter squared
#: (an equilateral triangle's is 0.048): a CAD step's sliver face 3e-5 mm wide, a slit.
SLIVER_LID = 1e-3
#: See :data:`MAX_LID_AREA_FRACTION`: a shell pierced by many small holes (a perforated
#: lampshade) stays a sheet.
MAX_LIDS_AREA_FRACTION = 0.05
#: A shell whose holes are all one or two missing triangles (however large) is closed
#: when they are at most this fraction of its faces -- or when its one hole is a single
#: missing triangle (a loop of three edges, whose lid is that triangle), however few its
#: faces: a 16-triangle CAD step missing one is a solid, not a sheet to thicken.
MAX_MISSING_TRIANGLES = 0.03


@dataclass(frozen=True)
class HolesClosed:
    """What :func:`close_small_holes` did: ``count`` holes closed, ``area`` mm² of lid
    added, ``lid_triangles`` triangles added, ``max_perimeter`` mm of the largest hole
    closed and ``max_lid_radius`` mm, a bound on how far any lid point lies from its rim
    (hence from the input surface); ``flaps_removed`` faces (``flap_area`` mm²) dangling
    off the shell next to a hole were removed so the hole could be closed. ``lids``: each
    lid (perimeter, area, planarity), ``faired_lids`` of them refined and faired;
    ``exact_faces``: the triangles of the ``facet_lids``
    lids that complete a planar facet of their shell (on the input's vertices)."""

    count: int = 0
    area: float = 0.0
    lid_triangles: int = 0
    max_perimeter: float = 0.0
    max_lid_radius: float = 0.0
    flaps_removed: int = 0
    flap_area: float = 0.0
    facet_lids: int = 0
    faired_lids: int = 0
    lids: tuple[Lid, ...] = field(default=(), compare=False)
    exact_faces: np.ndarray = field(
        default_factory=lambda: np.zeros((0, 3), dtype=np.int64), compare=False
    )

    def faired_crossing(self, n_faces: int, pairs: np.ndarray) -> tuple[int, ...]:
        """The faired lids (numbered in lid order) with a face in one of the crossing
        face ``pairs`` (k, 2) of the mesh :func:`close_small_holes` returned, of
        ``n_faces`` faces: its last ``lid_triangles`` faces are the lids', in order."""
        if self.faired_lids == 0 or len(pairs) == 0:
            return ()
        owner = np.repeat(np.arange(len(self.lids)), [len(lid.triangles) for lid in self.lids])
        first = n_faces - len(owner)
        hit = np.asarray(pairs, dtype=np.int64).reshape(-1)
        hit = np.unique(owner[hit[hit >= first] - first])
        return tuple(i for i in hit.tolist() if self.lids[i].faired)

    def to_dict(self) -> dict[str, float | int]:
        return {
            "count": int(self.count),
            "area": round(float(self.area), 9),
            "lid_triangles": int(self.lid_triangles),
            "max_perimeter": float(self.max_perimeter),
            "max_lid_radius": float(self.max_lid_radius),
            "flaps_removed": int(self.flaps_removed),
            "flap_area": round(float(self.flap_area), 9),
            "planar_lids": sum(1 for lid in self.lids if lid.planar),
            # Lids completing a planar facet: the intended surface, D is measured with them.
            "facet_lids": int(self.facet_lids),
            # Non-planar lids of a scan refined and faired (repair.fair).
            "faired_lids": int(self.faired_lids),
            # The largest lids first; a scan may have hundreds.
            "lids": [lid.to_dict() for lid in sorted(self.lids, key=lambda x: -x.area)[:50]],
        }


def _shells(
    v: np.ndarray, f: np.ndarray, max_boundary_fraction: float, topology: EdgeTopology
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per face: edge-connected component and the use count of each of its 3 edges
    (m, 3); per component: "almost closed" flag and bounding-box diagonal (mm).
    ``topology``: that of ``f``."""
    eid, cnt, comp = topology.eid, topology.counts, topology.shells
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
    topology: EdgeTopology | None = None,
) -> np.ndarray:
    """Mask of the *flaps* of almost-closed shells: faces with an open edge and an edge
    shared by more than two faces (a triangle dangling off, or folded over, an edge of
    the shell, as scanners leave them), no larger than 4x the median face area.

    Such a flap keeps the hole next to it from being a simple loop; removing it lets the
    hole be closed. Flaps of shells that are not almost closed are not flagged (those
    are sheets, and sheets are thickened). ``topology``: that of ``faces``, if known.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=bool)
    topo = topology if topology is not None and topology.of(f) else edge_topology(f)
    comp, use, almost_closed, _ = _shells(v, f, max_boundary_fraction, topo)
    flap = (use == 1).any(axis=1) & (use > 2).any(axis=1) & almost_closed[comp]
    if not flap.any():
        return flap
    p = v[f]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return flap & (area <= 4.0 * np.median(area))


def close_small_holes(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    max_boundary_fraction: float = MAX_BOUNDARY_FRACTION,
    max_perimeter_fraction: float = MAX_PERIMETER_FRACTION,
    topology: EdgeTopology | None = None,
    fair: bool = False,
    flat: tuple[int, ...] = (),
) -> tuple[np.ndarray, np.ndarray, HolesClosed]:
    """Close the holes of shells that a lid makes solid (Bøhn & Wozny's shell closure).

    A hole (a simple loop of boundary edges) may be closed when it is

    - *small*: its shell (edge-connected component) has at most ``max_boundary_fraction``
      of its edges on the boundary and the loop's perimeter is at most
      ``max_perimeter_fraction`` of the shell's bounding-box diagonal (mm), or a lid
      over each of the shell's holes would add at most :data:`MAX_LID_AREA_FRACTION` of
      its area (all of them :data:`MAX_LIDS_AREA_FRACTION`); or
    - *a missing piece of a facet*: the loop is planar and a face of its rim lies in the
      lid's plane facing the same way (the lid continues that facet: a triangle missing
      from a face of a box, not the open top of a box, whose rim faces stand across it).

    A shell's holes are closed only when all of them may be, so the shell comes out
    closed; otherwise it is left as it is (a sheet, thickened later). Lids are made by
    :func:`repair.closure.loop_lid`. Flaps (:func:`flap_faces`) of almost-closed shells
    are removed first, and stay removed only when their shell had its holes closed.
    Vertices are kept (same indices; fan centres are appended); faces keep their order
    except that the flaps kept move after the others; lid faces are appended.
    ``topology``: the :func:`repair.topology.edge_topology` of ``faces``, if known.
    ``fair``: the non-planar lids are refined and faired (:func:`repair.fair.fair_lids`,
    a scan's holes), except those numbered (in lid order) in ``flat``: where a faired lid
    crosses a face (:meth:`HolesClosed.faired_crossing`), it keeps its minimal-area lid.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    topo = topology if topology is not None and topology.of(f) else edge_topology(f)
    if len(f) == 0 or topo.boundary == 0:
        return v, f, HolesClosed()  # no open edge: nothing to close
    rules = (max_boundary_fraction, max_perimeter_fraction, fair, flat)
    out = _closed(v, f, topo, *rules)
    if out[2].count or not topo.misoriented:
        return out
    # An export with faces flipped (STL normals ignored): no hole's rim traces into a
    # loop until each patch is oriented consistently; the shell is given back so
    # oriented only when it gets lids.
    oriented = orient_patches(f)[0]
    again = _closed(v, oriented, edge_topology(oriented), *rules)
    return again if again[2].count else out


def _closed(
    v: np.ndarray, f: np.ndarray, topo: EdgeTopology, max_boundary_fraction: float,
    max_perimeter_fraction: float, fair: bool, flat: tuple[int, ...],
) -> tuple[np.ndarray, np.ndarray, HolesClosed]:
    """:func:`close_small_holes` of a mesh with boundary edges (``topo``: that of ``f``)."""
    flaps = flap_faces(v, f, max_boundary_fraction=max_boundary_fraction, topology=topo)
    flap_f = f[flaps]
    f = f[~flaps]
    if len(flap_f):
        topo = edge_topology(f)
    loops, labels, rims = traced_loops(f, topo, singular=True)
    if not loops:
        return v, np.vstack([f, flap_f]), HolesClosed()
    comp, use, almost_closed, diag = _shells(v, f, max_boundary_fraction, topo)
    # Lids only where they close the shell: every boundary edge of it (and edge of an
    # odd number of faces, two solids' shared edge missing one) is on a closable hole.
    # Closing some holes of a shell that stays open would not make it solid (it is
    # still a sheet, and is thickened), the lids would only add surface.
    n_bnd = np.bincount(comp, weights=(use == 1).sum(axis=1), minlength=len(diag))
    n_bnd += _singular_rims(f, topo, loops, rims, labels, len(diag))
    perims = _perimeters(v, loops)
    small = almost_closed[labels] & (perims <= max_perimeter_fraction * diag[labels])
    # A lid can complete a facet of a shell of three faces or more (a tetrahedron missing
    # one); single triangles and pairs (a soup's) are not looked at.
    n_faces = np.bincount(comp, minlength=len(diag))
    facet = np.array([n_faces[c] >= 3 and _continues_facet(v, f[r], lp)
                      for lp, r, c in zip(loops, rims, labels.tolist(), strict=True)],
                     dtype=bool)  # fmt: skip
    ok = small | facet
    sizes = np.array([len(lp) for lp in loops], dtype=np.float64)
    if not ok.all():
        slivers, lid_area = _lids_are_slivers(v, f, comp, loops, labels)
        ok |= slivers[labels]
        thin = lid_area <= SLIVER_LID * perims**2
        ok |= _missing_triangles(sizes, labels, n_faces, thin)[labels]
    covered = np.bincount(labels[ok], weights=sizes[ok], minlength=len(diag))
    closable = (covered == n_bnd) & (n_bnd > 0)

    lids: list[Lid] = []
    lid_loops: list[np.ndarray] = []
    exact: list[np.ndarray] = []
    n_new = 0
    for loop, c, is_facet in zip(loops, labels.tolist(), facet.tolist(), strict=True):
        if not closable[c]:
            continue
        lid = loop_lid(v, loop, len(v) + n_new)
        n_new += len(lid.new_vertices)
        lids.append(lid)
        lid_loops.append(loop)
        if is_facet and lid.planar:
            exact.append(lid.triangles)
    if fair and lids:
        lids = _faired(v, f, lid_loops, lids, flat)
        n_new = sum(len(lid.new_vertices) for lid in lids)
    # A flap stays removed only when its shell had holes closed (the shell is a scan with
    # holes, its flaps scanner noise next to them); the others go back (fins are sheets).
    gone = np.zeros(len(flap_f), dtype=bool)
    if len(flap_f) and lids:
        lidded = np.zeros(len(v), dtype=bool)
        lidded[f[closable[comp]].reshape(-1)] = True
        gone = lidded[flap_f].any(axis=1)
    out_v, lid_f = _lid_faces(v, lids)
    out_f = np.vstack([f, flap_f[~gone], *lid_f])
    return out_v, out_f, _tally(v, flap_f[gone], lids, exact)


def _singular_rims(
    f: np.ndarray, topo: EdgeTopology, loops: list[np.ndarray], rims: list[np.ndarray],
    labels: np.ndarray, n: int,
) -> np.ndarray:
    """Per shell: how many edges of more than two faces its ``loops`` (rim faces
    ``rims``, of shells ``labels``) run along (:func:`repair.loops.rim_half_edges`)."""
    if topo.nonmanifold == 0:
        return np.zeros(n)
    at, _, nxt = _loop_steps(loops)
    r = np.concatenate(rims)
    # The rim half-edge of lid edge a->b runs b->a in its face: it starts at corner k.
    k = np.argmax(f[r] == at[nxt][:, None], axis=1)
    shared = topo.counts[topo.eid[3 * r + k]] > 2
    owner = np.repeat(labels, [len(x) for x in rims])
    return np.bincount(owner[shared], minlength=n).astype(np.float64)


def _lid_faces(v: np.ndarray, lids: list[Lid]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The vertices with every lid's new ones appended in lid order, and each lid's
    triangles numbered so (a lid numbers its new vertices from wherever it was made)."""
    n, at, faces = len(v), len(v), []
    for lid in lids:
        t = lid.triangles
        if len(lid.new_vertices):
            t = np.where(t >= n, t - t[t >= n].min() + at, t)
            at += len(lid.new_vertices)
        faces.append(t)
    out_v = np.vstack([v, *(lid.new_vertices for lid in lids)]) if at > n else v
    return out_v, faces


def _faired(v: np.ndarray, f: np.ndarray, loops: list[np.ndarray], lids: list[Lid],
            flat: tuple[int, ...]) -> list[Lid]:  # fmt: skip
    """``lids`` with the non-planar ones but those numbered in ``flat`` refined and faired
    (:func:`repair.fair.fair_lids` on the shell ``f``)."""
    from repair.fair import fair_lids

    which = [i for i, lid in enumerate(lids) if not lid.planar and i not in flat]
    if not which:
        return lids
    faired = fair_lids(v, f, [loops[i] for i in which], [lids[i] for i in which])
    out = list(lids)
    for i, lid in zip(which, faired, strict=True):
        out[i] = lid
    return out


def _loop_steps(loops: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All loops' vertices end to end (``at``), each loop's start in ``at``, and per
    position the position of the next vertex round its loop."""
    sizes = np.fromiter((len(lp) for lp in loops), dtype=np.int64, count=len(loops))
    at = np.concatenate(loops)
    start = np.cumsum(sizes) - sizes
    nxt = np.arange(1, len(at) + 1)
    nxt[start + sizes - 1] = start  # each loop's last vertex goes back to its first
    return at, start, nxt


def _perimeters(v: np.ndarray, loops: list[np.ndarray]) -> np.ndarray:
    """Length (mm) round each loop, all loops at once."""
    at, start, nxt = _loop_steps(loops)
    return np.add.reduceat(np.linalg.norm(v[at[nxt]] - v[at], axis=1), start)


def _lids_are_slivers(
    v: np.ndarray, f: np.ndarray, comp: np.ndarray, loops: list[np.ndarray], labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per shell: whether a centroid-fan lid over each of its holes (``loops``, of shells
    ``labels``) adds at most :data:`MAX_LID_AREA_FRACTION` of its area (mm²), and all of
    them at most :data:`MAX_LIDS_AREA_FRACTION` (shells of three faces or more); and the
    area of each loop's lid (mm²)."""
    n = int(comp.max()) + 1
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    shell_area = np.bincount(comp, weights=area, minlength=n)
    at, start, nxt = _loop_steps(loops)
    sizes = np.diff(np.append(start, len(at)))
    centre = np.repeat(np.add.reduceat(v[at], start) / sizes[:, None], sizes, axis=0)
    fan = 0.5 * np.linalg.norm(np.cross(v[at] - centre, v[at[nxt]] - centre), axis=1)
    lid = np.add.reduceat(fan, start)
    total = np.bincount(labels, weights=lid, minlength=n)
    largest = np.zeros(n)
    np.maximum.at(largest, labels, lid)
    return ((largest <= MAX_LID_AREA_FRACTION * shell_area)
            & (total <= MAX_LIDS_AREA_FRACTION * shell_area)
            & (np.bincount(comp, minlength=n) >= 3), lid)  # fmt: skip


def _missing_triangles(
    sizes: np.ndarray, labels: np.ndarray, n_faces: np.ndarray, thin: np.ndarray
) -> np.ndarray:
    """Per shell: whether its holes (loops of ``sizes`` edges, of shells ``labels``) are
    all one or two missing triangles (3 or 4 edges; a loop of k edges takes k - 2), at
    most :data:`MAX_MISSING_TRIANGLES` of its ``n_faces`` faces. Such a lid is the
    missing triangle itself (or one of two diagonals), whatever its size: a coarse CAD
    export missing a long face gets it back instead of being thickened into a hollow
    skin. A single missing triangle is closed whatever the shell's size (three faces or
    more: a lone triangle's own rim is no hole); an open-topped box (two missing, a loop
    of four) stays a sheet. A hole whose lid is a sliver (``thin``, per loop: a CAD
    step's sliver face dropped as a crack's cap) counts as none."""
    n = len(n_faces)
    loops = np.bincount(labels, minlength=n)
    few = np.bincount(labels, weights=sizes <= 4, minlength=n)
    missing = np.bincount(labels, weights=np.where(thin, 0, sizes - 2), minlength=n)
    one = (missing == 1) & (n_faces >= 3)
    return (loops > 0) & (few == loops) & ((missing <= MAX_MISSING_TRIANGLES * n_faces) | one)


def _continues_facet(v: np.ndarray, rim: np.ndarray, loop: np.ndarray) -> bool:
    """Whether the loop (lid order) is planar and a face of its ``rim`` (the faces on its
    edges) lies in the lid's plane facing the lid's way."""
    p = v[loop]
    _, normal, planar = loop_planarity(p)
    if not planar:
        return False
    # Rim faces: the faces holding the loop's edges (a rim half-edge runs against the lid).
    q = v[rim]
    n = np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
    length = np.linalg.norm(n, axis=1)
    facing = (n @ normal) >= (1.0 - 1e-9) * length
    on_plane = np.abs((q - p[0]) @ normal).max(axis=1) <= 1e-6 * max(np.abs(p).max(), 1.0)
    return bool(np.any(facing & on_plane & (length > 0)))


def _tally(v: np.ndarray, flaps: np.ndarray, lids: list[Lid], exact: list[np.ndarray]):
    p = v[flaps]
    flap_area = 0.5 * float(
        np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    )
    return HolesClosed(
        count=len(lids),
        area=float(sum(lid.area for lid in lids)),
        lid_triangles=int(sum(len(lid.triangles) for lid in lids)),
        max_perimeter=max((lid.perimeter for lid in lids), default=0.0),
        max_lid_radius=max((lid.radius for lid in lids), default=0.0),
        flaps_removed=len(flaps),
        flap_area=flap_area,
        facet_lids=len(exact),
        faired_lids=sum(1 for lid in lids if lid.faired),
        lids=tuple(lids),
        exact_faces=np.vstack(exact) if exact else np.zeros((0, 3), dtype=np.int64),
    )
