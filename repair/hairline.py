"""Hairline gaps: places where a printable surface comes back within a hair of itself.

A mesh can pass the exact check and still hold faces whose two sides are not what a
solid's are: a slit thinner than a float32 ulp or two between two walls of one shell
(the winding number just outside such a wall is 1: the probe crosses the slit and lands
in the solid again), or a blade thinner than that (0 just inside). They come from the
input itself -- overlapping CAD shells whose faces nearly coincide, float32 points a hair
apart -- which the exact arrangement keeps as it finds them, and from rounding its result
to float32. A slicer should never see them.

:func:`hairline_suspects` finds, cheaply, the faces that another face comes nearer than
the probe distance of :func:`repair.junk.face_winding_sides` (on large meshes only those
near a fold, :func:`fold_suspects`); the winding number decides among them.
:func:`without_hairline_gaps` closes them, round by round, first by a cut
(:func:`cut_and_lid`: the failing faces and an edge ring or more round them cut out, each
hole lidded; the lid spans the slit's mouth or the blade's base, within the cut faces'
reach), else by the cheapest of: a zip (:mod:`repair.zip`: the walls' corners within
:data:`FILL_REACH` probe distances merged, faces left back to back dropped -- slits
whose walls have matching corners, blades, needles); a snap of one wall onto the other
and an exact local mend; and a fill (:func:`fill_hairline_gaps`: a prism of 2 probe
distances either side of each failing face, and thin cylinders along its creases, united
with the solid by manifold3d). Zip, snap and fill move nothing by more than those 2
probe distances (about 4 float32 ulps of the part's size); each result is rounded,
checked and kept only when it is printable and fewer faces fail.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from repair.hairline_cut import cut_and_lid, face_rings, local_cut_rounds
from repair.junk import WindingFromBase, face_winding_sides, failing_faces, probe_distance
from repair.probe_grid import faces_near_points, probes_near_faces, slivers_probed_clear
from repair.probe_grid import unit_normals as _unit_normals
from repair.report import RepairOutcome, RepairTally

__all__ = ["fill_hairline_gaps", "hairline_suspects", "hairline_failures",
           "without_hairline_gaps"]  # fmt: skip

#: How far the filling prisms reach either side of a failing face, in probe distances.
FILL_REACH = 2.0
#: Meshes with more faces are only zipped (:func:`repair.zip.zip_hairline`, a fraction
#: of a second a round): snapping and filling, each rounded and mended, took tens of
#: seconds on the corpus's 30k-90k-face outputs, more than the rest of their repair.
MAX_FACES = 20_000
#: Meshes with more faces are only cut and lidded, and searched for failing faces only
#: near folds (:func:`fold_suspects`): the whole search costs 2-15 s on the corpus's
#: 64k-90k-face outputs (the exact winding numbers near the surface).
MAX_ZIP_FACES = 40_000
#: Rounds of "find, fill, round and check" at most.
MAX_FILL_ROUNDS = 6
#: A fold: an edge whose two faces' unit normals have a dot product below this.
FOLD_DOT = -0.9
#: A fold is thin where the far corner of one of its faces lies within this many probe
#: distances of the other face's plane (mikedh_cycloidal's 47 failing faces lie within 2
#: edge rings of such folds: 408 of its 111k faces, where folds of any width reach 67 %).
FOLD_REACH = 4.0
#: Edge rings round a fold searched for failing faces on meshes of more than
#: :data:`MAX_ZIP_FACES` faces (counter's 24 failing faces lie within 2 rings of one).
FOLD_RINGS = 2
#: Large meshes with more of their faces near a thin fold are left as they are: the
#: search among them would cost seconds (mikedh_cycloidal: 0.6 % of 111k faces, where
#: folds of any width reach 67 %; counter: 0.2 %).
MAX_FOLD_FRACTION = 0.1
#: Edge rings round the failing faces cut out before lidding: 1, then up to this many
#: where fewer do not help.
MAX_CUT_RINGS = 3
#: Faces in a plane shared by at least this many are searched for hairline suspects
#: plane by plane (:func:`_near_in_planes`), the rest in a grid of cells (or libigl's
#: tree): on a CAD model's flat faces the boxes overlap (box: 0.083 s for the tree,
#: 0.019 s without them).
PLANE_FACES = 16
#: Up to this many (probe, plane) offset tests per direction, the probes are compared
#: with each plane of it rather than sorted along it (box: 10 directions, 87 planes).
PLANE_SLAB_TESTS = 1 << 22
#: Meshes of fewer faces are searched by the grid (or tree) alone: finding their planes costs more
#: than it saves (rabbit's 1.5k faces: 0.4 ms of a 7 ms search).
PLANE_MIN_MESH = 2048


def hairline_suspects(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray | None = None
) -> np.ndarray:
    """Faces (of ``which``, default all) with another face nearer than the probe
    distance ``d`` to a point ``d`` off their centroid (either side): the only faces whose
    winding sides can be wrong on a printable mesh of one nesting level; also every face
    too thin to be probed at ``d`` (its own probe is nearer). Faces of a plane shared by
    :data:`PLANE_FACES` or more (:func:`_shared_planes`) are searched plane by plane
    (:func:`_near_in_planes`); the others in a grid of cells
    (:func:`repair.probe_grid.probes_near_faces`), or where long faces crowd its cells
    by a libigl AABB distance query."""
    import igl

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    idx = np.arange(len(f)) if which is None else np.asarray(which, dtype=np.int64)
    if len(f) == 0 or len(idx) == 0:
        return np.zeros(0, dtype=np.int64)
    d = probe_distance(v)
    whole = 4 * len(idx) > len(f)  # else: a few faces, near which the tree is built
    p = v[f] if whole else v[f[idx]]
    n_all, length_all = _unit_normals(p)
    c = (p[:, 0] + p[:, 1] + p[:, 2]) / 3  # as p.mean(axis=1), bit for bit: 3x faster
    n, length = (n_all[idx], length_all[idx]) if whole else (n_all, length_all)
    if whole and which is not None:
        c = c[idx]
    q = np.vstack([c + d * n, c - d * n])
    owner = np.r_[idx, idx]
    m = len(idx)
    near = np.zeros(2 * m, dtype=bool)
    if whole:
        plane = (_shared_planes(v, f, n_all, length_all) if len(f) >= PLANE_MIN_MESH
                 else np.full(len(f), -1))  # fmt: skip
        near |= _near_in_planes(v, f, q, owner, plane, d)
        rest = np.flatnonzero(plane < 0)
    else:
        # Only faces whose box comes within 2 d of a probe can be nearer than d to it: for
        # a few faces of a large mesh, libigl's tree is built on those alone (its build on
        # all 88k of counter's faces is most of the query's cost), the same distances.
        rest = faces_near_points(v, f, q, 2 * d)
    if len(rest):
        by_grid = probes_near_faces(v, f, rest, q, c, n, idx, d)
        if by_grid is None:  # long faces crowd the cells: the tree is cheaper there
            sub = f if len(rest) == len(f) else np.ascontiguousarray(f[rest])
            sq, nearest, _ = igl.point_mesh_squared_distance(q, v, sub)
            by_grid = (rest[nearest] != owner) & (sq < (0.999 * d) ** 2)
        near |= by_grid
    return idx[near.reshape(2, m).any(axis=0) | (length == 0)]


def _shared_planes(v: np.ndarray, f: np.ndarray, n: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Per face, the plane it shares with at least :data:`PLANE_FACES - 1` other faces
    (0, 1, ...: unit normals ``n`` and offsets equal to 2^-20, of the part's size for the
    offset), or -1 (and for degenerate faces, ``length`` 0): a CAD model's flat faces,
    fans of long triangles whose boxes overlap those of many others (box's 10.2k of
    10.9k faces lie in 87 such planes). All -1 when such faces are under a quarter."""
    from repair.rows import unique_ints

    off = np.einsum("ij,ij->i", n, v[f[:, 0]]) / max(float(np.ptp(v, axis=0).max()), 1e-300)
    k = np.rint(np.c_[n, off] * 2.0**20).astype(np.int64) & 0xFFFFF  # 20 bits each
    key = ((k[:, 0] << 40) | (k[:, 1] << 20) | k[:, 2]) * np.int64(0x9E3779B1) ^ k[:, 3]
    _, inv, cnt = unique_ints(key, return_inverse=True, return_counts=True)
    big = (cnt >= PLANE_FACES).cumsum() - 1
    plane = np.where((cnt[inv] >= PLANE_FACES) & (length > 0), big[inv], -1)
    # A few flat faces among curved ones (chair, rabbit) do not pay for the plane search.
    return plane if 4 * np.count_nonzero(plane >= 0) >= len(f) else np.full(len(f), -1)


def _near_in_planes(
    v: np.ndarray, f: np.ndarray, q: np.ndarray, owner: np.ndarray, plane: np.ndarray,
    d: float,
) -> np.ndarray:
    """Which probes ``q`` (of the faces ``owner``) have a face of a shared plane
    (``plane``, :func:`_shared_planes`) other than their own nearer than ``0.999 d``: only
    a probe within that distance of the plane (grown by how far its faces' corners stray
    from it) can be, tested against the plane's faces, box then exact distance
    (:func:`repair.deviation.point_triangle_d2`)."""
    from repair.deviation import point_triangle_d2
    from repair.probe_grid import in_disjoint_slabs
    from repair.rows import ranges, unique_rows

    near = np.zeros(len(q), dtype=bool)
    gf = np.flatnonzero(plane >= 0)
    if len(gf) == 0:
        return near
    gf = gf[np.argsort(plane[gf], kind="stable")]
    starts = np.flatnonzero(np.r_[True, np.diff(plane[gf]) != 0])
    sizes = np.diff(np.r_[starts, len(gf)])
    p = v[f[gf]]
    a = p[starts, 0]
    nrm = np.cross(p[starts, 1] - a, p[starts, 2] - a)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    # Planes of one direction (a box's: 6) share one sort of the probes along it.
    _, first, way = unique_rows(np.rint(nrm * 2.0**20).astype(np.int64), return_index=True,
                                return_inverse=True)  # fmt: skip
    nrm = nrm[first][way]
    off = np.einsum("ij,ij->i", nrm, a)
    stray = np.abs(np.einsum("ikj,ij->ik", p, np.repeat(nrm, sizes, axis=0))
                   - np.repeat(off, sizes)[:, None]).max(axis=1)  # fmt: skip
    # Rounding of the dot products aside (a few ulps of the coordinates).
    reach = 0.999 * d + np.maximum.reduceat(stray, starts) + 2.0**-48 * float(np.abs(v).max())
    hits, groups = [], []
    for k in range(len(first)):
        g = np.flatnonzero(way == k)
        proj = q @ nrm[g[0]]
        lo, hi = off[g] - reach[g], off[g] + reach[g]
        apart = in_disjoint_slabs(proj, lo, hi)
        if apart is not None:  # one search per probe among the sorted slabs
            hits.append(apart[0])
            groups.append(g[apart[1]])
            continue
        if len(g) * len(q) <= PLANE_SLAB_TESTS:  # a few planes: each probe against each
            row, pi = np.nonzero((proj > lo[:, None]) & (proj < hi[:, None]))
            hits.append(pi)
            groups.append(g[row])
            continue
        order = np.argsort(proj)
        sp = proj[order]
        lo = np.searchsorted(sp, lo, side="right")
        hi = np.searchsorted(sp, hi, side="left")
        hits.append(order[ranges(lo, np.maximum(hi - lo, 0))])
        groups.append(np.repeat(g, np.maximum(hi - lo, 0)))
    pi, gi = np.concatenate(hits), np.concatenate(groups)
    pts = np.repeat(pi, sizes[gi])
    pos = ranges(starts[gi], sizes[gi])  # into gf
    keep = gf[pos] != owner[pts]
    pts, pos = pts[keep], pos[keep]
    # The faces' boxes, then the pairs' (a reduction over the corners of each pair's
    # triangle took a third of the search on box).
    lo = np.minimum(np.minimum(p[:, 0], p[:, 1]), p[:, 2])
    hi = np.maximum(np.maximum(p[:, 0], p[:, 1]), p[:, 2])
    keep = np.ones(len(pts), dtype=bool)
    for k in range(3):  # axis by axis, on ever fewer pairs
        pts, pos = pts[keep], pos[keep]
        x = q[pts, k]
        keep = (x >= lo[pos, k] - d) & (x <= hi[pos, k] + d)
    pts, tri = pts[keep], p[pos[keep]]
    d2 = point_triangle_d2(q[pts], tri[:, 0], tri[:, 1], tri[:, 2])
    near[pts[d2 < (0.999 * d) ** 2]] = True
    return near


def hairline_failures(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray | None = None,
    winding: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Faces (of ``which``, default all) that fail the two-sided winding test
    (:func:`repair.junk.failing_faces`), looked for among :func:`hairline_suspects`
    only; ``winding`` as in :func:`repair.junk.face_winding_sides`."""
    sus = hairline_suspects(vertices, faces, which)
    if len(sus):  # slivers next to a bent neighbour, mostly: probed closer, clear
        sus = sus[~slivers_probed_clear(vertices, faces, sus, probe_distance(vertices))]
    if len(sus) == 0:
        return sus
    outside, inside = face_winding_sides(vertices, faces, sus, winding=winding)
    return sus[failing_faces(outside, inside)]


def fold_suspects(vertices: np.ndarray, faces: np.ndarray, rings: int = FOLD_RINGS) -> np.ndarray:
    """Faces within ``rings`` edge rings of a thin fold -- an edge whose two faces face
    nearly opposite ways (unit normals' dot below :data:`FOLD_DOT`) and close up there
    (the far corner of one within :data:`FOLD_REACH` probe distances of the other's
    plane), as where a slit narrows to an edge or a blade's two sides meet -- or of a
    face lower than the probe distance (a flat-bottomed slit's floor, a needle). A cheap
    stand-in for :func:`hairline_suspects` on large meshes; it misses walls farther from
    such a place, and slits between two shells."""
    from repair.topology import edge_ids, paired_half_edges

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    d = probe_distance(v)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    longest = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2).max(axis=1)
    low = length[:, 0] < d * longest  # height under the probe distance
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    eid, counts = edge_ids(f)
    first, second, _ = paired_half_edges(eid)
    folded = np.einsum("ij,ij->i", n[first // 3], n[second // 3]) < FOLD_DOT
    first, second = first[folded], second[folded]
    a, b = first // 3, second // 3
    # Half-edge 3i + k runs from corner k to k + 1: the far corner is k + 2.
    far_a = v[f[a, (first % 3 + 2) % 3]] - p[b, 0]
    far_b = v[f[b, (second % 3 + 2) % 3]] - p[a, 0]
    gap = np.minimum(np.abs(np.einsum("ij,ij->i", far_a, n[b])),
                     np.abs(np.einsum("ij,ij->i", far_b, n[a])))  # fmt: skip
    thin = gap < FOLD_REACH * d
    seeds = np.r_[a[thin], b[thin], np.flatnonzero(low)]
    return face_rings(eid.reshape(-1, 3), len(counts), seeds, rings)


def _vertex_keys(v: np.ndarray) -> np.ndarray:
    """A 64-bit hash of each vertex's exact coordinates."""
    bits = np.ascontiguousarray(v, dtype=np.float64).view(np.int64)
    return (bits[:, 0] * np.int64(-7046029254386353131)) ^ (
        bits[:, 1] * np.int64(0x5851F42D4C957F2D)) ^ bits[:, 2]  # fmt: skip


def _face_keys(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    k = np.sort(_vertex_keys(v)[f], axis=1)
    return (k[:, 0] * np.int64(0x9E3779B97F4A7C15 - 2**64)) ^ (
        k[:, 1] * np.int64(0x5851F42D4C957F2D)) ^ k[:, 2]  # fmt: skip


def near_change(
    old: tuple[np.ndarray, np.ndarray], new: tuple[np.ndarray, np.ndarray], cut: np.ndarray
) -> np.ndarray:
    """Faces of ``new`` whose two winding sides a change from ``old`` can have changed:
    those near a new face (one not in ``old`` on the same corners) or near a face of
    ``old`` cut out (``cut``): the winding number changes only between the old surface and
    the new. A :class:`repair.face_grid.FaceGrid` query (its boxes are grown by more
    than twice the probe distance)."""
    from repair.face_grid import FaceGrid

    (v0, f0), (v1, f1) = old, new
    changed = np.flatnonzero(~np.isin(_face_keys(v1, f1), _face_keys(v0, f0)))
    both = np.vstack([f1, f0[cut] + len(v1)])
    asked = np.r_[changed, np.arange(len(f1), len(both))]
    near = FaceGrid(np.vstack([v1, v0]), both).near(asked)
    return near[near < len(f1)]


def fill_hairline_gaps(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The closed, oriented solid ``(vertices, faces)`` united with a prism of
    :data:`FILL_REACH` probe distances either side of each face ``which`` (manifold3d);
    None when manifold3d rejects a piece. Not yet rounded to float32."""
    from repair.thicken import face_prisms
    from repair.union import manifold_union

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    reach = FILL_REACH * probe_distance(v)
    pv, pf = face_prisms(v, f[np.asarray(which, dtype=np.int64)], 2.0 * reach)
    return manifold_union([(v, f), (pv, pf)], collapse=False)


def _closed_by(method: str, v: np.ndarray, f: np.ndarray, bad: np.ndarray):
    """``(v, f)`` with the hairline at the failing faces ``bad`` closed by ``method``
    (``zip``: corners within the fill's reach merged, back-to-back faces dropped;
    ``merge``: the same, walls triangulated differently left overlapping to be mended;
    ``snap``: one wall's corners moved onto the facing wall, then mended exactly;
    ``fill``: prisms united), not yet rounded; None when the method finds nothing."""
    from repair.mend import mend_intersections
    from repair.rounding import crossings_after_change
    from repair.zip import snap_onto_opposite, zip_hairline

    reach = FILL_REACH * probe_distance(v)
    if method in ("zip", "merge"):
        zipped = zip_hairline(v, f, bad, reach, guarded=method == "zip")
        return None if zipped is None else zipped[:2]
    if method == "snap":
        snapped = snap_onto_opposite(v, f, bad, reach)
        if snapped is None:
            return None
        sv, moved = snapped
        changed = moved[f].any(axis=1)
        pairs = crossings_after_change(sv, f, np.zeros((0, 2), dtype=np.int64), changed)
        try:
            mended = mend_intersections(sv, f, pairs)
        except (RuntimeError, ValueError, IndexError):
            return None
        return mended.vertices, mended.faces
    return fill_hairline_gaps(v, f, bad)


def _one_round(
    v: np.ndarray, f: np.ndarray, bad: np.ndarray, eps: float, tally: RepairTally
) -> tuple[str, tuple, np.ndarray] | None:
    """One round of closing: of zip, snap and fill, the one whose result is printable
    with the fewest failing faces, no more than before (a wedge's fill may only move the
    failure along it; ties go to the cheaper, earlier method):
    ``(method, (v, f, verdict), failing faces)``; None when none does."""
    from repair.finish import finish

    chosen = None
    no_pairs = np.zeros((0, 2), dtype=np.int64)
    for method in ("zip", "merge", "snap", "fill") if len(f) <= MAX_FACES else ("zip",):
        closed = _closed_by(method, v, f, bad)
        if closed is None:
            continue
        # (v, f) is printable on float32 points: only near what changed is tested again.
        tv, tf, verdict = finish(*closed, eps, tally, (v, f, no_pairs), local_only=True)
        if not verdict.ok:
            continue
        left = hairline_failures(tv, tf)
        if len(left) <= len(bad) and (chosen is None or len(left) < len(chosen[2])):
            chosen = method, (tv, tf, verdict), left
            if len(left) == 0:
                break
    return chosen


def _cut_round(
    v: np.ndarray, f: np.ndarray, bad: np.ndarray, eps: float, tally: RepairTally
) -> tuple[str, tuple, np.ndarray] | None:
    """One round of :func:`cut_and_lid` round the failing faces ``bad`` (1 edge ring,
    then more up to :data:`MAX_CUT_RINGS` while the result is not printable or fails no
    fewer faces), rounded and mended locally (:func:`repair.finish.finish`); the faces
    that then fail are looked for only near the change (:func:`near_change`).
    ``("cut", (v, f, verdict), failing faces)``, or None."""
    from repair.finish import finish

    no_pairs = np.zeros((0, 2), dtype=np.int64)
    for rings in range(1, MAX_CUT_RINGS + 1):
        lidded = cut_and_lid(v, f, bad, rings)
        if lidded is None:
            continue
        tv, tf, verdict = finish(*lidded[:2], eps, tally, (v, f, no_pairs), local_only=True)
        if not verdict.ok:
            continue
        left = hairline_failures(tv, tf, near_change((v, f), (tv, tf), lidded[2]))
        if len(left) < len(bad):
            return "cut", (tv, tf, verdict), left
    return None


def _close_rounds(out: RepairOutcome, bad: np.ndarray, eps: float) -> tuple[int, list[str]]:
    """Rounds of :func:`_cut_round`, else :func:`_one_round`, on ``out`` (updated in
    place to the round that left the fewest failing faces): ``(faces left, methods)``."""
    best = len(bad)
    used: list[str] = []
    v, f = out.vertices, out.faces
    # A slit that narrows to an edge (a wedge) closes from its narrow end: each round
    # closes what the last one left within a hair of the other wall, further along it.
    for _ in range(MAX_FILL_ROUNDS):
        if len(bad) == 0:
            break
        step = _cut_round(v, f, bad, eps, out.tally) or _one_round(v, f, bad, eps, out.tally)
        if step is None:
            break  # nothing closed any, or every try added failing faces: give up
        method, (v, f, verdict), bad = step
        used.append(method)
        if len(bad) < best:
            out.vertices, out.faces, out.verdict, best = v, f, verdict, len(bad)
    return best, used


def _cut_large(
    out: RepairOutcome, bad: np.ndarray, eps: float, base: WindingFromBase
) -> tuple[int, list[str]]:
    """Rounds of cuts checked near the cuts only (:func:`repair.hairline_cut.
    local_cut_rounds`; ``base``: the winding numbers of ``out``'s mesh), then the check
    of the round that left the fewest failing faces: ``out`` updated in place when that
    is printable (and ``out.sections["hairline_gaps"]["lid_deviation_mm"]``: how far the
    lids lie from the faces the cuts replaced, rounds summed). Where no two of its
    corners share a point, the rounds' local checks found every crossing pair (none)
    and the rest of the check runs on that; else it is welded and mended locally
    (:func:`repair.finish.finish`) and looked for failing faces again near folds.
    ``(faces left, methods)``."""
    from repair.check import verdict_given_pairs
    from repair.finish import finish
    from repair.topology import weld_exact

    v, f, left, rounds, reach = local_cut_rounds(
        out.vertices, out.faces, bad, MAX_FILL_ROUNDS, MAX_CUT_RINGS, base
    )
    if rounds == 0:
        return len(bad), []
    no_pairs = np.zeros((0, 2), dtype=np.int64)
    tv, tf = weld_exact(v, f)
    if len(tv) == len(v):
        verdict = verdict_given_pairs(tv, tf, no_pairs)[0]
    else:
        tv, tf, verdict = finish(v, f, eps, out.tally, (out.vertices, out.faces, no_pairs),
                                 local_only=True)  # fmt: skip
        if verdict.ok:
            left = len(hairline_failures(tv, tf, fold_suspects(tv, tf)))
    if not verdict.ok or left >= len(bad):
        return len(bad), []
    out.vertices, out.faces, out.verdict = tv, tf, verdict
    # D (output -> input) near the lids: within this of the surface the cuts replaced.
    out.sections["hairline_gaps"] = {"lid_deviation_mm": reach}
    return left, ["cut"] * rounds


def without_hairline_gaps(out: RepairOutcome, eps: float) -> RepairOutcome:
    """``out`` with its hairline slits, blades and needles closed, rounded to float32,
    checked and mended locally (:func:`repair.finish.finish`; a result that local mending
    cannot make printable is given up: the whole arrangement may take minutes). Each
    round first cuts the failing faces out and lids the holes (:func:`_cut_round`), taken
    when it leaves fewer failing faces; else it tries, in turn, a zip of the failing
    faces' corners that lie within :data:`FILL_REACH` probe distances of each other
    (:func:`repair.zip.zip_hairline`, without and with walls left overlapping for the mend),
    a snap of one wall onto the other and an exact mend
    (:func:`repair.zip.snap_onto_opposite`), and a fill with prisms
    (:func:`fill_hairline_gaps`); the one that leaves the mesh printable with the fewest
    faces failing the two-sided winding test (:func:`_one_round`) is taken; the round
    with the fewest is kept.
    Meshes of more than :data:`MAX_FACES` faces are only cut or zipped; of more than
    :data:`MAX_ZIP_FACES` searched near thin folds only, if those are not more than
    :data:`MAX_FOLD_FRACTION` of the faces, and only cut, in rounds checked near the cuts
    (:func:`_cut_large`: time).
    Counted in ``out.sections["hairline_gaps"]``."""
    if not out.verdict.ok or len(out.faces) == 0:
        return out
    large = len(out.faces) > MAX_ZIP_FACES
    which = fold_suspects(out.vertices, out.faces) if large else None
    if which is not None and len(which) > MAX_FOLD_FRACTION * len(out.faces):
        return out  # thin folds everywhere: the search would cost seconds
    if large:
        # The winding numbers of each round's mesh from those of this one (tree built once).
        base = WindingFromBase(out.vertices, out.faces)
        none = np.zeros(0, dtype=np.int64)
        bad = hairline_failures(out.vertices, out.faces, which,
                                lambda q: base.at(q, out.vertices, none.reshape(0, 3), none))
        best, used = _cut_large(out, bad, eps, base)
    else:
        bad = hairline_failures(out.vertices, out.faces)
        best, used = _close_rounds(out, bad, eps)
    found = len(bad)
    if found:
        out.sections["hairline_gaps"] = {
            "faces_found": found, "rounds": used, "faces_left": best,
            "reach_mm": float(FILL_REACH * probe_distance(out.vertices)),
            **out.sections.get("hairline_gaps", {}),
        }  # fmt: skip
    return out
