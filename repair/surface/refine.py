"""VTA: translate the point of largest chordal error of a facet onto the design surface.

For the facets of one recognised feature, repeatedly:

- every edge of the feature whose largest distance to the surface exceeds the target is a
  candidate; each face picks its worst candidate edge, and an edge picked by both its faces
  is split at its worst point, moved onto the surface, in both faces (1 → 2 each), so the
  mesh stays conforming. An edge on the feature's border moves within the plane of the
  neighbouring (non-feature) face, so that face stays flat: a hole's rim stays in the
  plate's top face. This is the paper's edge point, handled with its neighbour;
- a feature facet whose edges are all within the target but whose interior is not is split
  in three at its worst interior point, moved onto the surface (the paper's VTA step).

Everything is vectorised over the facets of one feature; the loop is over iterations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from repair.surface.band import zip_band
from repair.surface.fit import Surface
from repair.surface.patches import retriangulate
from repair.surface.regions import face_geometry
from repair.topology import edge_ids, paired_half_edges

#: samples per edge (the face grid uses the same spacing, so both see the same points)
GRID = 8
#: split where the error exceeds this share of the tolerance (a margin for sampling)
MARGIN = 0.9
MAX_ROUNDS = 24


def _bary(n: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    return np.column_stack([i, j, n - i - j]) / n


BARY = _bary(GRID)
INTERIOR = BARY[(BARY > 1e-9).all(1)]
EDGE_U = np.arange(1, GRID) / GRID


def facet_errors(surface: Surface, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Chordal error of each facet: the largest distance of its points to ``surface``."""
    if len(faces) == 0:
        return np.zeros(0)
    tri = vertices[faces]  # (m, 3, 3)
    pts = np.einsum("sk,mkd->msd", BARY, tri).reshape(-1, 3)
    return np.abs(surface.distance(pts)).reshape(len(faces), -1).max(1)


def error_summary(surface: Surface, vertices: np.ndarray, faces: np.ndarray
                  ) -> tuple[float, float]:
    """(max, area-weighted mean) of the facets' chordal errors."""
    err = facet_errors(surface, vertices, faces)
    if len(err) == 0:
        return 0.0, 0.0
    area = face_geometry(vertices, faces)[1]
    return float(err.max()), float(err @ area / max(area.sum(), 1e-300))


def _onto(surface: Surface, x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Points ``x`` moved along unit directions ``d`` onto the surface (Newton steps)."""
    t = np.zeros(len(x))
    for _ in range(6):
        y = x + t[:, None] * d
        slope = np.einsum("ij,ij->i", surface.normal(y), d)
        step = surface.distance(y) / np.where(np.abs(slope) > 1e-6, slope, np.inf)
        t -= step
    return x + t[:, None] * d


def _onto_both(a: Surface, b: Surface, x: np.ndarray) -> np.ndarray:
    """Points ``x`` moved onto the intersection of surfaces ``a`` and ``b`` (alternating
    projections; both meet near ``x`` along an edge the two features share)."""
    for _ in range(8):
        x = _onto(b, _onto(a, x, a.normal(x)), b.normal(x))
    return x


@dataclass
class _Mesh:
    v: np.ndarray
    f: np.ndarray
    labels: np.ndarray  # feature id per face (-1: none)
    fid: int
    patch: np.ndarray  # flat patch id per non-feature face (-1: none)
    born: np.ndarray  # the face was made by a split
    others: dict = field(default_factory=dict)  # the other features' surfaces by id

    @property
    def feature(self) -> np.ndarray:
        return self.labels == self.fid


def _split_edges(s: Surface, m: _Mesh, target: float, rims_only: bool = False) -> int:
    """One round of conforming edge splits (only the feature's border edges with
    ``rims_only``); the number of edges split."""
    f = m.f
    eid, _ = edge_ids(f)
    first, second, _ = paired_half_edges(eid)
    fa, fb = first // 3, second // 3
    feature = m.feature
    touch = (feature[fa] != feature[fb]) if rims_only else (feature[fa] | feature[fb])
    first, second, fa, fb = first[touch], second[touch], fa[touch], fb[touch]
    a = f.reshape(-1)[first]
    b = f[fa, (first % 3 + 1) % 3]
    pts = m.v[a][:, None] + EDGE_U[None, :, None] * (m.v[b] - m.v[a])[:, None]
    err = np.abs(s.distance(pts.reshape(-1, 3))).reshape(len(a), -1)
    worst = err.argmax(1)
    bad = err[np.arange(len(a)), worst] > target
    if not bad.any():
        return 0
    # each face picks its worst bad edge; an edge both faces picked is split
    score = np.where(bad, err.max(1), -1.0)
    best = np.full(len(f), -1.0)
    np.maximum.at(best, fa, score)
    np.maximum.at(best, fb, score)
    chosen = bad & (best[fa] == score) & (best[fb] == score)
    # ties inside a face: each face keeps one edge, its worst (then the lowest numbered)
    idx = np.flatnonzero(chosen)
    both = np.concatenate([idx, idx])
    owner = np.concatenate([fa[idx], fb[idx]])
    order = np.lexsort((both, -score[both]))
    _, win = np.unique(owner[order], return_index=True)
    wins = np.bincount(both[order][win], minlength=len(a))
    chosen = wins == 2
    sel = np.flatnonzero(chosen)
    x = pts[sel, worst[sel]]
    d = s.normal(x)
    border = feature[fa[sel]] != feature[fb[sel]]
    other = np.where(feature[fa[sel]], fb[sel], fa[sel])
    plane_n = face_geometry(m.v, f[other])[0]
    in_plane = d - np.einsum("ij,ij->i", d, plane_n)[:, None] * plane_n
    norm = np.linalg.norm(in_plane, axis=1, keepdims=True)
    d = np.where(border[:, None], in_plane / np.maximum(norm, 1e-12), d)
    twin = m.labels[other] if len(m.others) else np.full(len(sel), -1)
    shared = border & (twin >= 0) & np.isin(twin, list(m.others))
    # the surface must cross the flat neighbour's plane; an edge shared with another
    # feature goes onto both surfaces (their intersection curve)
    ok = ~border | shared | (norm[:, 0] > 0.2)
    sel, x, d, shared, twin = sel[ok], x[ok], d[ok], shared[ok], twin[ok]
    if len(sel) == 0:
        return 0
    new_v = _onto(s, x, d)
    for fid in np.unique(twin[shared]):
        pick = shared & (twin == fid)
        new_v[pick] = _onto_both(s, m.others[int(fid)], x[pick])
    base = len(m.v)
    m.v = np.vstack([m.v, new_v])
    mid = base + np.arange(len(sel))
    halves, parents = [], []
    for he in (first[sel], second[sel]):
        face, k = he // 3, he % 3
        c0, c1, c2 = f[face, k], f[face, (k + 1) % 3], f[face, (k + 2) % 3]
        halves.append(np.column_stack([c0, mid, c2]))
        halves.append(np.column_stack([mid, c1, c2]))
        parents += [face, face]
    _replace(m, np.concatenate(parents), np.vstack(halves))
    return len(sel)


def _replace(m: _Mesh, parents: np.ndarray, children: np.ndarray) -> None:
    """Faces ``parents`` replaced by ``children`` (one row each, parents repeated)."""
    n0 = face_geometry(m.v, m.f[parents])[0]
    n1 = face_geometry(m.v, children)[0]
    flips = np.einsum("ij,ij->i", n0, n1) <= 0.0
    if (flips & (m.patch[parents] < 0)).any():  # a flat patch is re-triangulated at the end
        raise ValueError("a split facet would flip over (the surface leaves its neighbour)")
    gone = np.zeros(len(m.f), bool)
    gone[parents] = True
    m.f = np.vstack([m.f[~gone], children])
    m.labels = np.concatenate([m.labels[~gone], m.labels[parents]])
    m.patch = np.concatenate([m.patch[~gone], m.patch[parents]])
    m.born = np.concatenate([m.born[~gone], np.ones(len(children), bool)])


def _split_interiors(s: Surface, m: _Mesh, target: float) -> int:
    """Split in three each feature facet whose interior (not its edges) is off by > target."""
    faces = np.flatnonzero(m.feature)
    tri = m.v[m.f[faces]]
    pts = np.einsum("sk,mkd->msd", INTERIOR, tri)
    err = np.abs(s.distance(pts.reshape(-1, 3))).reshape(len(faces), -1)
    worst = err.argmax(1)
    bad = err[np.arange(len(faces)), worst] > target
    if not bad.any():
        return 0
    faces, x = faces[bad], pts[bad, worst[bad]]
    new_v = _onto(s, x, s.normal(x))
    base = len(m.v)
    m.v = np.vstack([m.v, new_v])
    mid = base + np.arange(len(faces))
    c = m.f[faces]
    children = np.vstack([np.column_stack([c[:, 0], c[:, 1], mid]),
                          np.column_stack([c[:, 1], c[:, 2], mid]),
                          np.column_stack([c[:, 2], c[:, 0], mid])])
    _replace(m, np.tile(faces, 3), children)
    return len(faces)


def start_state(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                patch: np.ndarray) -> _Mesh:
    """The mesh VTA works on: ``labels`` a feature id per face (-1: none), ``patch`` a flat
    patch id per non-feature face (see ``patches.py``)."""
    return _Mesh(np.asarray(vertices, float), np.asarray(faces, np.int64), labels.copy(), -1,
                 patch.copy(), np.zeros(len(faces), bool))


def refine_feature(surface: Surface, state: _Mesh, fid: int, tolerance: float,
                   others: dict[int, Surface] | None = None) -> _Mesh:
    """A new state after VTA on the faces labelled ``fid`` (children inherit their parent's
    labels), until every facet of the feature is within ``tolerance`` of ``surface``. Flat
    patches split along the feature's border still need :func:`retriangulate_patches`.
    ``others``: the other features' surfaces by id (an edge shared with one is split onto
    both).
    Raises ValueError when a split would fold the mesh or the rounds run out."""
    # work on the feature and the faces across its edges only, then splice them back
    mine = state.labels == fid
    touched = np.zeros(len(state.v), bool)
    touched[state.f[mine]] = True
    near = touched[state.f].any(1)
    m = _Mesh(state.v, state.f[near], state.labels[near], fid, state.patch[near],
              state.born[near], others or {})
    target = MARGIN * tolerance
    if surface.kind in ("cylinder", "cone"):
        _rims_then_zip(surface, m, target)
    for _ in range(MAX_ROUNDS):
        if _split_edges(s := surface, m, target) == 0 and _split_interiors(s, m, target) == 0:
            return _Mesh(m.v, np.vstack([state.f[~near], m.f]),
                         np.concatenate([state.labels[~near], m.labels]), -1,
                         np.concatenate([state.patch[~near], m.patch]),
                         np.concatenate([state.born[~near], m.born]))
    raise ValueError(f"no convergence to {tolerance:g} mm in {MAX_ROUNDS} rounds")


def _rims_then_zip(surface: Surface, m: _Mesh, target: float) -> None:
    """A band feature: refine its rims, then re-connect it rim to rim (``band.py``); any
    other shape keeps its refined rims and is left to the general rounds."""
    for _ in range(MAX_ROUNDS):
        if _split_edges(surface, m, target, rims_only=True) == 0:
            break
    mine = m.feature
    try:
        new = zip_band(surface, m.v, m.f[mine])
    except ValueError:
        return
    m.f = np.vstack([m.f[~mine], new])
    m.labels = np.concatenate([m.labels[~mine], np.full(len(new), m.fid)])
    m.patch = np.concatenate([m.patch[~mine], np.full(len(new), -1)])
    m.born = np.concatenate([m.born[~mine], np.ones(len(new), bool)])


def retriangulate_patches(state: _Mesh, planes: np.ndarray) -> _Mesh:
    """A new state with each flat patch that a border split touched re-triangulated
    (``planes``: each patch's unit normal). Raises ValueError when one cannot be."""
    m = _Mesh(state.v, state.f, state.labels, -1, state.patch, state.born)
    touched = np.unique(m.patch[m.born & (m.patch >= 0)])
    if len(touched) == 0:
        return m
    keep = ~np.isin(m.patch, touched)
    order = np.argsort(m.patch, kind="stable")
    ids = m.patch[order]
    new_faces, new_patch = [], []
    for pid in touched:
        lo, hi = np.searchsorted(ids, [pid, pid + 1])
        tri = retriangulate(m.v, m.f[order[lo:hi]], planes[pid])
        new_faces.append(tri)
        new_patch.append(np.full(len(tri), pid))
    new = np.vstack(new_faces)
    m.f = np.vstack([m.f[keep], new])
    m.labels = np.concatenate([m.labels[keep], np.full(len(new), -1)])
    m.patch = np.concatenate([m.patch[keep], np.concatenate(new_patch)])
    m.born = np.concatenate([m.born[keep], np.ones(len(new), bool)])
    return m
