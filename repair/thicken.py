"""Stage 4 of the repair (Attene Sec. 4.2.1): zero-thickness sheets become thin solids.

A sheet (faces of the outer hull with the outside on both sides) is cut into orientable,
manifold patches -- at edges shared by more than two sheet faces, at edges whose faces
cannot be oriented consistently (a Moebius strip gets one cut), and at non-manifold
vertices -- and each patch becomes a closed slab: its offset copies at +-eps/2 along the
vertex normals plus side walls along the patch boundary. The slabs may overlap each other,
the solid and themselves; the next arrangement pass (``repair.hull``) takes their union.

The offset at a vertex is ``eps/2`` scaled up where the incident faces bend (so that the
slab stays about ``eps`` thick across creases) but never beyond ``MITER_LIMIT * eps/2``,
so every slab point is within ``MITER_LIMIT * eps / 2`` of the sheet.

Where one input triangle is partly solid hull and partly sheet, ``region_prisms`` gives
its sheet part one flat prism (the 2-D union of its arrangement pieces, extruded by
manifold3d) instead of a slab per sliver piece.

Units are mm; vertices float64 (n, 3), faces int64 (m, 3). Vectorised numpy + scipy.
"""

from __future__ import annotations

import numpy as np

from repair.topology import (
    connected_labels,
    edge_ids,
    half_edges,
    paired_half_edges,
    split_vertex_fans,
    vertex_components,
)

__all__ = [
    "MITER_LIMIT",
    "face_blocks",
    "face_prisms",
    "orient_patches",
    "orient_patches_with_edge_use",
    "region_prisms",
    "sheet_slabs",
]

#: Largest vertex offset, as a multiple of eps/2 (bounds Attene's deviation D by 0.55 eps).
MITER_LIMIT = 1.1
#: How far (x eps) a region prism's outline may move when its collinear corners go.
REGION_SIMPLIFY = 1e-4
#: Blocks from which a small sheet is thickened by its level set instead (see
#: :func:`sheet_slabs`): the union of fewer is cheap, and their faces keep the sheet's.
LEVEL_SET_MIN_BLOCKS = 64
#: Grid points the level set may sample per block it saves: one costs ~1/1000 of a
#: block's share of the union, and of rounding and mending its facets afterwards.
LEVEL_SET_POINTS_PER_BLOCK = 250
#: And never more than this many (~100 MB of samples and distances).
LEVEL_SET_MAX_POINTS = 2_000_000


def orient_patches(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orient every orientable manifold patch consistently.

    Returns ``(faces, cut)`` where ``cut`` marks the half-edges (3f+k) whose edge must be
    cut: non-manifold edges, and the edges that stay inconsistent in unorientable patches.
    """
    out, cut, _ = orient_patches_with_edge_use(faces)
    return out, cut


def orient_patches_with_edge_use(
    faces: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`orient_patches`, plus the use count of each returned half-edge's edge."""
    m = len(faces)
    he, eid = half_edges(faces), edge_ids(faces)[0]
    h1, h2, use = paired_half_edges(eid)
    f1, f2 = h1 // 3, h2 // 3
    consistent = he[h1, 0] == he[h2, 1]  # opposite directions
    if consistent.all():  # already oriented (what the double cover would keep): cut
        return faces.copy(), use > 2, use  # only the non-manifold edges
    # Double cover: node 2f+s is face f with flip s.
    a = np.r_[2 * f1, 2 * f1 + 1]
    b = np.r_[2 * f2 + np.where(consistent, 0, 1), 2 * f2 + np.where(consistent, 1, 0)]
    lab = connected_labels(2 * m, a, b)
    l0, l1 = lab[0::2], lab[1::2]
    flip = l1 < l0
    unorientable = np.flatnonzero(l0 == l1)
    out = faces.copy()
    if len(unorientable) == 0:
        # Whole patches flipped, each consistent: only non-manifold edges are cut. A
        # flipped face (c, b, a) has half-edges (bc, ab, ca): its first two swap.
        out[flip] = out[flip][:, ::-1]
        use2 = use.reshape(-1, 3).copy()
        use2[flip] = use2[flip][:, [1, 0, 2]]
        use2 = use2.reshape(-1)
        return out, use2 > 2, use2
    flip = _orient_by_tree(m, f1, f2, consistent, flip, unorientable)
    out[flip] = out[flip][:, ::-1]
    # Re-derive consistency after flipping; inconsistent manifold edges are cuts.
    he2 = half_edges(out)
    g1, g2, use2 = paired_half_edges(edge_ids(out)[0])
    bad = he2[g1, 0] != he2[g2, 1]
    cut = use2 > 2
    cut[g1[bad]] = True
    cut[g2[bad]] = True
    return out, cut, use2


def _orient_by_tree(
    m: int,
    f1: np.ndarray,
    f2: np.ndarray,
    consistent: np.ndarray,
    flip: np.ndarray,
    faces_sel: np.ndarray,
) -> np.ndarray:
    """Orientation of unorientable patches along a spanning forest (the cut is then where
    non-tree edges disagree). Parity is propagated by pointer jumping, vectorised."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_tree

    sel = np.zeros(m, dtype=bool)
    sel[faces_sel] = True
    keep = sel[f1] & sel[f2]
    a, b, inc = f1[keep], f2[keep], (~consistent[keep]).astype(np.int8)
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(m, m)).tocsr()
    lab = connected_labels(m, a, b)
    parent = np.arange(m)
    for comp in np.unique(lab[faces_sel]):
        root = int(faces_sel[lab[faces_sel] == comp][0])
        tree = breadth_first_tree(g, root, directed=False).tocoo()
        parent[tree.col] = tree.row
    # Parity of each tree edge (child, parent).
    key = np.minimum(a, b) * m + np.maximum(a, b)
    order = np.argsort(key)
    child = np.flatnonzero(parent != np.arange(m))
    ck = np.minimum(child, parent[child]) * m + np.maximum(child, parent[child])
    pos = order[np.searchsorted(key[order], ck)]
    par = np.zeros(m, dtype=np.int8)
    par[child] = inc[pos]
    ptr = parent.copy()
    while np.any(ptr != ptr[ptr]):
        par = par ^ par[ptr]
        ptr = ptr[ptr]
    par = par ^ np.where(ptr != np.arange(m), par[ptr], 0)
    out = flip.copy()
    out[faces_sel] = par[faces_sel].astype(bool)
    return out


def face_prisms(
    vertices: np.ndarray, faces: np.ndarray, epsilon: float
) -> tuple[np.ndarray, np.ndarray]:
    """One closed prism per face (the face moved +-eps/2 along its own normal, 8
    triangles), plus eps-prisms along the edges where two of the faces bend, so that the
    union covers the sheet's eps/2 neighbourhood without gaps. Always valid solids."""
    from repair.wires import cylinders

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = v[f]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    fl = np.linalg.norm(fn, axis=1, keepdims=True)
    ok = fl[:, 0] > 0
    p, fn = p[ok], fn[ok] / fl[ok]
    f = f[ok]
    m = len(f)
    d = 0.5 * epsilon * fn[:, None, :]
    pv = np.concatenate([p + d, p - d], axis=1).reshape(-1, 3)  # 6 per prism
    local = np.array(
        [[0, 1, 2], [3, 5, 4], [0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2], [2, 5, 3], [2, 3, 0]]
    )
    pf = (local[None] + 6 * np.arange(m)[:, None, None]).reshape(-1, 3)
    # Creases: edges shared by two of the faces whose normals differ.
    he = half_edges(f)
    eid = edge_ids(f)[0]
    order = np.argsort(eid, kind="stable")
    same = np.flatnonzero(eid[order][1:] == eid[order][:-1])
    h1, h2 = order[same], order[same + 1]
    # A sheet has no inside: faces folded flat onto each other are not a crease either.
    bend = np.abs(np.einsum("ij,ij->i", fn[h1 // 3], fn[h2 // 3])) < 1.0 - 1e-12
    cv, cf = cylinders(v[he[h1[bend]]], epsilon)
    return np.vstack([pv, cv]), np.vstack([pf, cf + len(pv)]).astype(np.int64)


def sheet_slabs(
    vertices: np.ndarray, faces: np.ndarray, epsilon: float, *, strict: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed slabs of thickness about ``epsilon`` (mm) around the sheet ``faces``.

    Returns ``(vertices, faces)`` of all slabs concatenated (may overlap one another;
    resolve and take the outer hull afterwards). A slab may cross itself where the
    sheet folds everywhere, unless ``strict``: then the folding faces get blocks
    (:func:`face_blocks`), however many. Else, where the blocks are many and the sheet
    small (its grid has fewer than ``LEVEL_SET_POINTS_PER_BLOCK`` points per block), the
    sheet's eps/2 level set (:func:`repair.sheet_level_set.sheet_level_set`) replaces
    slabs and blocks: one solid, never crossing itself, its deviation D a little over
    the slabs' bound (0.59 eps against 0.55 on mikedh_target); ``strict`` (the fallback,
    which states D <= 0.55 eps) keeps them. Empty input gives empty arrays.
    """
    blocked: list[int] = []
    sv, sf = _slabs(vertices, faces, epsilon, strict, 0, blocked)
    n_blocks = sum(blocked)
    if n_blocks >= LEVEL_SET_MIN_BLOCKS and not strict:
        from repair.sheet_level_set import level_set_points, sheet_level_set

        v = np.asarray(vertices, dtype=np.float64)
        used = v[np.unique(np.asarray(faces, dtype=np.int64))]
        budget = min(LEVEL_SET_POINTS_PER_BLOCK * n_blocks, LEVEL_SET_MAX_POINTS)
        if level_set_points(used, epsilon) <= budget:
            solid = sheet_level_set(v, faces, epsilon)
            if solid is not None:
                return solid
    return sv, sf


def _slabs(
    vertices: np.ndarray, faces: np.ndarray, epsilon: float, strict: bool, depth: int,
    blocked: list[int],
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sheet_slabs` without the level set; appends to ``blocked`` how many faces
    got blocks."""
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    v = np.asarray(vertices, dtype=np.float64)
    f, cut = orient_patches(faces)
    ids = split_vertex_fans(f, cut)
    n = int(ids.max()) + 1
    fs = ids.reshape(-1, 3)
    pos = np.zeros((n, 3))
    pos[ids] = v[f.reshape(-1)]

    p = pos[fs]  # (m, 3, 3)
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    fl = np.linalg.norm(fn, axis=1, keepdims=True)
    fn = np.divide(fn, fl, out=np.zeros_like(fn), where=fl > 0)  # tiny slivers: no say
    # Angle-weighted vertex normals.
    e0 = p[:, [1, 2, 0]] - p
    e1 = p[:, [2, 0, 1]] - p
    el = np.linalg.norm(e0, axis=2) * np.linalg.norm(e1, axis=2)
    dots = np.einsum("ijk,ijk->ij", e0, e1)
    cosang = np.divide(dots, el, out=np.ones_like(dots), where=el > 0)
    ang = np.arccos(np.clip(cosang, -1.0, 1.0))  # (m, 3)
    vn = np.zeros((n, 3))
    for k in range(3):
        np.add.at(vn, fs[:, k], fn * ang[:, k : k + 1])
    ln = np.linalg.norm(vn, axis=1)
    weak = ln < 1e-9
    vn[~weak] /= ln[~weak, None]
    if np.any(weak):  # normals cancel (a fold back onto itself): use one face's normal
        corner_face = np.repeat(np.arange(len(fs)), 3)
        some = np.zeros(n, dtype=np.int64)
        some[ids] = corner_face
        vn[weak] = fn[some[weak]]
        still = np.linalg.norm(vn, axis=1) == 0
        vn[still] = (0.0, 0.0, 1.0)
    # Miter: keep the slab ~eps thick along each face normal, up to the limit.
    cos_c = np.einsum("ij,ij->i", vn[ids], np.repeat(fn, 3, axis=0))
    cos_c[np.repeat(fl[:, 0] == 0, 3)] = 1.0
    min_cos = np.full(n, 1.0)
    np.minimum.at(min_cos, ids, cos_c)
    clamped = min_cos < 1.0 / MITER_LIMIT
    thin = clamped[fs].any(axis=1)
    if thin.any() and depth < 2:
        # A corner sharper than the miter limit (a box's): the slab would be thinner
        # than eps across every face at it, down to eps * MITER_LIMIT / sqrt(3) at a
        # cube's corner. Those faces get blocks exactly eps thick along their own normals
        # (overlapping across their creases); the rest is slabbed on its own.
        gv, gf = _slabs(v, f[~thin], epsilon, strict, depth + 1, blocked)
        blocked.append(int(np.count_nonzero(thin)))
        pv, pf = face_blocks(v, f[thin], epsilon)
        return np.vstack([gv, pv]), np.vstack([gf, pf + len(gv)]).astype(np.int64)
    scale = 1.0 / np.maximum(min_cos, 1.0 / MITER_LIMIT)
    d = (0.5 * epsilon) * scale[:, None] * vn

    top, bot = pos + d, pos - d
    out_v = np.vstack([top, bot])
    # Boundary half-edges of the slab's own faces: walls.
    he = half_edges(fs)
    eid, cnt = edge_ids(fs)
    is_bnd = cnt[eid] == 1
    bnd = he[is_bnd]
    wall_face = np.flatnonzero(is_bnd) // 3
    a, b = bnd[:, 0], bnd[:, 1]
    walls = np.vstack([np.stack([b, a, a + n], axis=1), np.stack([b, a + n, b + n], axis=1)])
    out_f = np.vstack([fs, fs[:, ::-1] + n, walls]).astype(np.int64)
    return _replace_bad_slabs(out_v, out_f, v, f, epsilon, wall_face, depth, strict, blocked)


def _replace_bad_slabs(
    sv: np.ndarray,
    sf: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    epsilon: float,
    wall_face: np.ndarray,
    depth: int,
    strict: bool,
    blocked: list[int],
) -> tuple[np.ndarray, np.ndarray]:
    """Where a slab folds onto itself (sharp folds, slits left by cuts) it is not a valid
    solid: the sheet faces involved (and their vertex neighbours) get per-face blocks
    (:func:`face_blocks`) and the rest of the sheet is slabbed again without them."""
    from repair.intersections import intersecting_face_pairs

    m = len(f)
    lab = vertex_components(len(sv), sf)
    flab = lab[sf[:, 0]]
    pairs = intersecting_face_pairs(sv, sf)
    if len(pairs):
        pairs = pairs[flab[pairs[:, 0]] == flab[pairs[:, 1]]]
    if len(pairs) == 0:
        return sv, sf
    # Slab face -> sheet face: top i, bottom m + i, walls via their half-edge.
    owner = np.r_[np.arange(m), np.arange(m), wall_face, wall_face]
    bad = np.zeros(m, dtype=bool)
    bad[owner[pairs.reshape(-1)]] = True
    touched = np.zeros(int(f.max()) + 1, dtype=bool)
    touched[f[bad].reshape(-1)] = True
    bad |= touched[f].any(axis=1)
    if strict and depth >= 2:
        blocked.append(m)
        return face_blocks(v, f, epsilon)  # still folding after two rounds: blocks only
    if (bad.mean() > 0.2 or depth >= 2) and not strict:
        # Folding everywhere (e.g. a neck narrower than eps): prisms would be too many;
        # keep the slab and let the union / exact arrangement sort the overlaps out.
        return sv, sf
    gv, gf = _slabs(v, f[~bad], epsilon, strict, depth + 1, blocked)
    blocked.append(int(np.count_nonzero(bad)))
    pv, pf = face_blocks(v, f[bad], epsilon)
    return np.vstack([gv, pv]), np.vstack([gf, pf + len(gv)]).astype(np.int64)


def region_prisms(
    vertices: np.ndarray,
    faces: np.ndarray,
    groups: np.ndarray,
    normals: np.ndarray,
    epsilon: float,
    grow: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """One prism of thickness ``epsilon`` (mm) per planar region: the faces of each group
    (e.g. the sheet pieces of one input triangle, cut up by the arrangement) lie in one
    plane with unit normal ``normals[i]`` (per face; equal within a group). Their 2-D
    union, grown by ``grow`` mm and rid of its collinear corners (outline moved by at
    most ``REGION_SIMPLIFY * eps``), is extruded to +-eps/2 about the plane (manifold3d
    ``CrossSection``): a few well-shaped solids in place of slabs of every sliver piece,
    which no float32 union can keep apart. Returns ``(vertices, faces)`` of closed prisms
    that overlap one another, not themselves; empty input gives empty arrays."""
    import manifold3d as m3d

    f = np.asarray(faces, dtype=np.int64)
    out_v: list[np.ndarray] = []
    out_f: list[np.ndarray] = []
    off = 0
    if len(f) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    v = np.asarray(vertices, dtype=np.float64)
    g = np.asarray(groups)
    order = np.argsort(g, kind="stable")
    starts = np.r_[0, np.flatnonzero(np.diff(g[order])) + 1, len(g)]
    for s, e in zip(starts[:-1], starts[1:], strict=True):
        idx = order[s:e]
        n = np.asarray(normals[idx[0]], dtype=np.float64)
        p = v[f[idx]]  # (k, 3, 3)
        origin = p.reshape(-1, 3).mean(axis=0)
        u = p[0, 1] - p[0, 0]
        u = u - n * np.dot(u, n)
        if np.linalg.norm(u) == 0:
            u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        q = p - origin
        tri2 = np.stack([q @ u, q @ w], axis=2)  # (k, 3, 2)
        a, b = tri2[:, 1] - tri2[:, 0], tri2[:, 2] - tri2[:, 0]
        area = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        tri2[area < 0] = tri2[area < 0][:, ::-1]
        tri2 = tri2[area != 0]
        if len(tri2) == 0:
            continue
        cs = m3d.CrossSection(list(tri2), m3d.FillRule.Positive)
        if grow > 0:
            cs = cs.offset(grow, m3d.JoinType.Miter)
        # The arrangement's cut points along the pieces' common edges are collinear:
        # without them the prism has a few corners instead of hundreds, and its union
        # with the solid is cheaper and leaves fewer slivers to round.
        cs = cs.simplify(REGION_SIMPLIFY * epsilon)
        if cs.is_empty():
            continue
        frame = np.column_stack([u, w, n, origin - 0.5 * epsilon * n])
        mesh = m3d.Manifold.extrude(cs, epsilon).transform(frame).to_mesh64()
        pv = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
        pf = np.asarray(mesh.tri_verts, dtype=np.int64)
        out_v.append(pv)
        out_f.append(pf + off)
        off += len(pv)
    if not out_f:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(out_v), np.vstack(out_f)


#: Each face block's triangles over its 12 corners: the face moved by +-eps/2 along its
#: normal (0-2 top, 3-5 bottom) and each edge moved by eps/2 outward in the face's plane
#: (6-11: a and b of edge ab, b and c of bc, c and a of ca).
_BLOCK = np.array(
    [[0, 1, 2], [3, 5, 4],
     [0, 6, 7], [0, 7, 1], [1, 8, 9], [1, 9, 2], [2, 10, 11], [2, 11, 0],
     [3, 7, 6], [3, 4, 7], [4, 9, 8], [4, 5, 9], [5, 11, 10], [5, 3, 11],
     [1, 7, 8], [2, 9, 10], [0, 11, 6], [4, 8, 7], [5, 10, 9], [3, 6, 11]]
)  # fmt: skip


def face_blocks(
    vertices: np.ndarray, faces: np.ndarray, epsilon: float
) -> tuple[np.ndarray, np.ndarray]:
    """One convex closed block per face: its Minkowski sum with the double pyramid whose
    apices are +-eps/2 along the face's normal and whose base corners are eps/2 out from
    each of its edges in its plane (12 corners, 20 triangles). Exactly eps thick along
    the normal, every point within eps/2 of the face; unlike :func:`face_prisms` the
    blocks of two faces that meet at a crease overlap across it, so no crease cylinders
    are needed, and a sheet of faces smaller than eps is covered by half as many pieces.
    Degenerate faces get none. Always valid (convex) solids."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    p = v[f]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    fl = np.linalg.norm(fn, axis=1)
    e = p[:, [1, 2, 0]] - p  # edges ab, bc, ca
    el = np.linalg.norm(e, axis=2)
    ok = (fl > 0) & (el > 0).all(axis=1)
    p, fn, e, el = p[ok], fn[ok] / fl[ok, None], e[ok], el[ok]
    r = 0.5 * epsilon
    out_dir = np.cross(e, fn[:, None, :]) / el[:, :, None]  # outward in-plane, per edge
    top, bot = p + r * fn[:, None, :], p - r * fn[:, None, :]
    mid = np.stack([p, p[:, [1, 2, 0]]], axis=2) + r * out_dir[:, :, None, :]  # (m, 3, 2, 3)
    corners = np.concatenate([top, bot, mid.reshape(-1, 6, 3)], axis=1)
    m = len(p)
    bf = (_BLOCK[None] + 12 * np.arange(m)[:, None, None]).reshape(-1, 3)
    return corners.reshape(-1, 3), bf.astype(np.int64)
