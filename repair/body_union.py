"""The closed bodies of a model united by manifold3d before the exact arrangement.

Where many closed, consistently oriented bodies of positive volume cross one another
(a gear exported as a hundred overlapping solids: tens of thousands of crossing face
pairs), their outer hull is the boundary of their union, less the cavities they
enclose. manifold3d computes that union from the exact input coordinates, robustly,
keeping each input triangle (cut where bodies cross) and saying which it is a piece of
-- at a small fraction of the cost of CGAL's exact arrangement of every crossing.

Only what the union cannot take is left to the arrangement (:mod:`repair.hull`): open or
non-manifold shells, and closed shells that cross themselves (manifold3d does not
resolve a solid's own crossings). They are handed over with the union's surface,
whose crossings with them are few. The outer hull of the whole then drops the union's
cavities and whatever of the rest lies inside, as for any input.

Bodies that touch along a plane rarely touch exactly: their points, rounded to float32
on export, stand a few ulps off it on either side, and the union keeps the gaps as
slits a few ulps wide between their walls (a slicer's probe a hair off such a wall lands
in the solid again). Before the union, each coordinate of the bodies' points a few
ulps from a more common value of the same axis (and within :data:`SNAP_REACH` probe
distances of it) is snapped to it (:func:`snapped_coordinates`): walls on a common
plane of constant x, y or z become coplanar, which manifold3d fuses (mikedh_cycloidal:
faces failing the two-sided winding test of the output 382 -> 47, D unchanged).

Units are mm; vertices float64 (n, 3) (float32 values), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.clean import drop_unreferenced
from repair.junk import probe_distance
from repair.meshes import concat_meshes
from repair.rounding import crossings_after_change, pairs_after_weld, round_finding_crossings
from repair.topology import weld_exact
from repair.union import _arrays_of, _manifolds_of, _sum_of

__all__ = ["MIN_BODY_PAIRS", "SNAP_REACH", "BodyUnion", "snapped_coordinates",
           "unite_closed_bodies"]  # fmt: skip

#: Unite the bodies first only when at least this many face pairs cross between two
#: of them: below it CGAL's arrangement of the crossings is quick, and exact.
MIN_BODY_PAIRS = 2000
#: How far (in probe distances of :func:`repair.junk.probe_distance`, about 2 float32
#: ulps of the part's size each) a coordinate of a body's point is snapped to a more
#: common value of its axis before the union.
SNAP_REACH = 8.0
#: Coordinate values at most this many float32 ulps apart are one plane's noise.
SNAP_ULPS = 2


@dataclass(frozen=True)
class BodyUnion:
    """The union of the closed bodies followed by the input's other faces: ``vertices``,
    ``faces``, ``birth`` (the input face each is a piece of) and ``pairs``, all their
    crossing face pairs. ``bodies``: how many bodies were united; ``dropped``: input
    faces of which no piece is left (inside other bodies, or a body's own inside)."""

    vertices: np.ndarray
    faces: np.ndarray
    birth: np.ndarray
    pairs: np.ndarray
    bodies: int
    dropped: int


@dataclass(frozen=True)
class _Bodies:
    """Closed bodies to unite: ``(vertices, faces)`` turned outward, ``label`` (body per
    face) and ``birth`` (input face per face); ``rest``: the input faces left over."""

    vertices: np.ndarray
    faces: np.ndarray
    label: np.ndarray
    birth: np.ndarray
    rest: np.ndarray


def _closed_bodies(v: np.ndarray, f: np.ndarray, pairs: np.ndarray) -> _Bodies | None:
    """The closed bodies of ``(v, f)``: shells closed, consistently oriented, of non-zero
    volume (:func:`repair.fallback.split_exact_shells`). Those that cross themselves are
    replaced by the outer hull of their exact arrangement (few crossings: quick), when
    that is a solid. None when fewer than :data:`MIN_BODY_PAIRS` pairs cross between
    two bodies."""
    from repair.fallback import _shell_labels, split_exact_shells  # it imports the hull's

    split = split_exact_shells(v, f, pairs)
    label = _shell_labels(f)
    closed = np.ones(len(f), dtype=bool)
    closed[split.offending] = False
    lab_p = label[pairs]
    between = closed[pairs].all(axis=1) & (lab_p[:, 0] != lab_p[:, 1])
    if np.count_nonzero(between) < MIN_BODY_PAIRS:
        return None
    # Rows of split.exact_faces: the closed faces in order, each turned outward.
    outward = np.zeros_like(f)
    outward[closed] = split.exact_faces
    knotted = np.zeros(int(label.max()) + 1, dtype=bool)
    knotted[label[split.knots]] = True
    plain = np.flatnonzero(closed & ~knotted[label])
    parts = [(v, outward[plain], label[plain], plain)]
    rest = [np.flatnonzero(~closed)]
    knot_faces = np.flatnonzero(closed & knotted[label])
    if len(knot_faces):
        hull = _knot_hull(v, outward, knot_faces, pairs)
        if hull is None:
            rest.append(knot_faces)
        else:
            hv, hf, hb = hull
            parts.append((hv, hf, np.full(len(hf), label.max() + 1), hb))
    bv, bf = concat_meshes([(pv, pf) for pv, pf, _, _ in parts])
    return _Bodies(bv, bf, np.concatenate([p[2] for p in parts]),
                   np.concatenate([p[3] for p in parts]), np.sort(np.concatenate(rest)))


def _knot_hull(
    v: np.ndarray, outward: np.ndarray, which: np.ndarray, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The outer hull of the closed shells ``outward[which]`` that cross themselves, by
    their exact arrangement: (vertices, faces, input face of each), or None when it
    has sheets (left to the arrangement of the whole)."""
    from repair.hull import outer_hull_split, resolve

    inside = np.zeros(len(outward), dtype=bool)
    inside[which] = True
    own = pairs[inside[pairs].all(axis=1)]
    sv, sf = drop_unreferenced(v, outward[which])
    rv, rf, birth, _ = resolve(sv, sf, solid=True, pairs=np.searchsorted(which, own))
    hull = outer_hull_split(rv, rf)
    if len(hull.sheet_faces) or len(hull.solid_faces) == 0:
        return None
    hv, hf = drop_unreferenced(rv, hull.solid_faces)
    return hv, hf, which[birth[hull.solid_index]]


def unite_closed_bodies(v: np.ndarray, f: np.ndarray, pairs: np.ndarray) -> BodyUnion | None:
    """The union of the closed bodies of ``(v, f)`` followed by its other faces (see the
    module's doc), or None where it does not apply: fewer than :data:`MIN_BODY_PAIRS`
    crossing pairs between bodies, or a body manifold3d rejects. ``pairs``: all the
    crossing face pairs of ``(v, f)``."""
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) < MIN_BODY_PAIRS:
        return None
    bodies = _closed_bodies(v, f, pairs)
    if bodies is None:
        return None
    try:
        snapped = snapped_coordinates(bodies.vertices, SNAP_REACH * probe_distance(v))
        solids = _manifolds_of(snapped, bodies.faces, bodies.label,
                               keep_faces=True, float64=True)
        if not solids:
            return None
        res = _sum_of(solids).to_mesh64()
    except Exception:  # noqa: BLE001 - any failure means: arrange it all exactly
        return None
    uv, uf = _arrays_of(res)
    source = np.asarray(res.face_id, dtype=np.int64).reshape(-1)
    n = len(bodies.faces)
    if len(source) != len(uf) or (len(uf) and (source.min() < 0 or source.max() >= n)):
        return None  # provenance lost: arrange it all rather than guess
    uv, uf, source, union_pairs = _rounded(uv, uf, source)
    out_v, out_f = weld_exact(*concat_meshes([(uv, uf), (v, f[bodies.rest])]))
    birth = np.r_[bodies.birth[source], bodies.rest].astype(np.int64)
    dropped = len(f) - len(np.unique(birth))
    # The union's own pairs are known: test only near the rest.
    rest = np.zeros(len(out_f), dtype=bool)
    rest[len(uf) :] = True
    out_pairs = crossings_after_change(out_v, out_f, union_pairs, rest)
    return BodyUnion(out_v, out_f, birth, out_pairs, len(solids), int(dropped))


def _rounded(
    uv: np.ndarray, uf: np.ndarray, source: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The union rounded to float32 (what is written; the union's new points are float
    anyway) so that the arrangement and finish that follow start from float32 points and
    do not round them again: ``(vertices, faces, source, pairs)``. Rounding avoids making
    faces cross where it can (:func:`repair.rounding.round_finding_crossings`); points it
    merges are welded and faces left with a repeated corner dropped. ``pairs``: all the
    crossing pairs of the result (only the faces on a welded point are tested again)."""
    rv, pairs = round_finding_crossings(uv, uf)
    wv, wf = weld_exact(rv, uf)
    if len(wv) == len(rv):
        return wv, wf, source, pairs
    pairs = pairs_after_weld(uf, wv, wf, pairs)
    keep = (wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 2] != wf[:, 0])
    # A face with a repeated corner is degenerate: in no pair.
    pairs = (np.cumsum(keep) - 1)[pairs[keep[pairs].all(axis=1)]]
    return wv, wf[keep], source[keep], pairs


def snapped_coordinates(vertices: np.ndarray, reach: float) -> np.ndarray:
    """``vertices`` (mm) with the values of each axis grouped into chains whose
    consecutive values are at most :data:`SNAP_ULPS` float32 ulps apart, and each
    coordinate moved onto its chain's most common value (ties: the lower) where that is
    within ``reach`` (mm) of it: points a few ulps either side of a plane of constant x,
    y or z that most of its points lie on move onto it. No coordinate moves by more
    than ``reach``."""
    out = np.array(vertices, dtype=np.float64)
    for axis in range(out.shape[1] if out.ndim == 2 and len(out) else 0):
        u, inv, count = np.unique(out[:, axis], return_inverse=True, return_counts=True)
        ulp = np.spacing(np.abs(u).astype(np.float32)).astype(np.float64)
        chain = np.cumsum(np.r_[True, np.diff(u) > SNAP_ULPS * ulp[1:]]) - 1
        order = np.lexsort((-count, chain))  # each chain's most common value first
        common = u[order[np.r_[True, np.diff(chain[order]) > 0]]][chain]
        out[:, axis] = np.where(np.abs(common - u) <= reach, common, u)[inv]
    return out
