"""Stage 5 of the repair: round to float32 (what a binary STL stores), verify with the
exact check, and mend until the written mesh is printable.

A closed surface is mended where it is damaged (:mod:`repair.mend`: exact local
arrangement of the crossing faces, winding-number choice of the pieces); from the
second round on, the shortest edge of each damaged face is first collapsed when it is
at float32-rounding scale, so that rounding cannot keep re-creating the same slivers.
Edges shared by more than two faces (parts touching along an edge) first get one
copy per part, a few ulps apart (:func:`repair.mend.separate_singular_edges`); where
that leaves more damage, they are thickened into thin prisms that fuse the parts. An
open result takes the whole arrangement and outer hull again.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.check import (
    Printability,
    check_printable,
    round_to_float32,
    verdict_given_pairs,
)
from repair.clean import degenerate_mask, drop_unreferenced
from repair.hull_and_thicken import hull_again
from repair.intersections import intersecting_face_pairs
from repair.mend import mend_intersections, separate_singular_edges
from repair.meshes import concat_meshes
from repair.provenance import carried_pairs, same_faces
from repair.report import RepairTally
from repair.rounding import crossings_after_change, pairs_after_weld, round_finding_crossings
from repair.rows import unique_ints, unique_rows
from repair.topology import (
    connected_labels,
    edge_ids,
    face_keys,
    half_edges,
    is_cycle,
    undirected_edges,
    weld_exact,
)
from repair.wires import cylinders

__all__ = [
    "COLLAPSE_FROM",
    "HULL_GROWTH",
    "HULL_GROWTH_FLOOR",
    "MAX_FINISH_ROUNDS",
    "MAX_HULL_ROUNDS",
    "SINGULAR_EDGE_DIAMETER",
    "collapse_damaged",
    "damaged_faces",
    "finish",
    "rounded_verdict",
    "unfinished_reasons",
]

#: Rounds of "round to float32, verify, resolve again" before giving up.
MAX_FINISH_ROUNDS = 12
#: Rounds that take the whole arrangement and outer hull again, at most, in one finish.
MAX_HULL_ROUNDS = 3
#: A whole-arrangement round is not taken when the damage it would mend is more than this
#: many times the previous one's (and over :data:`HULL_GROWTH_FLOOR`): rounding that
#: re-creates ever more crossings stacks thin slabs (CGAL's part with needles and
#: T-junctions: 1,120 -> 6,442 -> 36,835 crossing pairs, then a 259k-face arrangement).
HULL_GROWTH = 4.0
#: Damage below which a whole-arrangement round is taken whatever it grew from.
HULL_GROWTH_FLOOR = 256
#: From this finish round on, damaged faces first lose their float32-scale edges.
COLLAPSE_FROM = 1
#: Diameter of the prisms that fuse parts touching along an edge, as a fraction of eps.
SINGULAR_EDGE_DIAMETER = 0.1

#: A mesh, all of whose crossing face pairs are known: ``(vertices, faces, pairs)``.
Checked = tuple[np.ndarray, np.ndarray, np.ndarray]


def damaged_faces(v: np.ndarray, f: np.ndarray, pairs: np.ndarray | None = None) -> np.ndarray:
    """Faces that are degenerate, duplicated, intersect another, or sit on an edge that is
    open, non-manifold or traversed twice the same way. ``pairs``: the intersecting face
    pairs of ``(v, f)`` if known (the test is pairwise: those among the faces not damaged
    otherwise are the ones a test of those faces finds)."""
    bad = degenerate_mask(v, f)
    _, inv, cnt = unique_ints(face_keys(f), return_inverse=True, return_counts=True)
    bad |= cnt[inv] > 1
    he = half_edges(f)
    eid, ecnt = edge_ids(f)
    _, hinv, hcnt = unique_rows(he, return_inverse=True, return_counts=True)
    bad_he = (ecnt[eid] != 2) | (hcnt[hinv.reshape(-1)] > 1)
    bad |= bad_he.reshape(-1, 3).any(axis=1)
    if pairs is None:
        ok = np.flatnonzero(~bad)
        pairs = ok[intersecting_face_pairs(v, f[ok])]
    else:
        pairs = pairs[~bad[pairs].any(axis=1)]
    bad[pairs.reshape(-1)] = True
    return np.flatnonzero(bad)


def collapse_damaged(
    v: np.ndarray, f: np.ndarray, reach: float = 2.0**-18, pairs: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Merge the endpoints of the shortest edge of every damaged face when that edge is
    within float32 rounding scale (union-find over all such edges at once); the merged
    vertex keeps one endpoint's position, so nothing moves by more than ~4 ulps x chain.
    Returns ``(v, f)`` themselves when no edge is that short."""
    bad = damaged_faces(v, f, pairs)
    if len(bad) == 0:
        return v, f
    p = v[f[bad]]
    ln = np.linalg.norm(p[:, [1, 2, 0]] - p, axis=2)
    k = np.argmin(ln, axis=1)
    # Only edges at the scale of float32 rounding: a few ulps of the largest coordinate.
    tol = float(np.abs(v).max()) * reach
    short = ln[np.arange(len(bad)), k] <= tol
    a = f[bad[short], k[short]]
    b = f[bad[short], (k[short] + 1) % 3]
    if len(a) == 0:
        return v, f
    n = len(v)
    lab = connected_labels(n, a, b)
    # Representative: the lowest vertex index of each group keeps its position.
    rep = np.full(lab.max() + 1, n, dtype=np.int64)
    np.minimum.at(rep, lab, np.arange(n))
    return v, rep[lab][f]


def rounded_verdict(
    v: np.ndarray,
    f: np.ndarray,
    before: Checked | None = None,
) -> tuple[np.ndarray, np.ndarray, Printability, np.ndarray]:
    """Round to float32 avoiding crossings, weld, and check: ``(v32, f32, verdict,
    pairs)``. The crossings found while rounding are reused when the weld merged nothing
    (same faces, same coordinates: the same test). ``before = (v, f, pairs)``: a checked
    mesh this one was mended from, with all its crossing pairs; faces on the same points
    as one of its faces keep their pairs, and only the region near the others is tested.
    """
    known = None
    if before is not None:
        match = same_faces(before[0], before[1], v, f)
        known = carried_pairs(match, len(before[1]), before[2])
    r, found = round_finding_crossings(v, f, known=known)
    v32, f32 = weld_exact(r, f)
    if len(v32) != len(r):
        found = pairs_after_weld(f, v32, f32, found)
    verdict, pairs = verdict_given_pairs(v32, f32, found)
    return v32, f32, verdict, pairs


def finish(
    v: np.ndarray,
    f: np.ndarray,
    eps: float,
    tally: RepairTally,
    before: Checked | None = None,
    *,
    local_only: bool = False,
) -> tuple[np.ndarray, np.ndarray, Printability]:
    """Round to float32, verify, and mend until the written mesh is printable (see the
    module docstring). Returns the float32-valued ``(vertices, faces)`` and their verdict,
    which is not ``ok`` when the rounds ran out or the damage kept growing, or, with
    ``local_only``, when local mending does not do (the whole arrangement is not taken).
    Whole-arrangement rounds are bounded by what they do (:data:`MAX_HULL_ROUNDS`,
    :data:`HULL_GROWTH`): past that, this round's rounded mesh is returned, not ``ok``,
    and ``tally.finish_stopped`` says why.

    ``before = (v, f, pairs)``: a mesh whose crossing pairs are all known, on float32
    points, that ``(v, f)`` was made from (a union of shells keeps most of their faces):
    faces on the same points keep their pairs, only the region near the others is
    tested. A mend passes its own on to the next round the same way.
    """
    tried_separation = False
    worse = 0
    last_damage = None
    ready = None  # this round's rounded verdict, when already taken
    hulled: list[int] = []  # the damage each whole-arrangement round set out to mend
    for round_ in range(MAX_FINISH_ROUNDS):
        v32, f32, verdict, pairs = ready or rounded_verdict(v, f, before)
        before = ready = None
        if verdict.ok:
            return v32, f32, verdict
        rounded = (v32, f32, verdict)
        damage = _damage(verdict)
        grew = last_damage is not None and damage > last_damage
        worse += grew
        # Diverging (the 4th round to grow the damage): give up rather than grow without
        # bound; nothing left: nothing to mend.
        if worse >= 4 or len(f32) == 0:
            break
        last_damage = damage
        tally.passes += 1
        # Mend locally while that shrinks the damage; where rounding keeps re-creating it
        # (crossing thin slabs), take the whole arrangement and outer hull again instead.
        local = is_cycle(f32) and not grew
        v32, f32, pairs = _collapse_short_edges(v32, f32, pairs, verdict, round_, local, tally)
        touching = verdict.nonmanifold_edges and not (
            verdict.intersecting_pairs or verdict.degenerate_faces
        )
        # Separated at the first round they show, crossings or not (the parts that touch
        # are there from the start: an outer hull keeps them; each round spent mending
        # around them first costs a rounding and check); tried again once they are all
        # that is left.
        if verdict.nonmanifold_edges and not tried_separation and not verdict.boundary_edges:
            tried_separation = bool(touching)
            separated = _separate_if_better(v32, f32, pairs, verdict)
            if separated is not None:
                tried_separation = True
                # Its rounded verdict is the next round's (not taken twice): done if ok.
                (v, f, tally.separated), ready = separated
                if ready[2].ok:
                    return ready[0], ready[1], ready[2]
                continue
        # Parts touching along an edge, all that is left: fused by thin prisms there;
        # ``pairs`` stay those of (v32, f32): the prisms' are found apart.
        extra = [_singular_edge_prisms(v32, f32, eps, tally)] if touching else []
        if local and is_cycle(f32):
            mended = _mend_locally(v32, f32, extra, pairs)
            if mended is not None:
                v, f, before = mended
                continue
        if local_only:
            break
        if stop := _hull_round_refused(hulled, damage):
            tally.finish_stopped = stop
            return rounded
        hulled.append(damage)
        v, f, before = hull_again(v32, f32, pairs, extra, eps, tally)
    return _rounded_as_it_is(v, f)


def _rounded_as_it_is(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, Printability]:
    """``(v, f)`` rounded to float32 and welded, without avoiding crossings, and its
    verdict: what the finish returns when its rounds ran out or diverged."""
    v32, f32 = weld_exact(round_to_float32(v), f)
    return v32, f32, check_printable(v32, f32)


def unfinished_reasons(verdict: Printability, tally: RepairTally) -> list[str]:
    """Why a :func:`finish` result is not printable: ``verdict``'s failures, then why the
    finish stopped taking the whole arrangement again (``tally.finish_stopped``), if it
    did."""
    return [*verdict.failures(), *([tally.finish_stopped] if tally.finish_stopped else [])]


def _damage(p: Printability) -> int:
    """What a finish round mends: crossing pairs, degenerate faces, non-manifold edges."""
    return p.intersecting_pairs + p.degenerate_faces + p.nonmanifold_edges


def _hull_round_refused(hulled: list[int], damage: int) -> str:
    """Why the next whole-arrangement round is not taken (empty when it is), given the
    damage each earlier one set out to mend and this round's."""
    if len(hulled) >= MAX_HULL_ROUNDS:
        return f"still damaged after {len(hulled)} rounds of the whole arrangement again"
    if hulled and damage > max(HULL_GROWTH * hulled[-1], HULL_GROWTH_FLOOR):
        return (f"the finish's whole-arrangement rounds grew the damage {hulled[-1]} -> "
                f"{damage} (over {HULL_GROWTH:g}x a round)")
    return ""


def _collapse_short_edges(
    v32: np.ndarray,
    f32: np.ndarray,
    pairs: np.ndarray | None,
    verdict: Printability,
    round_: int,
    local: bool,
    tally: RepairTally,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """From round :data:`COLLAPSE_FROM` on (or when not mending locally), collapse the
    float32-scale edges of damaged faces; from the second round on, drop the faces left
    with a repeated corner and unused vertices. Returns the mesh and its crossing pairs,
    kept up to date when they were known."""
    changed = None  # faces whose corners a collapse moved (pairs known for the rest)
    if (round_ >= COLLAPSE_FROM or not local) and (
        verdict.intersecting_pairs or verdict.degenerate_faces
    ):
        # Growing reach (still far below a nozzle) when damage keeps coming back.
        reach = 2.0 ** (-18 + min(max(round_ - COLLAPSE_FROM, 0), 6))
        collapsed = collapse_damaged(v32, f32, reach, pairs)
        tally.collapsed += 1
        if collapsed[1] is not f32:
            changed = np.any(collapsed[1] != f32, axis=1)
        v32, f32 = collapsed
    if verdict.duplicate_faces or round_ >= 1:
        # Drop faces a collapse left with a repeated corner, and unused vertices (a
        # closed cycle stays one; coincident copies are merged by weight in the mend).
        keep = (f32[:, 0] != f32[:, 1]) & (f32[:, 1] != f32[:, 2]) & (f32[:, 2] != f32[:, 0])
        if pairs is not None and not keep.all():
            pairs = np.cumsum(keep)[pairs[keep[pairs].all(axis=1)]] - 1
            changed = changed[keep] if changed is not None else None
        v32, f32 = drop_unreferenced(v32, f32[keep])
    if pairs is not None and changed is not None:
        # The pairs of faces the collapse left alone stand; test near the others.
        pairs = crossings_after_change(v32, f32, pairs[~changed[pairs].any(axis=1)], changed)
    return v32, f32, pairs


def _separate_if_better(
    v32: np.ndarray, f32: np.ndarray, pairs: np.ndarray | None, verdict: Printability
) -> tuple[tuple[np.ndarray, np.ndarray, int], tuple] | None:
    """Parts that touch along an edge: give each its own copy of the edge, a few ulps
    apart (exact elsewhere). Kept -- ``(separated mesh and edge count, its rounded
    verdict)`` -- if that leaves less damage (crossing pairs, degenerate faces and
    non-manifold edges) once rounded than ``verdict`` counts (a copy may cross a face
    close by); else None, and the edges are fused instead."""
    step = float(np.abs(v32).max()) * 2.0**-17
    sep = separate_singular_edges(v32, f32, step)
    if sep is None:
        return None
    tried = rounded_verdict(*sep[:2], None if pairs is None else (v32, f32, pairs))
    trial = tried[2]
    if _damage(trial) < _damage(verdict):
        return sep, tried
    return None


def _singular_edge_prisms(
    v32: np.ndarray, f32: np.ndarray, eps: float, tally: RepairTally
) -> tuple[np.ndarray, np.ndarray]:
    """Thin prisms along the edges shared by more than two faces, so the parts touching
    there fuse."""
    edges, uses = undirected_edges(f32)
    singular = edges[uses > 2]
    tally.singular_edges += len(singular)
    return cylinders(v32[singular], eps * SINGULAR_EDGE_DIAMETER)


def _mend_locally(
    v32: np.ndarray,
    f32: np.ndarray,
    extra: list[tuple[np.ndarray, np.ndarray]],
    pairs: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, Checked | None] | None:
    """The mended surface and, when the crossing pairs of ``(v32, f32)`` were all known
    (``pairs``), the checked mesh it was mended from (for the next round); None when
    libigl refuses the subset (the caller then takes the whole outer hull). The
    ``extra`` solids' crossings are found near them only: cycloidal's fallback, 22
    prisms on 78k faces, 2.6 s CPU for a whole test."""
    mv, mf = concat_meshes([(v32, f32), *extra])
    every = pairs
    if pairs is not None and len(mf) > len(f32):
        every = crossings_after_change(mv, mf, pairs, np.arange(len(mf)) >= len(f32))
    try:
        md = mend_intersections(mv, mf, every)
    except (RuntimeError, ValueError, IndexError):
        return None
    # Carried on float32 points only: the prisms' corners are not rounded yet.
    before = (v32, f32, pairs) if pairs is not None else None
    return md.vertices, md.faces, before
