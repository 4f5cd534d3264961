"""Stages 2-3 of the repair (Attene Sec. 4.1-4.2): polyhedron, then its outer hull.

``resolve`` turns a regular layer into a polyhedron (Def. 3.7): CGAL's exact arrangement
(libigl ``remesh_self_intersections``) splits every pair of intersecting triangles along
their intersection, and coincident vertices are welded. ``outer_hull_split`` labels the
cells of space the polyhedron bounds (libigl ``extract_cells``, cell 0 is the unbounded
one) and splits the faces that see the outside into ``solid`` (outside on one side only,
oriented to face it: the solid outer hull, Def. 3.9) and ``sheet`` (outside on both
sides). Faces that do not see the outside are internal and are dropped. A polyhedron of
several components has the largest one's cells extracted on its own and the parts nested
by winding numbers (libigl's exact nesting is slow against a big component), falling
back to the one libigl call wherever a winding number is unclear.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.clean import cancel_opposite_faces, degenerate_mask, drop_unreferenced
from repair.intersections import intersecting_face_pairs
from repair.rays import RayCaster, ray_hits
from repair.rows import unique_ints
from repair.thicken import orient_patches, orient_patches_with_edge_use
from repair.topology import (
    connected_labels,
    count_duplicate_faces,
    edge_components,
    edge_ids,
    face_keys,
    unique_faces,
    weld_exact,
)
from repair.winding import winding_numbers

#: Re-mesh only the intersecting faces, component by component, from this many faces.
LOCAL_REMESH_MIN_FACES = 2000
#: Arrange the components on several CPUs from this many crossing faces.
PARALLEL_MIN_ARRANGED = 200
#: Components of more crossing faces are arranged in pieces of at most this many
#: (:func:`_pieces`).
PIECE_FACES = 128

__all__ = [
    "HullSplit",
    "is_unorientable",
    "outer_hull_split",
    "resolve",
    "unorientable_outer_hull",
]


def _remesh_all(
    v: np.ndarray, f: np.ndarray, k: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """libigl's exact arrangement of ``(v, f)`` in one call: (vertices, faces, birth into
    ``f``, intersecting pairs found). ``k``: the power of two the coordinates are scaled
    by (default :func:`_integer_scale` of ``v``)."""
    import igl.copyleft.cgal as cgal

    v = np.ascontiguousarray(v, dtype=np.float64)
    k = _integer_scale(v) if k is None else k
    vv, ff, pairs, birth, im = cgal.remesh_self_intersections(
        np.ldexp(v, k), np.ascontiguousarray(f, dtype=np.int64), stitch_all=True,
        cutoff=2**31 - 1,
    )  # fmt: skip
    ff = np.asarray(im, dtype=np.int64)[np.asarray(ff, dtype=np.int64)]
    vv = np.ldexp(np.asarray(vv, dtype=np.float64), -k)
    return vv, ff, np.asarray(birth, dtype=np.int64), len(pairs)


def _integer_scale(v: np.ndarray) -> int:
    """The power of two ``k`` that makes every coordinate of ``v`` an integer of at most
    53 bits (0 if none does, or they already are). Scaling by a power of two is exact,
    and so is rounding the arrangement's exact points back (the same doubles, scaled),
    but CGAL's exact rationals of integer input stay shorter: mikedh_soup's arrangement
    took 1.86 s of CPU against 2.16 (medians of 6). Only the faces' triangulation
    differs (CGAL projects each face into its plane by a basis that does not scale)."""
    x = np.abs(v[v != 0])
    if len(x) == 0:
        return 0
    m, e = np.frexp(x)  # x = m 2^e, m in [0.5, 1)
    bits = np.ldexp(m, 53).astype(np.int64)  # exact: 53-bit integers
    low = (bits & -bits).astype(np.float64)  # lowest set bit
    lowest = int((np.frexp(low)[1] - 1 + e - 53).min())  # exponent of the lowest bit
    k = -lowest
    if k <= 0 or int(np.frexp(x.max())[1]) + k > 53:
        return 0
    return k


def _remesh(
    v: np.ndarray, f: np.ndarray, pairs: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One exact arrangement pass: (vertices, faces, birth face, intersecting pairs).

    Only the faces that intersect another are re-meshed: a face that meets no other one
    beyond a shared vertex or edge cannot be split (a split point on its edge would lie
    on the face across that edge too, so that face would be in a pair). For the same
    reason the groups of faces linked by crossings (components of the pair graph) are
    independent: each is arranged on its own, side by side on the CPUs
    (:func:`repair.workers.map_forked`), and the output is the same for any number of
    them. The new faces get their own copies of the vertices, to be merged by an exact
    weld. Small meshes, and meshes whose faces repeat a vertex triple, are arranged
    whole in one call.
    """
    from repair.workers import balanced_shares, cpu_workers, map_forked

    v = np.ascontiguousarray(v, dtype=np.float64)
    f = np.ascontiguousarray(f, dtype=np.int64)
    if len(f) < LOCAL_REMESH_MIN_FACES or count_duplicate_faces(f):
        return _remesh_all(v, f)
    if pairs is None:
        pairs = intersecting_face_pairs(v, f)
    if len(pairs) == 0:
        return v, f, np.arange(len(f)), 0
    hit = np.unique(pairs)
    local = np.searchsorted(hit, pairs)
    lab = connected_labels(len(hit), local[:, 0], local[:, 1])
    order = np.argsort(lab, kind="stable")
    cuts = np.flatnonzero(np.diff(lab[order])) + 1
    groups = np.split(hit[order], cuts)  # by lowest face first (labels follow hit order)
    jobs = [job for g_ in groups for job in _pieces(v, f, g_, pairs)]

    def arrange(job: tuple[np.ndarray, np.ndarray, int | None]) -> tuple[np.ndarray, ...]:
        faces, kept, k = job
        # libigl's cost grows with all the vertices it is given: give it the few used.
        sv, sf = drop_unreferenced(v, f[faces])
        vv, ff, birth, _ = _remesh_all(sv, sf, k)
        keep = kept[birth]
        vv, ff = drop_unreferenced(vv, ff[keep])
        return vv, ff, faces[birth[keep]]

    # libigl's time grows with a job's faces and, about as much each, its crossing
    # pairs (coplanar ones cost more): share the jobs out by both.
    sizes = [len(faces) + int(np.count_nonzero(np.isin(pairs, faces).any(axis=1)))
             for faces, _, _ in jobs]  # fmt: skip
    workers = cpu_workers() if len(hit) >= PARALLEL_MIN_ARRANGED else 1
    parts = map_forked(arrange, jobs, balanced_shares(sizes, workers))
    # New vertices after the input's, each part's after the last; faces by birth.
    out_v, out_f, out_b = [v], [], []
    rest = np.ones(len(f), dtype=bool)
    rest[hit] = False
    keep = np.flatnonzero(rest)
    out_f.append(f[keep])
    out_b.append(keep)
    offset = len(v)
    for vv, ff, birth in parts:
        out_v.append(vv)
        out_f.append(ff + offset)
        out_b.append(birth)
        offset += len(vv)
    vs, fs, bs = np.vstack(out_v), np.vstack(out_f), np.concatenate(out_b)
    by_birth = np.argsort(bs, kind="stable")  # input order, as a whole-mesh pass gives
    return vs, fs[by_birth], bs[by_birth], len(pairs)


def _pieces(
    v: np.ndarray, f: np.ndarray, group: np.ndarray, pairs: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray, int | None]]:
    """Jobs that arrange the faces ``group`` (a component of the crossing ``pairs``):
    ``(faces given to libigl, which of them to keep, scale k or None: their own)``. A
    face's pieces depend only on the faces it crosses and the scale, so a group of more
    than :data:`PIECE_FACES` faces is cut in halves at the median of their centroids
    along its longest side, again and again, each half arranged with the faces it
    crosses at the group's scale and only its own faces' pieces kept: the same pieces
    in the same order, from jobs that side by side on several CPUs take a fraction of
    the time (chair: one group of 413 faces and 543 pairs, 0.17 s of libigl; each half
    crosses 6 faces of the other). A piece is not cut where its halves would cross an
    eighth of its faces again (libigl would arrange those twice)."""
    whole = [(group, np.ones(len(group), dtype=bool), None)]
    if len(group) <= PIECE_FACES:
        return whole
    c = v[f[group]].mean(axis=1)  # group: ascending face ids
    inside = np.zeros(len(f), dtype=bool)

    def call(own: np.ndarray) -> np.ndarray:  # own faces and those they cross
        inside[own] = True
        meets = pairs[inside[pairs].any(axis=1)].reshape(-1)
        inside[own] = False
        return np.union1d(own, meets)

    stack, jobs = [(np.arange(len(group)), group)], []
    while stack:
        at, given = stack.pop()  # positions in group, faces given to libigl
        if len(at) > PIECE_FACES:
            by = at[np.argsort(c[at, int(np.argmax(np.ptp(c[at], axis=0)))], kind="stable")]
            halves = [np.sort(by[len(by) // 2 :]), np.sort(by[: len(by) // 2])]
            calls = [call(group[h]) for h in halves]
            if 8 * (len(calls[0]) + len(calls[1])) <= 9 * len(given):
                stack += list(zip(halves, calls, strict=True))
                continue
        jobs.append((given, np.isin(given, group[at])))
    if len(jobs) == 1:
        return whole
    k = _integer_scale(v[unique_ints(f[group].reshape(-1))])
    return [(given, kept, k) for given, kept in jobs]


def resolve(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    max_rounds: int = 4,
    solid: bool = False,
    pairs: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Make ``(vertices, faces)`` a polyhedron: no two faces meet except in a shared edge
    or vertex, no degenerate and no duplicate faces.

    Exact intersection points are rounded to doubles; points that round together are
    welded, and faces that this collapses are dropped and the arrangement recomputed (a
    face made collinear leaves a T-junction the next pass splits exactly).

    With ``solid=True`` (the input is a closed oriented surface, e.g. a result rounded to
    float32) coincident faces cancel by orientation instead of keeping one layer.

    ``pairs``: the intersecting face pairs of the input, if known (spares the first test).
    Returns ``(vertices, faces, birth, pairs)``: ``birth[i]`` is the input face face ``i``
    came from; ``pairs`` counts the intersecting face pairs found by the first pass.
    """
    from repair.rounding import crossings_after_change

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    birth = np.arange(len(f))
    first_pairs = -1
    for _ in range(max_rounds):
        if len(f) == 0:
            break
        n_before = len(v)
        v, f, b, n_pairs = _remesh(v, f, pairs)
        pairs = None
        # Faces on a vertex the arrangement made (its new vertices come after the old).
        new = (f >= n_before).any(axis=1)
        birth = birth[b]
        if first_pairs < 0:
            first_pairs = n_pairs
        v, f = weld_exact(v, f)
        deg = degenerate_mask(v, f)
        keep = np.flatnonzero(~deg)
        keep = keep[(cancel_opposite_faces if solid else unique_faces)(f[keep])]
        changed = len(keep) != len(f)
        f, birth, new = f[keep], birth[keep], new[keep]
        v, f = drop_unreferenced(v, f)
        if not changed and n_pairs == 0:
            break
        if not changed and not np.any(deg):
            # The arrangement is exact and nothing was collapsed: it is a polyhedron.
            break
        if len(f) >= LOCAL_REMESH_MIN_FACES and np.count_nonzero(new) <= len(f) // 5:
            # The faces the pass left alone crossed nothing and still do not (their
            # corners did not move): only near the new ones can rounding have made
            # crossings. (Collapsed faces are gone; welding moves no point.)
            pairs = crossings_after_change(v, f, np.zeros((0, 2), dtype=np.int64), new)
    return v, f, birth, max(first_pairs, 0)


@dataclass(frozen=True)
class HullSplit:
    """The outer hull of a polyhedron split into solid and sheet faces (indices into the
    polyhedron's faces). ``solid_faces`` are oriented outward. ``internal`` counts faces
    that cannot be reached from outside."""

    solid_faces: np.ndarray
    sheet_faces: np.ndarray
    solid_index: np.ndarray
    sheet_index: np.ndarray
    internal: int
    cells: int


def _boundary_faces(faces: np.ndarray) -> np.ndarray:
    """Indices of faces with at least one edge used by no other face."""
    eid, cnt = edge_ids(faces)
    return np.unique(np.flatnonzero(cnt[eid] == 1) // 3)


def _merge_cells_at_boundaries(cells: np.ndarray, bf: np.ndarray, n_cells: int) -> np.ndarray:
    """libigl labels the two sides of an open patch as different cells; they are one
    region of space, connected around the patch's boundary (faces ``bf``, see
    :func:`_boundary_faces`). Merge them (cell 0, the unbounded one, keeps its label)."""
    if len(bf) == 0:
        return cells
    label = connected_labels(n_cells, cells[bf, 0], cells[bf, 1])
    # Relabel so that whatever merged with cell 0 is 0.
    label = np.where(label == label[0], 0, label + 1)
    return label[cells]


def is_unorientable(faces: np.ndarray) -> bool:
    """True when some edge used by exactly two faces stays traversed twice the same way
    after :func:`repair.thicken.orient_patches` (a Klein bottle, a Moebius strip)."""
    _, cut, use = orient_patches_with_edge_use(np.asarray(faces, dtype=np.int64))
    return bool(np.any(cut & (use == 2)))


def unorientable_outer_hull(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, HullSplit]:
    """Outer hull of an unorientable surface by libigl's ``outer_hull`` (Attene's
    propagation over radially sorted fans, with its own exact arrangement), where cell
    extraction needs orientable patches. Returns ``(vertices, faces, birth, split)``:
    the hull's faces (birth: input face of each) and their split into solid faces and
    sheets (faces kept in both orientations)."""
    import igl.copyleft.cgal as cgal

    hv, hf, birth, _ = cgal.outer_hull(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
    )
    hv = np.asarray(hv, dtype=np.float64)
    hf = np.asarray(hf, dtype=np.int64)
    birth = np.asarray(birth, dtype=np.int64)
    _, inv, cnt = unique_ints(face_keys(hf), return_inverse=True, return_counts=True)
    both = cnt[inv] > 1
    _, first = np.unique(inv[both], return_index=True)
    sheet_rows = np.flatnonzero(both)[first]
    solid_rows = np.flatnonzero(~both)
    internal = int(len(faces) - len(np.unique(birth)))
    split = HullSplit(hf[solid_rows], hf[sheet_rows], solid_rows, sheet_rows, internal, -1)
    return hv, hf, birth, split


def _outside_sides(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """For each face of a polyhedron: does its positive / negative side see the unbounded
    cell (libigl ``extract_cells``, open patches' two sides merged)? Also the cell count."""
    import igl.copyleft.cgal as cgal

    n_cells, cells = cgal.extract_cells(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
    )
    bf = _boundary_faces(faces)
    cells = _merge_cells_at_boundaries(np.asarray(cells, dtype=np.int64), bf, int(n_cells))
    if len(bf):
        # Among open patches libigl's labels of the regions of space hold face by face,
        # but it splits the unbounded region into several labels (or misses it, e.g.
        # among crossing sheets that enclose cells between them): find them by rays.
        cells = np.where(np.isin(cells, unbounded_cells(vertices, faces, cells)), 0, cells)
    return cells[:, 0] == 0, cells[:, 1] == 0, int(n_cells)


#: At most this many rays in all are cast by :func:`unbounded_cells`, and at most
#: :data:`MAX_CELL_RAY_TESTS` ray-triangle tests (each ray is tested against every face).
MAX_CELL_RAYS = 3000
MAX_CELL_RAY_TESTS = 20_000_000


def unbounded_cells(vertices: np.ndarray, faces: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The labels (in ``cells``, (m, 2): the region on the positive and the negative side
    of each face) of regions that reach infinity: a ray from a hair off one of their
    faces leaves the model without meeting another face. Up to 8 faces per region and
    6 directions per face are tried (away from the model's centre first), largest
    regions first, within :data:`MAX_CELL_RAYS` rays and :data:`MAX_CELL_RAY_TESTS`
    ray-triangle tests in all (each ray is tested against the region's own faces first,
    which a bounded region's rays meet, then culls by bounding spheres,
    :class:`repair.rays.RayCaster`). Float ray tests: a grazing hit only makes a ray
    fail, never pass wrongly."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = v[f]
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    cen = p.mean(axis=1)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    hair = float(np.ptp(v, axis=0).max()) * 2.0**-26
    dirs = np.random.default_rng(0).normal(size=(4, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    labels, counts = np.unique(cells, return_counts=True)
    caster = RayCaster(p)
    out: list[int] = []
    budget = min(MAX_CELL_RAYS, MAX_CELL_RAY_TESTS // max(len(f), 1))
    for lab in labels[np.argsort(-counts, kind="stable")].tolist():
        if lab == 0:
            continue  # libigl's own unbounded cell
        own_side = cells == lab
        sides = np.argwhere(own_side)
        own = np.flatnonzero(own_side.any(axis=1))
        sides = sides[np.linspace(0, len(sides) - 1, min(8, len(sides))).astype(int)]
        for face, col in sides.tolist():
            sign = 1.0 if col == 0 else -1.0
            normal = sign * n[face]
            if not normal.any():
                continue
            away = cen[face] - centre
            tries = np.vstack([away, normal, dirs])
            tries = tries[tries @ normal > 1e-9 * np.linalg.norm(tries, axis=1)]
            origin = cen[face] + hair * normal
            escaped = False
            # A bounded region's rays leave it through its own faces: test those first,
            # all at once (a hit on any face is a hit: the same answer, only cheaper),
            # unless they are more than one culling pass over all faces would cost.
            units = np.array([d / np.linalg.norm(d) for d in tries]).reshape(-1, 3)
            blocked = np.zeros(len(units), dtype=bool)
            if len(own) * len(units) <= len(f):
                blocked = ray_hits(origin, units, p[own[own != face]]).any(axis=1)
            for unit, own_hit in zip(units, blocked, strict=True):
                budget -= 1
                if own_hit:
                    continue
                if not caster.hits_any(origin, unit, face):
                    escaped = True
                    break
            if escaped:
                out.append(lab)
                break
            if budget <= 0:
                return np.asarray(out, dtype=np.int64)
    return np.asarray(out, dtype=np.int64)


def _encloses(
    vertices: np.ndarray, faces: np.ndarray, pos_out: np.ndarray, neg_out: np.ndarray,
    points: np.ndarray,
) -> np.ndarray | None:
    """Which ``points`` (off the faces) lie in a bounded cell of the polyhedron ``faces``:
    the winding number of its solid outer hull (faces with the unbounded cell on one side,
    turned to face it -- a closed cycle) is 1 there and 0 outside. None when a number is
    not clearly an integer (a point too close to the hull for floating point)."""
    solid = pos_out ^ neg_out
    hull = faces[solid].copy()
    flip = neg_out[solid]
    hull[flip] = hull[flip][:, ::-1]
    if len(hull) == 0:
        return np.zeros(len(points), dtype=bool)
    w = winding_numbers(vertices, hull, points)
    if np.any(np.abs(w - np.rint(w)) > 0.2):
        return None
    return np.rint(w) != 0


def _outside_sides_by_parts(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """:func:`_outside_sides` for a polyhedron of several edge-connected components, with
    the largest one's cells extracted on their own: libigl nests components by exact
    closest-facet queries, which cost seconds against a big component (2 s for a sphere
    inside an 82k-face one), while one component alone takes a fraction of that. The
    components are disjoint (a polyhedron), so the largest (L) and the rest (R) nest as
    wholes: a part lies in a bounded cell of the other or in its unbounded one, decided
    by the winding number of the other's outer hull at a face centre of the part. Every
    component of R lies in one cell of L, tested one by one. None when a winding number
    is unclear (then take the single libigl call)."""
    lab = edge_components(faces)
    n = int(lab.max()) + 1
    if n == 1:
        return None
    big = int(np.argmax(np.bincount(lab, minlength=n)))
    in_l = lab == big
    fl, fr = np.flatnonzero(in_l), np.flatnonzero(~in_l)
    pos = np.zeros(len(faces), dtype=bool)
    neg = np.zeros(len(faces), dtype=bool)
    pos[fl], neg[fl], cells_l = _outside_sides(vertices, faces[fl])
    pos[fr], neg[fr], cells_r = _outside_sides(vertices, faces[fr])
    v = vertices
    centre = v[faces].mean(axis=1)
    # One probe per component of R: the centre of its first face.
    comps, first = np.unique(lab[fr], return_index=True)
    probe = centre[fr[first]]
    inside_l = _encloses(v, faces[fl], pos[fl], neg[fl], probe)
    if inside_l is None:
        return None
    l_inside = _encloses(v, faces[fr], pos[fr], neg[fr], centre[fl[:1]])
    if l_inside is None:
        return None
    if l_inside[0]:
        pos[fl] = neg[fl] = False
    hidden = np.zeros(n, dtype=bool)
    hidden[comps[inside_l]] = True
    pos[hidden[lab]] = neg[hidden[lab]] = False
    return pos, neg, cells_l + cells_r - 1


def outer_hull_split(vertices: np.ndarray, faces: np.ndarray) -> HullSplit:
    """Classify the faces of a polyhedron by the cells on their two sides."""
    if len(faces) == 0:
        e = np.zeros((0, 3), dtype=np.int64)
        i = np.zeros(0, dtype=np.int64)
        return HullSplit(e, e, i, i, 0, 1)
    # libigl grows its patches across two-face edges assuming they agree in orientation.
    faces = orient_patches(faces)[0]
    sides = _outside_sides_by_parts(vertices, faces) if len(faces) >= 2000 else None
    if sides is None:
        sides = _outside_sides(vertices, faces)
    pos_out, neg_out, n_cells = sides
    solid = np.flatnonzero(pos_out ^ neg_out)
    sheet = np.flatnonzero(pos_out & neg_out)
    sf = faces[solid].copy()
    flip = neg_out[solid]
    sf[flip] = sf[flip][:, ::-1]
    internal = int(len(faces) - len(solid) - len(sheet))
    return HullSplit(sf, faces[sheet], solid, sheet, internal, int(n_cells))
