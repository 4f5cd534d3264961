"""Which faces of a later stage of the repair are faces of an earlier one (on exactly the
same three points), so that what is known of the earlier faces -- their crossing pairs,
the input face they are a piece of -- is carried over instead of computed again.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.check import round_to_float32
from repair.rounding import crossings_after_change
from repair.rows import unique_ints
from repair.topology import face_keys, weld_exact
from repair.union import ShellUnion

__all__ = [
    "carried_pairs",
    "carry_input_pairs",
    "hull_face_sources",
    "same_faces",
    "starts_with_faces",
    "union_face_sources",
]


def starts_with_faces(va: np.ndarray, fa: np.ndarray, vb: np.ndarray, fb: np.ndarray) -> bool:
    """True when the first ``len(fa)`` faces of ``(vb, fb)`` are those of ``(va, fa)``,
    row by row, on exactly the same points (cleaning that removed nothing, lids appended)."""
    n = len(fa)
    if len(fb) < n:
        return False
    if n == 0:
        return True
    # The same rows on the same vertex rows say so without a gather (the union and the
    # hull get the very arrays of a stage that changed nothing: ~5 ms a call otherwise
    # on box and capsule).
    if (fb is fa or np.array_equal(fb[:n], fa)) and (vb is va or _same_prefix(va, vb, fa)):
        return True
    # Block by block: where the faces differ they usually do early (a weld renumbered
    # them), and the gathers stop there (2-3 ms a call on 16k faces otherwise).
    for s in range(0, n, _BLOCK):
        e = min(s + _BLOCK, n)
        if not np.array_equal(vb[fb[s:e]], va[fa[s:e]]):
            return False
    return True


#: Faces compared at a time by :func:`starts_with_faces`.
_BLOCK = 1024


def _same_prefix(va: np.ndarray, vb: np.ndarray, fa: np.ndarray) -> bool:
    """True when the vertices ``fa`` uses are at the same rows of ``vb`` as of ``va``,
    with equal coordinates (those rows of both, up to the last one used)."""
    k = int(fa.max()) + 1
    return len(vb) >= k and np.array_equal(va[:k], vb[:k])


def same_faces(va: np.ndarray, fa: np.ndarray, vb: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """For each face of ``(vb, fb)``: a face of ``(va, fa)`` on the same three points
    (exactly equal coordinates, any order), or -1. Row by row when ``fb`` starts with
    ``fa``'s faces; else by one exact weld of both."""
    if len(fa) == 0:
        return np.full(len(fb), -1, dtype=np.int64)
    if starts_with_faces(va, fa, vb, fb):
        return np.r_[np.arange(len(fa)), np.full(len(fb) - len(fa), -1)]
    # One vertex numbering for both, by exact position.
    _, both = weld_exact(np.vstack([va, vb]), np.vstack([fa, fb + len(va)]))
    keys = face_keys(both)
    ka, kb = keys[: len(fa)], keys[len(fa) :]
    order = np.argsort(ka, kind="stable")
    pos = np.clip(np.searchsorted(ka[order], kb), 0, len(ka) - 1)
    return np.where(ka[order][pos] == kb, order[pos], -1)


def union_face_sources(
    v_in: np.ndarray,
    f_in: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    union: ShellUnion,
    out_v: np.ndarray,
    out_f: np.ndarray,
) -> np.ndarray:
    """For each written face (``out_v, out_f``, finished from ``union``, the union of
    ``(v, f)``): the face of ``(v_in, f_in)`` it is believed to
    be a piece of, or -1 (a guess, verified by :func:`repair.deviation.max_deviation`).
    Finishing keeps the union's faces in order unless it mended them."""
    to_input = same_faces(v_in, f_in, v, f)  # lids: -1
    uv, uf = union.vertices, union.faces
    source = np.where(union.source >= 0, to_input[union.source], -1)
    if len(out_f) == len(uf):  # finished in one round: the same faces, rounded
        return source
    match = same_faces(round_to_float32(uv), uf, out_v, out_f)
    return np.where(match >= 0, source[match], -1)


def hull_face_sources(
    v_in: np.ndarray,
    f_in: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    hull: tuple[np.ndarray, np.ndarray],
    birth: np.ndarray,
    out_v: np.ndarray,
    out_f: np.ndarray,
) -> np.ndarray:
    """For each written face (``out_v, out_f``, finished from an outer hull of ``(v, f)``):
    the face of ``(v_in, f_in)`` it is believed to be a piece of, or -1 (a guess, verified
    by :func:`repair.deviation.max_deviation`). ``hull = (vertices, faces)``: the first
    outer hull of the exact arrangement, ``birth`` the face of ``f`` each is a piece of;
    faces the finish kept are on its corners rounded to float32."""
    to_input = same_faces(v_in, f_in, v, f)  # lids: -1
    source = np.where(birth >= 0, to_input[birth], -1) if len(birth) else birth
    match = same_faces(round_to_float32(hull[0]), hull[1], out_v, out_f)
    return np.where(match >= 0, source[match], -1) if len(source) else match


def carry_input_pairs(
    v_in: np.ndarray, f_in: np.ndarray, pairs_in: np.ndarray, v: np.ndarray, f: np.ndarray
) -> np.ndarray:
    """The intersecting face pairs of ``(v, f)`` -- the cleaned input with lids added --
    from those of the input (``pairs_in``, indices into ``f_in``, found on the same
    coordinates): faces on the same three points as an input face keep its pairs, only
    the region near the others (lids) is tested. ``v_in`` must be float32-valued (as
    :func:`repair.pipeline.repair_mesh` makes it), the coordinates ``pairs_in`` were found on."""
    same, kept = carried_pairs(same_faces(v_in, f_in, v, f), len(f_in), pairs_in)
    return crossings_after_change(v, f, kept, ~same)


def carried_pairs(
    match: np.ndarray, n_before: int, pairs_before: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Faces that keep their crossing pairs, and those pairs: ``match`` gives for each
    face the earlier face on its three points (or -1), ``pairs_before`` all the crossing
    pairs of the ``n_before`` earlier faces. A face matched twice (a copy) is not kept:
    the test is pairwise, so each copy must be tested for its own pairs."""
    hit = np.flatnonzero(match >= 0)
    _, first, cnt = unique_ints(match[hit], return_index=True, return_counts=True)
    hit = hit[first[cnt == 1]]
    same = np.zeros(len(match), dtype=bool)
    same[hit] = True
    to_new = np.full(n_before, -1, dtype=np.int64)
    to_new[match[hit]] = hit
    pairs = np.asarray(pairs_before, dtype=np.int64).reshape(-1, 2)
    kept = to_new[pairs] if len(pairs) else np.zeros((0, 2), dtype=np.int64)
    return same, kept[(kept >= 0).all(axis=1)]
