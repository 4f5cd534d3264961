"""Hairline gaps: places where a printable surface comes back within a hair of itself.

A mesh can pass the exact check and still hold faces whose two sides are not what a
solid's are: a slit thinner than a float32 ulp or two between two walls of one shell
(the winding number just outside such a wall is 1: the probe crosses the slit and lands
in the solid again), or a blade thinner than that (0 just inside). They come from the
input itself -- overlapping CAD shells whose faces nearly coincide, float32 points a hair
apart -- which the exact arrangement keeps as it finds them, and from rounding its result
to float32. A slicer should never see them.

:func:`hairline_suspects` finds, cheaply, the faces that another face comes nearer than
the probe distance of :func:`repair.junk.face_winding_sides`; the winding number decides
among them. :func:`without_hairline_gaps` closes them, round by round, by the cheapest
of: a zip (:mod:`repair.zip`: the walls' corners within :data:`FILL_REACH` probe
distances merged, faces left back to back dropped -- slits whose walls have matching
corners, blades, needles); a snap of one wall onto the other and an exact local mend;
and a fill (:func:`fill_hairline_gaps`: a prism of 2 probe distances either side of each
failing face, and thin cylinders along its creases, united with the solid by
manifold3d). Nothing moves by more than those 2 probe distances (about 4 float32 ulps of
the part's size); each result is rounded, checked and kept only when it is printable
and fewer faces fail.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.junk import face_winding_sides, failing_faces, probe_distance
from repair.report import RepairOutcome, RepairTally

__all__ = ["fill_hairline_gaps", "hairline_suspects", "hairline_failures",
           "without_hairline_gaps"]  # fmt: skip

#: How far the filling prisms reach either side of a failing face, in probe distances.
FILL_REACH = 2.0
#: Meshes with more faces are only zipped (:func:`repair.zip.zip_hairline`, a fraction
#: of a second a round): snapping and filling, each rounded and mended, took tens of
#: seconds on the corpus's 30k-90k-face outputs, more than the rest of their repair.
MAX_FACES = 20_000
#: Meshes with more faces are left as they are: finding the failing faces costs 2-15 s on
#: the corpus's 64k-90k-face outputs (the exact winding numbers near the surface).
MAX_ZIP_FACES = 40_000
#: Rounds of "find, fill, round and check" at most.
MAX_FILL_ROUNDS = 6


def hairline_suspects(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with another face nearer than the probe distance ``d`` to a point ``d``
    off their centroid (either side): the only faces whose winding sides can be wrong on
    a printable mesh of one nesting level. A libigl AABB distance query; also every face
    too thin to be probed at ``d`` (its own probe is nearer)."""
    import igl

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    d = probe_distance(v)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    c = p.mean(axis=1)
    q = np.vstack([c + d * n, c - d * n])
    sq, nearest, _ = igl.point_mesh_squared_distance(q, v, f)
    m = len(f)
    other = (nearest.reshape(2, m) != np.arange(m)) & (sq.reshape(2, m) < (0.999 * d) ** 2)
    return np.flatnonzero(other.any(axis=0) | (length[:, 0] == 0))


def hairline_failures(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces that fail the two-sided winding test (:func:`repair.junk.failing_faces`),
    looked for among :func:`hairline_suspects` only."""
    sus = hairline_suspects(vertices, faces)
    if len(sus) == 0:
        return sus
    outside, inside = face_winding_sides(vertices, faces, sus)
    return sus[failing_faces(outside, inside)]


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


def without_hairline_gaps(out: RepairOutcome, eps: float) -> RepairOutcome:
    """``out`` with its hairline slits, blades and needles closed, rounded to float32,
    checked and mended locally (:func:`repair.finish.finish`; a result that local mending
    cannot make printable is given up: the whole arrangement may take minutes). Each
    round tries, in turn, a zip of the failing faces' corners that lie within
    :data:`FILL_REACH` probe distances of each other (:func:`repair.zip.zip_hairline`,
    without and with walls left overlapping for the mend),
    a snap of one wall onto the other and an exact mend
    (:func:`repair.zip.snap_onto_opposite`), and a fill with prisms
    (:func:`fill_hairline_gaps`); the one that leaves the mesh printable with the fewest
    faces failing the two-sided winding test (:func:`_one_round`) is taken; the round
    with the fewest is kept.
    Meshes of more than :data:`MAX_FACES` faces are only zipped, of more than
    :data:`MAX_ZIP_FACES` returned as they are (time).
    Counted in ``out.sections["hairline_gaps"]``."""
    if not out.verdict.ok or not 0 < len(out.faces) <= MAX_ZIP_FACES:
        return out
    bad = hairline_failures(out.vertices, out.faces)
    found = best = len(bad)
    used: list[str] = []
    v, f = out.vertices, out.faces
    # A slit that narrows to an edge (a wedge) closes from its narrow end: each round
    # closes what the last one left within a hair of the other wall, further along it.
    for _ in range(MAX_FILL_ROUNDS):
        if len(bad) == 0:
            break
        step = _one_round(v, f, bad, eps, out.tally)
        if step is None:
            break  # nothing closed any, or every try added failing faces: give up
        method, (v, f, verdict), bad = step
        used.append(method)
        if len(bad) < best:
            out.vertices, out.faces, out.verdict, best = v, f, verdict, len(bad)
    if found:
        out.sections["hairline_gaps"] = {
            "faces_found": int(found), "rounds": used, "faces_left": int(best),
            "reach_mm": float(FILL_REACH * probe_distance(out.vertices)),
        }  # fmt: skip
    return out
