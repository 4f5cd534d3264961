"""The repair's fallback: a stated approximation for when the exact repair cannot finish
within its time budget, or cannot make the model printable.

The cleaned input (:mod:`repair.clean`, with small holes closed) is split by shell. A
shell that is already a solid -- closed, every edge used twice and in opposite
directions within the shell once its faces are oriented consistently (orientation is
exact: faces listed the wrong way round are turned), a non-zero volume -- is kept
exactly (turned outward if it was inside out). Open sheets, non-manifold shells and
wires are replaced by an approximation of their eps-Minkowski sum: Attene's slabs
(:func:`repair.thicken.sheet_slabs`: offset copies at +-eps/2 along the vertex normals,
walls along the boundary, per-face eps-blocks where a slab would fold; where those
blocks would be many, the sheet's eps/2 level set instead, unless that result does not
print) and eps-prisms
(:data:`repair.wires.SIDES` sides) around wires. The solids and the slabs are united by
manifold3d's robust booleans (one solid per shell, where shells share an edge) --
Attene's exact arrangement and outer hull, what takes the time, are skipped -- then
finished as the exact path's result is (:func:`repair.finish.finish`: rounded to
float32, checked exactly, mended locally).

A closed shell that crosses itself is kept too. Its crossings are resolved exactly
and locally first (:func:`repair.mend.mend_intersections`: only the crossing faces
are cut, along their exact intersection curves; a piece is kept where the winding
number is non-zero on one side only, so a lobe turned inside out stays solid):
manifold3d's booleans assume their input does not cross itself, and its constructor
re-meshes a knotted solid -- on admesh_basic.stl it swapped edges across a wall that
overlaps itself, cutting 0.77M mm³ out up to 40 mm deep. Where the mended surface is
not a closed edge-manifold solid (and separating the lobes that touch along an edge,
a few float32 ulps, does not make it one), the shell is kept as it is and the faces
where it crosses itself (the "knots", with the faces that share a corner with them)
are covered by eps-blocks instead (:func:`repair.thicken.face_blocks`: each face's
Minkowski sum with an eps-double pyramid, convex). A sheet whose slab would
cross itself gets eps-blocks in place of the slab. The union's cavities (negative
shells, unreachable from outside: Attene's outer hull keeps none) are filled.

Slab points lie within ``MITER_LIMIT * eps/2`` of the input, block points within
eps/2 and level-set points a little beyond (0.59 eps on mikedh_target, as on the exact
path), so the deviation D of the thickened parts is about eps/2 (measured and
reported); exact shells keep their triangles where nothing crosses them, D = 0 there
(lids of closed holes aside), and a mended knot's pieces lie on its own faces.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Vectorised numpy; one
manifold3d batch union; CGAL (libigl) on the knots only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from repair.clean import drop_unreferenced
from repair.errors import RepairError
from repair.finish import finish, unfinished_reasons
from repair.holes import HolesClosed
from repair.mend import mend_intersections, separate_singular_edges
from repair.meshes import concat_meshes, shell_volumes, surface_area
from repair.report import RepairOutcome, RepairTally
from repair.rows import unique_rows
from repair.thicken import face_blocks, orient_patches, sheet_slabs
from repair.topology import (
    connected_labels,
    edge_components,
    edge_ids,
    edge_stats,
    paired_half_edges,
)
from repair.union import manifold_union, speck_volume
from repair.wires import cylinders

__all__ = [
    "APPROXIMATION",
    "ShellSplit",
    "fallback_repair",
    "minkowski_pieces",
    "split_exact_shells",
]

#: What the fallback does, as the report states it.
APPROXIMATION = (
    "closed solid shells kept exact (where one crosses itself, its crossings resolved "
    "exactly, or else covered by eps-blocks), "
    "the other parts replaced by their eps-Minkowski sum (eps-thick slabs, blocks or "
    "level sets, "
    "eps-prisms around wires), united by manifold3d, cavities filled"
)


@dataclass(frozen=True)
class ShellSplit:
    """The faces of the shells kept exactly (rows of the input's, turned outward), the
    indices of the faces that are approximated, and how many shells of each; of the
    kept ones, how many are closed solids that cross themselves, and ``knots``: the
    indices of their faces that cross a face of the same shell; ``knotted``: which rows
    of ``exact_faces`` are of such a shell, and ``knot_pairs``: those crossings, as
    pairs of rows of ``exact_faces``."""

    exact_faces: np.ndarray
    offending: np.ndarray
    exact_shells: int
    offending_shells: int
    crossing_solids: int
    knots: np.ndarray
    knotted: np.ndarray
    knot_pairs: np.ndarray


def _shell_labels(faces: np.ndarray) -> np.ndarray:
    """Shells: faces joined by edges that exactly two faces use, so that two solids
    sharing an edge or a sheet hanging off a solid stay apart."""
    eid, _ = edge_ids(faces)
    h1, h2, _ = paired_half_edges(eid)
    return connected_labels(len(faces), h1 // 3, h2 // 3)


def split_exact_shells(
    vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray | None = None
) -> ShellSplit:
    """Which shells of ``(vertices, faces)`` are solids to keep exactly; ``pairs``: its
    intersecting face pairs (k, 2) -- a shell crossing itself is not kept."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return ShellSplit(np.zeros((0, 3), dtype=np.int64), empty, 0, 0, 0, empty,
                          np.zeros(0, dtype=bool), np.zeros((0, 2), dtype=np.int64))  # fmt: skip
    label = _shell_labels(f)
    n = int(label.max()) + 1
    bad = np.zeros(n, dtype=bool)
    # Within its own shell, every edge must be used by two half-edges in opposite
    # directions: count the uses of (shell, lo, hi) and of (shell, from, to).
    a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
    shell = np.repeat(label, 3)
    _, inv, uses = unique_rows(np.stack([shell, np.minimum(a, b), np.maximum(a, b)], 1),
                               return_inverse=True, return_counts=True)  # fmt: skip
    _, dinv, dcount = unique_rows(np.stack([shell, a, b], 1), return_inverse=True,
                                  return_counts=True)  # fmt: skip
    open_or_twisted = (uses[inv] != 2) | (dcount[dinv] != 1)
    bad[shell[open_or_twisted]] = True
    volume = shell_volumes(np.asarray(vertices, dtype=np.float64), f, label, n)
    bad |= volume == 0.0
    crossing = np.zeros(n, dtype=bool)
    p = np.zeros((0, 2), dtype=np.int64)
    if pairs is not None and len(pairs):
        p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        p = p[label[p[:, 0]] == label[p[:, 1]]]
        p = p[~bad[label[p[:, 0]]]]
        crossing[label[p[:, 0]]] = True
    keep = ~bad[label]
    row = np.cumsum(keep) - 1  # input face -> row of exact_faces
    exact = f[keep].copy()
    inside_out = volume[label[keep]] < 0
    exact[inside_out] = exact[inside_out][:, ::-1]
    return ShellSplit(exact, np.flatnonzero(~keep), int(np.count_nonzero(~bad)),
                      int(np.count_nonzero(bad)), int(np.count_nonzero(crossing & ~bad)),
                      np.unique(p), crossing[label[keep]], row[p])  # fmt: skip


def minkowski_pieces(
    vertices: np.ndarray, faces: np.ndarray, segments: np.ndarray, eps: float,
    strict: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed pieces whose union approximates the eps-Minkowski sum of the faces and
    segments: the faces' slabs (eps-blocks for a sheet whose slab would cross itself:
    manifold3d does not resolve a piece's own crossings; unless ``strict``, the sheet's
    eps/2 level set where the blocks would be many, :func:`repair.thicken.sheet_slabs`)
    and an eps-prism per segment."""
    parts = []
    if len(faces):
        parts.append(sheet_slabs(vertices, faces, eps, strict=strict))
    if segments is not None and len(segments):
        parts.append(cylinders(segments, eps))
    return concat_meshes(parts)


def _mended_solids(
    v: np.ndarray, split: ShellSplit
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None:
    """The kept solids, those that cross themselves with their crossings resolved
    exactly (:func:`repair.mend.mend_intersections`, non-zero winding: only the knots
    are cut and sorted; where lobes then touch along an edge, each gets its own copy of
    it a few float32 ulps apart, :func:`repair.mend.separate_singular_edges`), and the
    mended pieces that bound no solid (a fold whose two layers cancel: sheets to
    thicken); None when the mended shells are still not closed edge-manifold solids.
    The solids that do not cross themselves keep their faces."""
    none = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    if len(split.knot_pairs) == 0:
        return (v, split.exact_faces), none
    own = np.flatnonzero(split.knotted)
    at = np.full(len(split.exact_faces), -1, dtype=np.int64)
    at[own] = np.arange(len(own))
    sv, sf = drop_unreferenced(v, split.exact_faces[own])
    mended = mend_intersections(sv, sf, at[split.knot_pairs], nonzero=True,
                                outside_sheets=True)  # fmt: skip
    mv, mf = mended.vertices, mended.faces
    if len(mf) == 0:
        return None
    boundary, nonmanifold, misoriented, _, _ = edge_stats(mf)
    if nonmanifold and not (boundary or misoriented):
        separated = separate_singular_edges(mv, mf, float(np.abs(mv).max()) * 2.0**-17)
        if separated is None:
            return None
        mv, mf, _ = separated
        boundary, nonmanifold, misoriented, _, _ = edge_stats(mf)
    if boundary or nonmanifold or misoriented:
        return None
    solids = concat_meshes([(v, split.exact_faces[~split.knotted]), (mv, mf)])
    return solids, (mended.vertices, mended.sheets)


def _knot_blocks(
    vertices: np.ndarray, faces: np.ndarray, knots: np.ndarray, eps: float
) -> tuple[np.ndarray, np.ndarray]:
    """eps-blocks over the ``knots`` (face indices) and the faces sharing a corner with
    one: their union covers every crossing of those faces with room to spare."""
    near = np.zeros(len(vertices), dtype=bool)
    near[faces[knots].reshape(-1)] = True
    return face_blocks(vertices, faces[near[faces].any(axis=1)], eps)


def fallback_repair(
    v: np.ndarray, f: np.ndarray, segments: np.ndarray, pairs: np.ndarray | None, eps: float,
    reason: str,
) -> RepairOutcome:
    """The fallback's outcome for a cleaned input ``(v, f)`` plus its wires ``segments``
    (``pairs``: its intersecting face pairs, if known); ``reason`` says why it ran.
    Raises :class:`RepairError` when its float32 result is not printable; D is left for
    the caller to measure."""
    t0 = time.perf_counter()
    # Orientation is exact and cheap: a closed shell with some faces flipped is turned
    # consistent here and kept exact, not thickened (an unorientable one still is).
    f = orient_patches(f)[0]
    split = split_exact_shells(v, f, pairs)
    mended = _mended_solids(v, split)
    if mended is None:  # kept as they are, their knots covered by eps-blocks
        solids, folds = (v, split.exact_faces), (v, f[:0])
        kv, kf = _knot_blocks(v, f, split.knots, eps)
    else:
        (solids, folds), (kv, kf) = mended, (np.zeros((0, 3)), f[:0])
    # One manifold3d solid per shell: solids that share an edge, as one non-manifold
    # piece, leave manifold3d's union crossing itself (mikedh_cycloidal: 6,992 crossing
    # pairs once rounded, 45 this way).
    shells = _shell_labels(solids[1])
    # The approximated faces (rows of sv, sf): the offending shells', then the folds'.
    sv, sf = concat_meshes([(v, f[split.offending]), folds])
    # A sheet whose slab folds in many places is thickened by its level set, as on the
    # exact path (one solid: far cheaper to unite than thousands of eps-blocks; D up to
    # ~0.59 eps against the blocks' 0.55); where that does not print, by the blocks.
    for strict in (False, True) if len(sf) else (True,):
        pv, pf = minkowski_pieces(sv, sf, segments, eps, strict=strict)
        tally = RepairTally(sheet_triangles=len(sf), wires=len(segments),
                            sheet_area=surface_area(sv, sf))  # fmt: skip
        fused = manifold_union([solids, (pv, pf), (kv, kf)], min_volume=speck_volume(eps),
                               shells=shells)  # fmt: skip
        if fused is None:
            failure = "manifold3d rejected a part"
            continue
        fused, cavities = _without_cavities(*fused)
        if len(fused[1]) == 0:  # not "the mesh has no triangles": say what the union did
            failure = (f"manifold3d's union of the thickened parts has no outward-facing "
                       f"shell ({cavities} shell(s), all inside out)")
            continue
        # Rounded to float32 and checked; where rounding made faces cross or collapse,
        # mended locally, as the exact path's result is.
        out_v, out_f, verdict = finish(*fused, eps, tally)
        if verdict.ok:
            break
        failure = "; ".join(unfinished_reasons(verdict, tally))
    else:
        raise _failed(reason, failure)
    out = RepairOutcome(out_v, out_f, verdict, "fallback", 0.0, tally, HolesClosed())
    out.sections["fallback"] = {
        "reason": reason,
        "approximation": APPROXIMATION,
        "exact_shells": split.exact_shells,
        "approximated_shells": split.offending_shells,
        "approximated_triangles": int(len(split.offending)),
        "self_crossing_shells": split.crossing_solids,
        "knot_triangles": int(len(split.knots)),
        "knots_blocked": bool(len(kf)),
        "knot_fold_triangles": int(len(folds[1])),
        "cavities_filled": cavities,
        "strict_slabs": strict,
        "wires": int(len(segments)),
        "seconds": round(time.perf_counter() - t0, 4),
    }
    return out


def _without_cavities(
    v: np.ndarray, f: np.ndarray
) -> tuple[tuple[np.ndarray, np.ndarray], int]:
    """The closed mesh without its negative (inward-facing) shells, and how many: the
    cavities a union of thickened surfaces leaves inside."""
    shell = edge_components(f)
    n = int(shell.max()) + 1 if len(f) else 0
    cavity = shell_volumes(v, f, shell, n) < 0
    if not cavity.any():
        return (v, f), 0
    return drop_unreferenced(v, f[~cavity[shell]]), int(np.count_nonzero(cavity))


def _failed(reason: str, why: str) -> RepairError:
    return RepairError(f"{reason}, and the fallback failed: {why}")
