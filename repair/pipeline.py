"""As-exact-as-possible repair (Attene 2018, Sec. 4): any triangle soup in, a printable
solid out, thickened only where it has to be.

Stages (each timed in the report):

1. ``clean``   weld exactly coincident vertices, move degenerate triangles to a list of
   segments (wires), keep one layer of equivalent triangles (:mod:`repair.clean`);
   ``holes``: close the small holes of almost-closed shells with lids (:mod:`repair.holes`),
   so an open scan becomes a solid instead of a sheet;
2. ``resolve`` exact arrangement of the self-intersections (CGAL via libigl), so the
   triangles form a polyhedron (:mod:`repair.hull`);
3. ``hull``    cells of space; keep the faces that see the outside, split into the solid
   outer hull and zero-thickness sheets; internal faces and nested parts go;
4. ``thicken`` sheets become slabs of thickness eps, visible wires eps-prisms
   (:mod:`repair.thicken`, :mod:`repair.wires`), and stages 1-3 run again on the union;
5. ``finish``  round to float32 (what a binary STL stores), verify with
   :func:`repair.check.check_printable`, and resolve again if rounding broke anything
   (singular edges left by touching parts are thickened into eps-prisms the same way);
6. ``report``  manifold-connected parts, volume, Attene's deviation D.

Two fast paths keep exact inputs exact and quick: an input that is already printable
comes out unchanged, and an input made only of closed, edge-manifold shells that overlap
one another (a typical CAD export) is united by manifold3d's boolean union.

Units are mm. Arrays in and out: vertices float64 (n, 3), faces int64 (m, 3). No global
state: every call is independent (the daemon runs it in a child process).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from repair.check import (
    Printability,
    check_printable,
    check_printable_pairs,
    edge_components,
    edge_stats,
    intersecting_face_pairs,
    round_to_float32,
    verdict_given_pairs,
    weld_exact,
)
from repair.clean import Cleaned, clean_soup, degenerate_mask, drop_unreferenced, face_keys
from repair.deviation import max_deviation
from repair.holes import HolesClosed, close_small_holes
from repair.hull import (
    HullSplit,
    is_unorientable,
    outer_hull_split,
    resolve,
    unorientable_outer_hull,
)
from repair.mend import (
    crossings_after_change,
    is_cycle,
    mend_intersections,
    round_finding_crossings,
    separate_singular_edges,
)
from repair.rows import unique_ints, unique_rows
from repair.thicken import region_prisms, sheet_slabs
from repair.wires import cylinders, visible_segments

__all__ = ["RepairError", "RepairResult", "repair_file", "repair_mesh"]

Progress = Callable[[str, float], None] | None

#: Rounds of "round to float32, verify, resolve again" before giving up.
MAX_FINISH_ROUNDS = 12
#: From this finish round on, damaged faces first lose their float32-scale edges.
COLLAPSE_FROM = 1
#: Diameter of the prisms that fuse parts touching along an edge, as a fraction of eps.
SINGULAR_EDGE_DIAMETER = 0.1
#: Rounds of "thicken the sheets, take the outer hull of the union".
MAX_THICKEN_ROUNDS = 3


class RepairError(ValueError):
    """The input cannot be made printable; the message is one human-readable line."""


@dataclass(frozen=True)
class RepairResult:
    """A repaired mesh (mm; float64 (n, 3) vertices exactly representable in float32,
    int64 (m, 3) faces) and its JSON-serialisable report."""

    vertices: np.ndarray
    faces: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------- helpers


class _Clock:
    def __init__(self, progress: Progress) -> None:
        self.stages: dict[str, float] = {}
        self.progress = progress
        self._t = time.perf_counter()

    def lap(self, name: str, fraction: float) -> None:
        now = time.perf_counter()
        self.stages[name] = round(self.stages.get(name, 0.0) + now - self._t, 4)
        self._t = now
        if self.progress is not None:
            self.progress(name, fraction)


def _edge_use(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (k, 2) and how many faces use each."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return unique_rows(e, return_counts=True)


def _volumes(v: np.ndarray, f: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    a, b, c = v[f[:, 0]] - centre, v[f[:, 1]] - centre, v[f[:, 2]] - centre
    return np.bincount(labels, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0, minlength=n)


def _area(v: np.ndarray, f: np.ndarray) -> float:
    if len(f) == 0:
        return 0.0
    p = v[f]
    return float(0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())


def _concat(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    vs, fs, off = [], [], 0
    for v, f in parts:
        if len(f) == 0:
            continue
        vs.append(np.asarray(v, dtype=np.float64))
        fs.append(np.asarray(f, dtype=np.int64) + off)
        off += len(v)
    if not fs:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(vs), np.vstack(fs)


# --------------------------------------------------------------------------- fast paths


def _manifolds_of(
    v: np.ndarray, f: np.ndarray, labels: np.ndarray | None = None, *, keep_faces: bool = False
) -> list | None:
    """One manifold3d solid per edge-connected component of ``(v, f)`` (float32), or None
    if manifold3d rejects one. Much faster than ``Manifold.decompose`` on many pieces.
    ``keep_faces``: give each triangle its own face id, so that manifold3d keeps the
    input's triangles (cutting them where needed) instead of merging coplanar ones."""
    import manifold3d as m3d

    lab = edge_components(f) if labels is None else labels
    order = np.argsort(lab, kind="stable")
    cuts = np.r_[0, np.flatnonzero(np.diff(lab[order])) + 1, len(lab)]
    v32 = np.ascontiguousarray(v, dtype=np.float32)
    out = []
    for i in range(len(cuts) - 1):
        ff = f[order[cuts[i] : cuts[i + 1]]]
        used, inv = unique_ints(ff.reshape(-1), return_inverse=True)
        ids = {"face_id": order[cuts[i] : cuts[i + 1]].astype(np.uint32)} if keep_faces else {}
        solid = m3d.Manifold(
            m3d.Mesh(
                vert_properties=np.ascontiguousarray(v32[used]),
                tri_verts=np.ascontiguousarray(inv.reshape(-1, 3), dtype=np.uint32),
                **ids,
            )
        )
        if solid.status() != m3d.Error.NoError:
            return None
        out.append(solid)
    return out


def _starts_with(va: np.ndarray, fa: np.ndarray, vb: np.ndarray, fb: np.ndarray) -> bool:
    """True when the first ``len(fa)`` faces of ``(vb, fb)`` are those of ``(va, fa)``,
    row by row, on exactly the same points (cleaning that removed nothing, lids appended)."""
    n = len(fa)
    return len(fb) >= n and np.array_equal(vb[fb[:n]], va[fa])


def _same_faces(va: np.ndarray, fa: np.ndarray, vb: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """For each face of ``(vb, fb)``: a face of ``(va, fa)`` on the same three points
    (exactly equal coordinates, any order), or -1. Row by row when ``fb`` starts with
    ``fa``'s faces; else by one exact weld of both."""
    if len(fa) == 0:
        return np.full(len(fb), -1, dtype=np.int64)
    if _starts_with(va, fa, vb, fb):
        return np.r_[np.arange(len(fa)), np.full(len(fb) - len(fa), -1)]
    # One vertex numbering for both, by exact position.
    _, both = weld_exact(np.vstack([va, vb]), np.vstack([fa, fb + len(va)]))
    keys = face_keys(both)
    ka, kb = keys[: len(fa)], keys[len(fa) :]
    order = np.argsort(ka, kind="stable")
    pos = np.clip(np.searchsorted(ka[order], kb), 0, len(ka) - 1)
    return np.where(ka[order][pos] == kb, order[pos], -1)


def _union_hint(
    v_in: np.ndarray,
    f_in: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    union: _Union,
    out_v: np.ndarray,
    out_f: np.ndarray,
) -> np.ndarray:
    """For each written face (``out_v, out_f``, finished from ``union``, the union of
    ``(v, f)``): the face of ``(v_in, f_in)`` it is believed to
    be a piece of, or -1 (a guess, verified by :func:`repair.deviation.max_deviation`).
    Finishing keeps the union's faces in order unless it mended them."""
    to_input = _same_faces(v_in, f_in, v, f)  # lids: -1
    uv, uf = union.vertices, union.faces
    source = np.where(union.source >= 0, to_input[union.source], -1)
    if len(out_f) == len(uf):  # finished in one round: the same faces, rounded
        return source
    match = _same_faces(round_to_float32(uv), uf, out_v, out_f)
    return np.where(match >= 0, source[match], -1)


def _carry_pairs(
    v_in: np.ndarray, f_in: np.ndarray, pairs_in: np.ndarray, v: np.ndarray, f: np.ndarray
) -> np.ndarray:
    """The intersecting face pairs of ``(v, f)`` -- the cleaned input with lids added --
    from those of the input (``pairs_in``, indices into ``f_in``, found on the same
    coordinates): faces on the same three points as an input face keep its pairs, only
    the region near the others (lids) is tested. ``v_in`` must be float32-valued (as
    :func:`repair_mesh` makes it), the coordinates ``pairs_in`` were found on."""
    same, kept = _carried_pairs(_same_faces(v_in, f_in, v, f), len(f_in), pairs_in)
    return crossings_after_change(v, f, kept, ~same)


def _carried_pairs(
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


@dataclass(frozen=True)
class _Union:
    """The union of shells: its ``vertices`` and ``faces``; for each face, the ``source``
    face of the input it is a piece of; the input's ``shells`` (label per input face)."""

    vertices: np.ndarray
    faces: np.ndarray
    source: np.ndarray
    shells: np.ndarray

    def shells_dropped(self) -> int:
        """Input shells no piece of which is in the union (nested inside others)."""
        seen = np.zeros(int(self.shells.max()) + 1, dtype=bool)
        seen[self.shells[self.source[self.source >= 0]]] = True
        return int(np.count_nonzero(~seen))


def _union_fast_path(
    v: np.ndarray,
    f: np.ndarray,
    pairs: np.ndarray | None = None,
    census: tuple[int, int, int, int, np.ndarray | None] | None = None,
) -> _Union | None:
    """Exact union of closed, edge-manifold, consistently oriented shells that intersect
    only one another (never themselves), by manifold3d, which keeps the input's
    triangles, cut where the shells cross, and says which each piece is of. None when
    not applicable. ``pairs``: the intersecting face pairs of ``(v, f)`` if known;
    ``census``: :func:`repair.check.edge_stats` of ``f`` if known."""
    if len(f) == 0:
        return None
    # Every edge used by exactly two faces, in opposite directions; and the shells.
    if census is None or census[4] is None or len(census[4]) != len(f):
        census = edge_stats(f)
    boundary, nonmanifold, misoriented, n, labels = census
    if boundary or nonmanifold or misoriented:
        return None
    if pairs is None:
        pairs = intersecting_face_pairs(v, f)
    if len(pairs) and np.any(labels[pairs[:, 0]] == labels[pairs[:, 1]]):
        return None  # a shell intersects itself: needs the exact arrangement
    vol = _volumes(v, f, labels, n)
    if np.any(vol == 0.0):
        return None
    f = f.copy()
    inv = vol[labels] < 0
    f[inv] = f[inv][:, ::-1]
    if n == 1 and len(pairs) == 0:  # one closed shell, crossing nothing: it is the union
        uv, uf = drop_unreferenced(v, f)
        return _Union(uv, uf, np.arange(len(uf)), labels)
    import manifold3d as m3d

    try:
        parts = _manifolds_of(v, f, labels, keep_faces=True)
        if not parts:
            return None
        out = m3d.Manifold.batch_boolean(parts, m3d.OpType.Add) if len(parts) > 1 else parts[0]
        res = out.to_mesh64()
    except Exception:  # noqa: BLE001 - any failure means: take the exact path
        return None
    rv = np.asarray(res.vert_properties, dtype=np.float64)[:, :3]
    rf = np.asarray(res.tri_verts, dtype=np.int64)
    if len(rf) == 0:
        return None
    source = np.asarray(res.face_id, dtype=np.int64).reshape(-1)
    if len(source) != len(rf) or source.min() < 0 or source.max() >= len(f):
        return None  # provenance lost: take the exact path rather than guess
    return _Union(*weld_exact(rv, rf), source, labels)


def _manifold_union(
    parts: list[tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray] | None:
    """Union of closed oriented pieces -- the solid outer hull first (welded here), then
    sheet slabs, ledge prisms and wire cylinders (each already an indexed closed solid)
    -- by manifold3d's robust booleans; None if manifold3d rejects a piece. The result
    is verified (and resolved exactly if need be) by the caller's float32 check."""
    import manifold3d as m3d

    solids = []
    try:
        for i, (v, f) in enumerate(parts):
            if len(f) == 0:
                continue
            # The solid hull is welded; slabs, prisms and cylinders are each indexed
            # closed solids -- welding would fuse coincident corners of different ones.
            pieces = _manifolds_of(*drop_unreferenced(*(weld_exact(v, f) if i == 0 else (v, f))))
            if pieces is None:
                return None
            solids.extend(pieces)
        if not solids:
            return None
        out = m3d.Manifold.batch_boolean(solids, m3d.OpType.Add) if len(solids) > 1 else solids[0]
        # Collapse what float32 cannot hold apart anyway: slivers and sub-ulp features.
        size = max(float(np.abs(np.asarray(p[0])).max()) for p in parts if len(p[1]))
        out = out.simplify(size * 2.0**-17)
        res = out.to_mesh()
    except Exception:  # noqa: BLE001 - any failure means: take the exact path
        return None
    rv = np.asarray(res.vert_properties, dtype=np.float64)[:, :3]
    rf = np.asarray(res.tri_verts, dtype=np.int64)
    if len(rf) == 0:
        return None
    return weld_exact(rv, rf)


# --------------------------------------------------------------------------- exact path


@dataclass
class _Tally:
    intersecting_pairs: int = -1
    internal_faces: int = 0
    sheet_area: float = 0.0
    sheet_triangles: int = 0
    wires: int = 0
    singular_edges: int = 0
    separated: int = 0
    passes: int = 0
    collapsed: int = 0


def _outer_hull(
    v: np.ndarray,
    f: np.ndarray,
    eps: float,
    tally: _Tally,
    segments: np.ndarray | None = None,
    *,
    solid: bool = False,
    pairs: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Resolve, take the outer hull, thicken sheets/wires and repeat until no sheet is left.
    ``pairs``: the intersecting face pairs of ``(v, f)`` if known.

    Returns the closed solid ``(vertices, faces)`` plus the first pass's polyhedron and
    the birth face (into ``f``) of each of its outer-hull faces.
    """
    first_hull_birth = np.zeros(0, dtype=np.int64)
    first_poly = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    for round_ in range(MAX_THICKEN_ROUNDS + 1):
        tally.passes += 1
        if round_ == 0 and not solid and is_unorientable(f):
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
            first_poly = (rv, rf)
            first_hull_birth = birth[np.r_[split.solid_index, split.sheet_index]]
        extra: list[tuple[np.ndarray, np.ndarray]] = []
        if len(split.sheet_faces) and round_ < MAX_THICKEN_ROUNDS:
            tally.sheet_area += _area(rv, split.sheet_faces)
            tally.sheet_triangles += len(split.sheet_faces)
            extra.extend(_sheet_to_thicken(v, f, rv, birth, split, eps))
        if segments is not None and len(segments) and round_ == 0:
            hull_f = np.vstack([split.solid_faces, split.sheet_faces])
            vis = visible_segments(segments, rv, hull_f, split.solid_faces)
            tally.wires += len(vis)
            if len(vis):
                extra.append(cylinders(vis, eps))
        if not extra:
            sv, sf = drop_unreferenced(rv, split.solid_faces)
            return sv, sf, first_poly, first_hull_birth
        fused = _manifold_union([(rv, split.solid_faces), *extra])
        if fused is not None:
            sv, sf = fused
            return sv, sf, first_poly, first_hull_birth
        v, f = _concat([(rv, split.solid_faces), *extra])
        c = clean_soup(v, f, solid=True)
        v, f = c.vertices, c.faces
    sv, sf = drop_unreferenced(v, f)
    return sv, sf, first_poly, first_hull_birth


def _sheet_to_thicken(
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


def _damaged_faces(v: np.ndarray, f: np.ndarray, pairs: np.ndarray | None = None) -> np.ndarray:
    """Faces that are degenerate, duplicated, intersect another, or sit on an edge that is
    open, non-manifold or traversed twice the same way. ``pairs``: the intersecting face
    pairs of ``(v, f)`` if known (the test is pairwise: those among the faces not damaged
    otherwise are the ones a test of those faces finds)."""
    bad = degenerate_mask(v, f)
    s = np.sort(f, axis=1)
    _, inv, cnt = unique_rows(s, return_inverse=True, return_counts=True)
    bad |= cnt[inv.reshape(-1)] > 1
    he = np.stack([f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)], axis=1)
    _, einv, ecnt = unique_rows(np.sort(he, axis=1), return_inverse=True,
                              return_counts=True)  # fmt: skip
    _, hinv, hcnt = unique_rows(he, return_inverse=True, return_counts=True)
    bad_he = (ecnt[einv.reshape(-1)] != 2) | (hcnt[hinv.reshape(-1)] > 1)
    bad |= bad_he.reshape(-1, 3).any(axis=1)
    if pairs is None:
        ok = np.flatnonzero(~bad)
        pairs = ok[intersecting_face_pairs(v, f[ok])]
    else:
        pairs = pairs[~bad[pairs].any(axis=1)]
    bad[pairs.reshape(-1)] = True
    return np.flatnonzero(bad)


def _collapse_damaged(
    v: np.ndarray, f: np.ndarray, reach: float = 2.0**-18, pairs: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Merge the endpoints of the shortest edge of every damaged face when that edge is
    within float32 rounding scale (union-find over all such edges at once); the merged
    vertex keeps one endpoint's position, so nothing moves by more than ~4 ulps x chain.
    Returns ``(v, f)`` themselves when no edge is that short."""
    bad = _damaged_faces(v, f, pairs)
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
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(v)
    g = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    # Representative: the lowest vertex index of each group keeps its position.
    rep = np.full(lab.max() + 1, n, dtype=np.int64)
    np.minimum.at(rep, lab, np.arange(n))
    return v, rep[lab][f]


def _rounded_verdict(
    v: np.ndarray,
    f: np.ndarray,
    before: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, Printability, np.ndarray]:
    """Round to float32 avoiding crossings, weld, and check: ``(v32, f32, verdict,
    pairs)``. The crossings found while rounding are reused when the weld merged nothing
    (same faces, same coordinates: the same test). ``before = (v, f, pairs)``: a checked
    mesh this one was mended from, with all its crossing pairs; faces on the same points
    as one of its faces keep their pairs, and only the region near the others is tested.
    """
    known = None
    if before is not None:
        match = _same_faces(before[0], before[1], v, f)
        known = _carried_pairs(match, len(before[1]), before[2])
    r, found = round_finding_crossings(v, f, known=known)
    v32, f32 = weld_exact(r, f)
    if len(v32) == len(r):
        verdict, pairs = verdict_given_pairs(v32, f32, found)
    else:
        verdict, pairs = check_printable_pairs(v32, f32)
    return v32, f32, verdict, pairs


def _finish(
    v: np.ndarray,
    f: np.ndarray,
    eps: float,
    tally: _Tally,
    before: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, Printability]:
    """Round to float32, verify, and mend until the written mesh is printable.

    A closed surface is mended where it is damaged (:mod:`repair.mend`: exact local
    arrangement of the crossing faces, winding-number choice of the pieces); from the
    second round on, the shortest edge of each damaged face is first collapsed when it is
    at float32-rounding scale, so that rounding cannot keep re-creating the same slivers.
    Edges shared by more than two faces (parts touching along an edge) first get one
    copy per part, a few ulps apart (:func:`repair.mend.separate_singular_edges`); where
    that leaves more damage, they are thickened into thin prisms that fuse the parts. An
    open result takes the whole arrangement and outer hull again.

    ``before = (v, f, pairs)``: a mesh whose crossing pairs are all known, on float32
    points, that ``(v, f)`` was made from (a union of shells keeps most of their faces):
    faces on the same points keep their pairs, only the region near the others is
    tested. A mend passes its own on to the next round the same way.
    """
    verdict: Printability | None = None
    tried_separation = False
    worse = 0
    last_damage = None
    for round_ in range(MAX_FINISH_ROUNDS):
        v32, f32, verdict, pairs = _rounded_verdict(v, f, before)
        before = None
        if verdict.ok:
            return v32, f32, verdict
        damage = verdict.intersecting_pairs + verdict.degenerate_faces + verdict.nonmanifold_edges
        grew = last_damage is not None and damage > last_damage
        if grew:
            worse += 1
            if worse >= 4:  # diverging: give up rather than grow without bound
                break
        last_damage = damage
        if len(f32) == 0:
            break
        tally.passes += 1
        # Mend locally while that shrinks the damage; where rounding keeps re-creating it
        # (crossing thin slabs), take the whole arrangement and outer hull again instead.
        local = is_cycle(f32) and not grew
        changed = None  # faces whose corners a collapse moved (pairs known for the rest)
        if (round_ >= COLLAPSE_FROM or not local) and (
            verdict.intersecting_pairs or verdict.degenerate_faces
        ):
            # Growing reach (still far below a nozzle) when damage keeps coming back.
            reach = 2.0 ** (-18 + min(max(round_ - COLLAPSE_FROM, 0), 6))
            collapsed = _collapse_damaged(v32, f32, reach, pairs)
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
        extra: list[tuple[np.ndarray, np.ndarray]] = []
        clean_touch = verdict.nonmanifold_edges and not (
            verdict.intersecting_pairs or verdict.degenerate_faces
        )
        if clean_touch and not tried_separation and not verdict.boundary_edges:
            # Parts that touch along an edge: first try giving each its own copy of the
            # edge, a few ulps apart (exact elsewhere); kept if that leaves less damage
            # once rounded (a copy may cross a face close by), else fused below.
            tried_separation = True
            step = float(np.abs(v32).max()) * 2.0**-17
            sep = separate_singular_edges(v32, f32, step)
            if sep is not None:
                tried = _rounded_verdict(*sep[:2], None if pairs is None else (v32, f32, pairs))
                trial = tried[2]
                left = trial.intersecting_pairs + trial.degenerate_faces
                if left + trial.nonmanifold_edges < verdict.nonmanifold_edges:
                    v, f, tally.separated = sep
                    if trial.ok:  # what the next round would find: done
                        return tried[0], tried[1], trial
                    continue
        if clean_touch:
            # Parts that touch along an edge: thicken the edge so they fuse.
            edges, cnt = _edge_use(f32)
            sing = edges[cnt > 2]
            tally.singular_edges += len(sing)
            extra.append(cylinders(v32[sing], eps * SINGULAR_EDGE_DIAMETER))
            pairs = None
        if local and is_cycle(f32):
            mv, mf = _concat([(v32, f32), *extra])
            try:
                md = mend_intersections(mv, mf, pairs)
            except (RuntimeError, ValueError, IndexError):
                md = None  # libigl refused the subset: take the whole outer hull below
            if md is not None:
                if pairs is not None and not extra:
                    before = (mv, mf, pairs)
                v, f = md.vertices, md.faces
                continue
        c = clean_soup(*_concat([(v32, f32), *extra]), solid=True)
        v, f, _, _ = _outer_hull(c.vertices, c.faces, eps, tally, solid=True)
    assert verdict is not None
    v32, f32 = weld_exact(round_to_float32(v), f)
    return v32, f32, check_printable(v32, f32)


# --------------------------------------------------------------------------- entry points


def repair_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    epsilon: float = 0.4,
    *,
    progress: Progress = None,
) -> RepairResult:
    """Repair a triangle soup into a printable solid, as exactly as possible.

    ``vertices`` (n, 3) mm, ``faces`` (m, 3) indices; ``epsilon`` (mm, > 0) is the
    thickness given to zero-thickness sheets and the diameter given to wires -- the
    printer's nozzle diameter. Solid parts are kept exactly (their outer hull); only
    sheets and wires move the surface, by at most ``0.6 * epsilon``.

    The result's coordinates are float32 values (what a binary STL stores) and it passes
    :func:`repair.check.check_printable` on them, or :class:`RepairError` is raised. The
    input is rounded to float32 first (an STL already is): solid parts come out on their
    rounded corners either way, and the arrangement then rounds once, not twice. The
    reported deviation D includes that rounding.
    """
    eps = float(epsilon)
    if not np.isfinite(eps) or eps <= 0:
        raise RepairError(f"epsilon must be a positive number of mm, got {epsilon!r}")
    v_in = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f_in = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f_in) == 0:
        raise RepairError("nothing printable: the mesh has no triangles")
    if not np.all(np.isfinite(v_in)):
        raise RepairError("vertex coordinates are not all finite")
    if f_in.min() < 0 or f_in.max() >= len(v_in):
        raise RepairError("face indices out of range")

    clock = _Clock(progress)
    # The output is written in float32 (binary STL): repair what will be written. Solid
    # parts come out on their rounded corners either way; rounding the input first (as an
    # STL input already is) keeps the arrangement from having to round twice.
    v32 = round_to_float32(v_in)
    rounding = float(np.sqrt(np.max(np.einsum("ij,ij->i", v32 - v_in, v32 - v_in))))
    v_in = v32
    before, pairs_in = check_printable_pairs(v_in, f_in, as_float32=True)
    clock.lap("check_input", 0.1)
    report: dict[str, Any] = {
        "epsilon": eps,
        "before": {
            "triangles": int(len(f_in)),
            "vertices": int(len(v_in)),
            "components": before.components,
            "boundary_edges": before.boundary_edges,
            "nonmanifold_edges": before.nonmanifold_edges,
            "misoriented_edges": before.misoriented_edges,
            "degenerate_faces": before.degenerate_faces,
            "duplicate_faces": before.duplicate_faces,
            "intersecting_pairs": before.intersecting_pairs,
            "volume": before.volume,
            "printable": before.ok,
        },
    }
    tally = _Tally()
    degenerate_removed = duplicates_removed = dropped_components = 0
    holes = HolesClosed()

    if before.ok:
        path = "unchanged"
        # The check proved these very float32 coordinates: no weld, no copy; D is how far
        # rounding to them moved the input (0 for an STL).
        out_v, out_f = v_in, f_in
        verdict = before
        deviation = rounding
        clock.lap("finish", 0.9)
    else:
        if before.degenerate_faces == 0 and before.duplicate_faces == 0:
            # The check (on the same welded coordinates) found nothing for cleaning to
            # remove: the welded input is the cleaned input.
            c = Cleaned(*drop_unreferenced(*weld_exact(v_in, f_in)), np.zeros((0, 2, 3)), 0, 0)
        else:
            c = clean_soup(v_in, f_in)
        degenerate_removed, duplicates_removed = c.degenerate_removed, c.duplicates_removed
        clock.lap("clean", 0.2)
        if len(c.faces) == 0 and len(c.segments) == 0:
            raise RepairError(
                f"nothing printable: all {len(f_in)} triangles collapse to a single point"
            )
        cv, cf, holes = close_small_holes(c.vertices, c.faces)
        clock.lap("holes", 0.25)
        fast = None
        known = _carry_pairs(v_in, f_in, pairs_in, cv, cf)
        if len(c.segments) == 0:
            # The input check's edge census holds for the same faces (cleaning and lids
            # changed nothing); else the fast path takes its own.
            same = len(cf) == len(f_in) and _starts_with(v_in, f_in, cv, cf)
            census = (before.boundary_edges, before.nonmanifold_edges, before.misoriented_edges,
                      before.components, before.shells) if same else None  # fmt: skip
            fast = _union_fast_path(cv, cf, known, census)
        clock.lap("union", 0.4)
        verdict = None
        hint = None  # per output face: the input face it lies on, if known
        if fast is not None:
            # A shell that is its own union keeps the crossings found on it (none): only
            # its lids' corners round. (Where the union cut faces, the cut ones and
            # those near them are a large part of the mesh: a whole test is cheaper.)
            whole = len(fast.faces) == len(cf) and np.array_equal(fast.source, np.arange(len(cf)))
            fv, ff, verdict = _finish(fast.vertices, fast.faces, eps, tally,
                                      (cv, cf, known) if whole else None)  # fmt: skip
            clock.lap("finish", 0.7)
        if verdict is not None and verdict.ok:
            path = "union"
            out_v, out_f = fv, ff
            # The input face each written face is a piece of, where finishing kept it
            # (its corners rounded to nearest): D bounds those without samples.
            hint = _union_hint(c.vertices, c.faces, cv, cf, fast, out_v, out_f)
            tally.intersecting_pairs = before.intersecting_pairs
            # Lids close holes of a shell and make no shell of their own.
            dropped_components = fast.shells_dropped()
        else:
            path = "exact"
            sv, sf, poly, hull_birth = _outer_hull(cv, cf, eps, tally, c.segments, pairs=known)
            clock.lap("hull_and_thicken", 0.6)
            if len(cf):
                comp_in = edge_components(cf)
                seen = np.unique(comp_in[hull_birth]) if len(hull_birth) else []
                dropped_components = int(comp_in.max()) + 1 - len(seen)
            if len(sf) == 0:
                raise RepairError(
                    "nothing printable: no part of the model can be reached from outside"
                )
            out_v, out_f, verdict = _finish(sv, sf, eps, tally)
            clock.lap("finish", 0.8)
            if not verdict.ok:
                raise RepairError(
                    "could not make the model printable: " + "; ".join(verdict.failures())
                )
        # Measured against the rounded input; the input itself is at most `rounding` away
        # from it (each rounded face lies within its corners' displacement of the original).
        deviation = rounding + max_deviation(
            out_v, out_f, c.vertices, c.faces, c.segments,
            max_points=400_000 if path == "exact" else 0, hint=hint,
        )  # fmt: skip
        clock.lap("deviation", 0.95)

    if verdict.components == 1:  # the check already counted: skip relabelling
        n_parts = 1
        part_vol = np.array([verdict.volume])
        part_tris = np.array([len(out_f)])
    else:
        known = verdict.shells is not None and len(verdict.shells) == len(out_f)
        labels = verdict.shells if known else edge_components(out_f)
        n_parts = int(labels.max()) + 1 if len(labels) else 0
        part_vol = _volumes(out_v, out_f, labels, n_parts) if n_parts else np.zeros(0)
        part_tris = np.bincount(labels, minlength=n_parts)
    order = np.argsort(-part_vol)
    report["after"] = {
        "triangles": int(len(out_f)),
        "vertices": int(len(out_v)),
        "components": n_parts,
        "degenerate_removed": int(degenerate_removed),
        "duplicates_removed": int(duplicates_removed),
        "intersecting_pairs_resolved": int(max(tally.intersecting_pairs, 0)),
        "internal_triangles_dropped": int(tally.internal_faces),
        "components_dropped_internal": int(dropped_components),
        "sheet_triangles_thickened": int(tally.sheet_triangles),
        "sheet_area_thickened": round(float(tally.sheet_area), 6),
        "wires_inflated": int(tally.wires),
        "singular_edges_thickened": int(tally.singular_edges),
        "singular_edges_separated": int(tally.separated),
        "arrangement_passes": int(tally.passes),
    }
    report["holes_closed"] = holes.to_dict()
    report["path"] = path
    report["deviation"] = deviation
    report["deviation_over_epsilon"] = deviation / eps
    report["volume"] = verdict.volume
    report["parts"] = [
        {"triangles": int(part_tris[i]), "volume": float(part_vol[i])} for i in order[:50]
    ]
    report["printable"] = verdict.to_dict()
    clock.lap("report", 1.0)
    report["stages"] = dict(clock.stages)
    report["seconds"] = round(sum(clock.stages.values()), 4)
    report["summary"] = _summary(report)
    return RepairResult(out_v, out_f, report)


def _summary(r: dict[str, Any]) -> str:
    a, b = r["after"], r["before"]
    if r["path"] == "unchanged":
        return f"already printable: {b['triangles']} triangles kept unchanged"
    fixes = []
    for key, label in (
        ("degenerate_removed", "degenerate triangles removed"),
        ("duplicates_removed", "duplicate triangles removed"),
        ("intersecting_pairs_resolved", "intersecting pairs resolved"),
        ("components_dropped_internal", "internal parts dropped"),
        ("internal_triangles_dropped", "internal triangles dropped"),
        ("wires_inflated", "wires inflated"),
        ("singular_edges_thickened", "singular edges thickened"),
    ):
        if a.get(key):
            fixes.append(f"{a[key]} {label}")
    h = r.get("holes_closed") or {}
    if h.get("count"):
        fixes.append(f"{h['count']} small hole(s) closed ({h['area']:.4g} mm² of lid)")
    if h.get("flaps_removed"):
        fixes.append(f"{h['flaps_removed']} flap triangle(s) beside holes removed")
    if a["sheet_triangles_thickened"]:
        fixes.append(
            f"{a['sheet_area_thickened']:.4g} mm² of sheet thickened to {r['epsilon']:g} mm"
        )
    if b["misoriented_edges"] or b["volume"] < 0:
        fixes.append("orientation fixed")
    what = ", ".join(fixes) if fixes else "re-oriented and closed"
    return (
        f"{b['triangles']} -> {a['triangles']} triangles in {a['components']} part(s), "
        f"{r['volume']:.6g} mm³, D = {r['deviation']:.3g} mm: {what}"
    )


def repair_file(
    in_path: str | Path,
    out_path: str | Path,
    *,
    epsilon: float = 0.4,
    report_path: str | Path | None = None,
    max_bytes: int | None = None,
    max_triangles: int | None = None,
    progress: Progress = None,
) -> dict[str, Any]:
    """Load a mesh file (STL/OBJ/PLY/3MF), repair it, write a binary STL at ``out_path``
    and, if asked, the report as JSON at ``report_path``. Returns the report.

    Raises :class:`repair.io.MeshReadError` for unreadable input and :class:`RepairError`
    when nothing printable can be made of it.
    """
    from repair.io import load_mesh, write_stl

    t0 = time.perf_counter()
    mesh = load_mesh(in_path, max_bytes=max_bytes, max_triangles=max_triangles)
    t_load = time.perf_counter() - t0
    if progress is not None:
        progress("load", 0.05)
    result = repair_mesh(mesh.vertices, mesh.faces, epsilon, progress=progress)
    t1 = time.perf_counter()
    write_stl(out_path, result.vertices, result.faces)
    report = dict(result.report)
    report["stages"] = {"load": round(t_load, 4), **report["stages"],
                        "write": round(time.perf_counter() - t1, 4)}  # fmt: skip
    report["input"] = {"path": str(in_path), "format": mesh.source_format,
                       "unit_scale": mesh.unit_scale}  # fmt: skip
    report["output"] = str(out_path)
    if report_path is not None:
        Path(report_path).write_text(json.dumps(report, indent=2) + "\n")
    return report
