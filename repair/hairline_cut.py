"""Cutting hairline slits and blades out of a printable mesh and lidding the holes, and,
on large meshes, doing so round by round near the cuts only.

:func:`cut_and_lid` cuts the failing faces (:func:`repair.hairline.hairline_failures`)
and an edge ring or more round them out and lids each hole
(:func:`repair.closure.loop_lid`); a lid that lands back to back on another face (the
two walls of a slit lidded across the same corners) cancels with it. Only the faces
round the cut are looked at: the holes' loops are traced among the faces that share a
corner with a cut face.

:func:`local_cut_rounds` repeats that on a large mesh without rounding, checking and
mending all of it each round: the lidded mesh is on float32 points but for a lid's fan
centre (rounded), and it is taken when the lids are not degenerate, each of their edges
has exactly one opposite partner, and no lid face meets another face (CGAL's exact test
against the faces near the cuts only); the faces failing the two-sided winding test
are then looked for only where the cuts changed the winding number. The caller runs the
whole check (:func:`repair.finish.finish`) once, on the last mesh.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.junk import WindingFromBase

__all__ = ["CutMesh", "cut_and_lid", "local_cut_rounds"]


def face_rings(eid: np.ndarray, n_edges: int, which: np.ndarray, rings: int) -> np.ndarray:
    """Sorted faces within ``rings`` edge rings of the faces ``which`` (included);
    ``eid``: the edge id of each face's 3 edges (m, 3)."""
    sel = np.unique(np.asarray(which, dtype=np.int64))
    for _ in range(rings):
        hit = np.zeros(n_edges, dtype=bool)
        hit[eid[sel].reshape(-1)] = True
        sel = np.flatnonzero(hit[eid].any(axis=1))
    return sel


@dataclass(frozen=True)
class CutMesh:
    """A lidded mesh: ``vertices``, ``faces`` (the kept faces in their order, then the
    lids), ``kept`` and ``cut`` (indices of the input's faces kept, and cut out or
    cancelled by a lid), ``new`` (indices into ``faces`` of the lid faces) and ``radius``
    (mm): every lid point lies within it of its hole's rim (:class:`repair.closure.Lid`)."""

    vertices: np.ndarray
    faces: np.ndarray
    kept: np.ndarray
    cut: np.ndarray
    new: np.ndarray
    radius: float


def cut_and_lid(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray, rings: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The closed, oriented ``(vertices, faces)`` with the faces ``which`` and ``rings``
    edge rings round them cut out, and each hole this leaves lidded
    (:func:`repair.closure.loop_lid`: a slit's or blade's two walls give way to one
    surface across its mouth or base); lids back to back with a face cancel with it.
    Returns ``(vertices, faces, cut)`` (``cut``: the indices of the faces cut out), not
    yet rounded; None when a hole is not a simple loop."""
    from repair.topology import edge_ids

    f = np.asarray(faces, dtype=np.int64)
    eid, counts = edge_ids(f)
    lidded = _cut_and_lid(vertices, f, eid.reshape(-1, 3), len(counts), which, rings)
    if lidded is None:
        return None
    return lidded.vertices, lidded.faces, lidded.cut


def _cut_and_lid(
    vertices: np.ndarray, f: np.ndarray, eid: np.ndarray, n_edges: int, which: np.ndarray,
    rings: int,
) -> CutMesh | None:
    """:func:`cut_and_lid` given the edge ids ``eid`` (m, 3) of the closed 2-manifold
    ``f``."""
    from repair.clean import cancel_opposite_faces
    from repair.closure import loop_lid
    from repair.loops import boundary_loops

    v = np.asarray(vertices, dtype=np.float64)
    cut = face_rings(eid, n_edges, which, rings)
    keep = np.ones(len(f), dtype=bool)
    keep[cut] = False
    on_cut = np.zeros(len(v), dtype=bool)
    on_cut[f[cut].reshape(-1)] = True
    # The kept faces with a corner on the cut hold every face round each hole's corners
    # (what tracing a loop through a pinch corner turns through); their outer boundary
    # has no corner on the cut. Same faces in the same order: the loops of all kept faces.
    star = np.flatnonzero(keep & on_cut[f].any(axis=1))
    loops = [lp for lp in boundary_loops(f[star])[0] if on_cut[lp].all()]
    open_edges = int(np.count_nonzero(np.bincount(eid[cut].reshape(-1)) == 1))
    if len(loops) == 0 or sum(len(loop) for loop in loops) != open_edges:
        return None  # some hole is no simple loop: the lids would not close the shell
    new_v, lids = [v], []
    n, radius = len(v), 0.0
    for loop in loops:
        lid = loop_lid(v, loop, n)  # only a fan adds a vertex (its centre): index n
        lids.append(lid.triangles)
        new_v.append(lid.new_vertices)
        n += len(lid.new_vertices)
        radius = max(radius, lid.radius)
    lid_f = np.vstack(lids)
    # Only a kept face on the holes' corners can be a lid's back-to-back twin.
    on_loop = np.zeros(n, dtype=bool)
    on_loop[np.concatenate(loops)] = True
    twins = star[on_loop[f[star]].all(axis=1)]
    both = np.vstack([f[twins], lid_f])
    stays = np.zeros(len(both), dtype=bool)
    stays[cancel_opposite_faces(both)] = True
    keep[twins[~stays[: len(twins)]]] = False
    lid_f = lid_f[stays[len(twins) :]]
    kept = np.flatnonzero(keep)
    out_f = np.vstack([f[kept], lid_f])
    gone = np.flatnonzero(~keep)
    new = np.arange(len(kept), len(out_f))
    return CutMesh(np.vstack(new_v), out_f, kept, gone, new, radius)


def local_cut_rounds(
    vertices: np.ndarray, faces: np.ndarray, bad: np.ndarray, rounds: int, max_rings: int,
    base: WindingFromBase,
) -> tuple[np.ndarray, np.ndarray, int, int, float]:
    """Up to ``rounds`` rounds of :func:`cut_and_lid` round the failing faces ``bad`` of
    the printable, float32-valued ``(vertices, faces)`` (1 edge ring, then more up to
    ``max_rings`` while the lids are not sound or fail no fewer faces; after a round
    that left more than half of its failing faces, the next starts one ring wider),
    each checked near its cuts only (module docstring; ``base``: the winding numbers of
    ``(vertices, faces)``, from which each round's are taken). Returns the mesh of the
    round that left the fewest failing faces (the input when none left fewer), how many
    it left, the rounds taken to it and how far its surface lies from the input's where
    the rounds changed it (mm; each round's lids from the faces they replace, summed):
    ``(vertices, faces, left, rounds, reach)``. Not checked as a whole."""
    v, f = vertices, faces
    origin = np.arange(len(f))  # each face's index in ``faces``, or -1 (a lid)
    best = (v, f, len(bad), 0, 0.0)
    first, radius = 1, 0.0
    for k in range(rounds):
        if len(bad) == 0:
            break
        step = _local_round(v, f, origin, bad, first, max_rings, base)
        if step is None:
            break  # nothing closed any: give up
        v, f, origin, left, rings, reach = step
        radius += reach
        # Wedges whose thin end a cut only moves along: cut wider at once next time.
        first = min(rings + 1, max_rings) if 2 * len(left) > len(bad) else rings
        bad = left
        if len(bad) < best[2]:
            best = (v, f, len(bad), k + 1, radius)
    return best


def _local_round(
    v: np.ndarray, f: np.ndarray, origin: np.ndarray, bad: np.ndarray, first: int,
    max_rings: int, base: WindingFromBase,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, float] | None:
    """One round of :func:`local_cut_rounds` from ``first`` edge rings on (``origin``:
    each face's index in ``base``'s mesh, or -1): ``(vertices, faces, origin, failing
    faces, rings, how far the lids lie from the faces they replace in mm)``, or None
    when no ring count leaves a sound mesh with fewer failing faces."""
    from repair.check import round_to_float32
    from repair.deviation import max_deviation
    from repair.hairline import hairline_failures
    from repair.junk import probe_distance
    from repair.topology import edge_ids

    eid, counts = edge_ids(f)
    for rings in range(first, max_rings + 1):
        lidded = _cut_and_lid(v, f, eid.reshape(-1, 3), len(counts), bad, rings)
        if lidded is None:
            continue
        # Kept corners are float32 already: only a fan's centre moves.
        cv, cf, new = round_to_float32(lidded.vertices), lidded.faces, lidded.new
        lo, hi = _cut_boxes(v, f, lidded.cut)
        # The winding number changes only between the old surface and the new, within
        # these boxes: grown by twice the probe distance, they hold every face with a
        # probe there (and every face a lid can meet).
        pad = 2.0 * probe_distance(cv)
        near = _faces_meeting(cv, cf, lo - pad, hi + pad)
        if not _lids_sound(cv, cf, new, near):
            continue
        now = np.r_[origin[lidded.kept], np.full(len(new), -1)]
        gone = np.ones(len(base.f0), dtype=bool)
        gone[now[now >= 0]] = False
        added, removed = cf[now < 0], np.flatnonzero(gone)
        left = hairline_failures(cv, cf, near, lambda q: base.at(q, cv, added, removed))  # noqa: B023
        if len(left) < len(bad):
            # How far the lids lie from the surface they replace (Attene's D, sampled).
            reach = max_deviation(*_compact(cv, cf[new]), *_compact(v, f[lidded.cut]))
            return cv, cf, now, left, rings, reach
    return None


def _compact(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices ``f`` uses and ``f`` re-indexed into them (same points)."""
    used, inverse = np.unique(f.reshape(-1), return_inverse=True)
    return v[used], inverse.reshape(-1, 3)


def _cut_boxes(v: np.ndarray, f: np.ndarray, cut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bounding boxes ``(lo, hi)`` (k, 3) of the corner-connected groups of the
    faces ``cut``: each holds its group's lids too (a lid spans its loop's corners)."""
    from repair.topology import connected_labels

    used, corner = np.unique(f[cut].reshape(-1), return_inverse=True)
    c = corner.reshape(-1, 3)
    label = connected_labels(len(used), np.r_[c[:, 0], c[:, 1]], np.r_[c[:, 1], c[:, 2]])
    k = int(label.max()) + 1
    p = v[used]
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    np.minimum.at(lo, label, p)
    np.maximum.at(hi, label, p)
    return lo, hi


def _faces_meeting(v: np.ndarray, f: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sorted faces whose bounding box meets one of the boxes ``lo .. hi`` (k, 3). Per
    axis, whether some box overlaps the face's extent (the boxes sorted by their low
    end: the highest high end among those starting below the face's top); the faces that
    pass on every axis are then tested box by box."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    flo = np.minimum(np.minimum(a, b), c)
    fhi = np.maximum(np.maximum(a, b), c)
    cand = np.arange(len(f))
    for k in range(3):
        order = np.argsort(lo[:, k])
        top = np.maximum.accumulate(hi[order, k])
        i = np.searchsorted(lo[order, k], fhi[cand, k], side="right") - 1
        cand = cand[(i >= 0) & (top[np.maximum(i, 0)] >= flo[cand, k])]
    meet = (flo[cand, None] <= hi[None]) & (fhi[cand, None] >= lo[None])
    return cand[meet.all(axis=2).any(axis=1)]


def _lids_sound(v: np.ndarray, f: np.ndarray, new: np.ndarray, near: np.ndarray) -> bool:
    """Whether the lid faces ``new`` leave the mesh printable where the rest was: none
    degenerate (exactly), each of their edges used by exactly two faces running it
    opposite ways, and none meeting another face (CGAL's exact test against the faces
    ``near``, which hold every face that can)."""
    from repair.check import degenerate_face_mask
    from repair.intersections import intersecting_pairs_with
    from repair.topology import edge_ids, half_edges

    if len(new) == 0:
        return True
    if degenerate_face_mask(v, f[new]).any():
        return False
    on_new = np.zeros(len(v), dtype=bool)
    on_new[f[new].reshape(-1)] = True
    around = np.flatnonzero(on_new[f].any(axis=1))  # every face on a lid's edge
    is_new = np.isin(around, new)
    eid, counts = edge_ids(f[around])
    lid_edges = eid.reshape(-1, 3)[is_new].reshape(-1)
    if np.any(counts[lid_edges] != 2):
        return False
    he = half_edges(f[around])
    key = he[:, 0] * np.int64(len(v)) + he[:, 1]
    if len(np.unique(key)) != len(key):
        return False  # two faces run an edge the same way
    others = np.setdiff1d(near, new)
    return len(intersecting_pairs_with(v, f, new, others)) == 0
