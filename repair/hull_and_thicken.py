"""Stages 2-4 of the repair (Attene Sec. 4.1-4.2.1): resolve the self-intersections
exactly, take the outer hull, and thicken what of it is a zero-thickness sheet or a
visible wire by epsilon; the union of the hull and those thin solids is taken again
until no sheet is left.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

import numpy as np

from repair.body_union import unite_closed_bodies
from repair.clean import clean_soup, drop_unreferenced
from repair.hull import (
    HullSplit,
    is_unorientable,
    outer_hull_split,
    resolve,
    unorientable_outer_hull,
)
from repair.intersections import intersecting_face_pairs
from repair.meshes import concat_meshes, surface_area
from repair.provenance import carry_input_pairs
from repair.report import RepairTally
from repair.thicken import region_prisms, sheet_slabs
from repair.union import manifold_union, speck_volume, without_specks
from repair.wires import cylinders, visible_segments

__all__ = ["MAX_THICKEN_ROUNDS", "hull_again", "hull_and_thicken"]

#: Rounds of "thicken the sheets, take the outer hull of the union".
MAX_THICKEN_ROUNDS = 3


def hull_and_thicken(
    v: np.ndarray,
    f: np.ndarray,
    eps: float,
    tally: RepairTally,
    segments: np.ndarray | None = None,
    *,
    solid: bool = False,
    pairs: np.ndarray | None = None,
) -> tuple[
    np.ndarray, np.ndarray, tuple, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None
]:
    """Resolve, take the outer hull, thicken sheets/wires and repeat until no sheet is left.
    ``pairs``: the intersecting face pairs of ``(v, f)`` if known.

    Returns the closed solid ``(vertices, faces)`` plus the first pass's outer hull
    ``(vertices, faces)`` (solid faces, then sheet faces), the birth face (into ``f``)
    of each of its faces, and, when the closed bodies were united, the rounded union
    with all its crossing pairs ``(vertices, faces, pairs)`` (else None): the solid
    keeps most of its faces on the same points, so a check of it need test only near
    the others (``before`` of :func:`repair.finish.rounded_verdict`).
    """
    first_hull_birth = np.zeros(0, dtype=np.int64)
    first_poly = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    unorientable = not solid and is_unorientable(f)
    united = None if unorientable or pairs is None else unite_closed_bodies(v, f, pairs)
    checked = None
    if united is not None:
        # The bodies' union stands for them: only the rest is arranged exactly.
        tally.intersecting_pairs = len(pairs)
        tally.internal_faces += united.dropped
        v, f, pairs = united.vertices, united.faces, united.pairs
        checked = (v, f, pairs)
    for round_ in range(MAX_THICKEN_ROUNDS + 1):
        tally.passes += 1
        if round_ == 0 and unorientable:
            rv, rf, birth, split = unorientable_outer_hull(v, f)
            n_pairs = len(intersecting_face_pairs(v, f) if pairs is None else pairs)
        else:
            known = pairs if round_ == 0 else None
            rv, rf, birth, n_pairs = resolve(v, f, solid=solid or round_ > 0, pairs=known)
            split = outer_hull_split(rv, rf)
        if tally.intersecting_pairs < 0:
            tally.intersecting_pairs = n_pairs
        tally.internal_faces += split.internal if round_ == 0 else 0
        if round_ == 0:
            first_poly = (rv, np.vstack([split.solid_faces, split.sheet_faces]))
            first_hull_birth = birth[np.r_[split.solid_index, split.sheet_index]]
            if united is not None:
                first_hull_birth = united.birth[first_hull_birth]
        extra: list[tuple[np.ndarray, np.ndarray]] = []
        if len(split.sheet_faces) and round_ < MAX_THICKEN_ROUNDS:
            tally.sheet_area += surface_area(rv, split.sheet_faces)
            tally.sheet_triangles += len(split.sheet_faces)
            extra.extend(_sheet_solids(v, f, rv, birth, split, eps))
        if segments is not None and len(segments) and round_ == 0:
            hull_f = np.vstack([split.solid_faces, split.sheet_faces])
            vis = visible_segments(segments, rv, hull_f, split.solid_faces)
            tally.wires += len(vis)
            if len(vis):
                extra.append(cylinders(vis, eps))
        if not extra:
            # Specks: outer-hull shells of a mend's crumbs (see without_specks).
            sv, sf = without_specks(*drop_unreferenced(rv, split.solid_faces), speck_volume(eps))
            return sv, sf, first_poly, first_hull_birth, checked
        fused = manifold_union([(rv, split.solid_faces), *extra], min_volume=speck_volume(eps))
        if fused is not None:
            sv, sf = fused
            return sv, sf, first_poly, first_hull_birth, checked
        v, f = concat_meshes([(rv, split.solid_faces), *extra])
        c = clean_soup(v, f, solid=True)
        v, f = c.vertices, c.faces
    sv, sf = drop_unreferenced(v, f)
    return sv, sf, first_poly, first_hull_birth, checked


def hull_again(
    v32: np.ndarray,
    f32: np.ndarray,
    pairs: np.ndarray | None,
    extra: list[tuple[np.ndarray, np.ndarray]],
    eps: float,
    tally: RepairTally,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """The whole arrangement and outer hull taken again of a rounded mesh ``(v32, f32)``
    (float32 values) and ``extra`` solids, where mending it locally does not do.

    ``pairs``: all the crossing pairs of ``(v32, f32)``, if known. Then most faces of the
    cleaned union are faces of it, on the same points: they keep their pairs and only
    the region near the others is tested, both for the arrangement and for the check of
    the result, which gets them as ``before = (vertices, faces, pairs)`` (see
    :func:`repair.finish.rounded_verdict`; None when ``pairs`` is). The outer hull keeps
    most faces as they were, so that check too tests only near the faces it changed.
    """
    c = clean_soup(*concat_meshes([(v32, f32), *extra]), solid=True)
    known = None if pairs is None else carry_input_pairs(v32, f32, pairs, c.vertices, c.faces)
    v, f, _, _, _ = hull_and_thicken(c.vertices, c.faces, eps, tally, solid=True, pairs=known)
    return v, f, None if known is None else (c.vertices, c.faces, known)


def _sheet_solids(
    v: np.ndarray, f: np.ndarray, rv: np.ndarray, birth: np.ndarray, split: HullSplit,
    eps: float,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Closed solids that thicken the sheet, from as few and as whole triangles as
    possible. An input face all of whose outer-hull pieces are sheet is thickened whole,
    with its input neighbours (its pieces inside the solid vanish in the union anyway):
    slabs of whole triangles cross one another transversally instead of abutting along
    the arrangement's cut lines, which float32 rounding could not keep apart. A face
    that is partly solid hull gets one prism over the union of its sheet pieces, grown
    by a hair (``eps / 100``) so that it fuses with the solid it sticks out of."""
    sb = birth[split.sheet_index]
    mixed = np.isin(sb, birth[split.solid_index])
    whole = np.unique(sb[~mixed])
    out = [sheet_slabs(*drop_unreferenced(v, f[whole]), eps)] if len(whole) else []
    if np.any(mixed):
        owner = sb[mixed]
        p = v[f[owner]]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)  # clean_soup left no degenerate face
        out.append(region_prisms(rv, split.sheet_faces[mixed], owner, n, eps, 0.01 * eps))
    return out
