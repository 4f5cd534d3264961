"""Find the analytic features of a mesh (FIA) and refine them (VTA), with a report.

Tolerance: the chordal error target is ``min(0.01 mm, ε/40)`` (ε = the nozzle diameter):
0.01 mm for a 0.4 mm nozzle. A region is a feature when every vertex lies within
min(tolerance/4, 10⁻⁴ of the region's size) of the fitted surface: an exporter puts the
vertices on the design surface, a freeform scan's do not fit (not even a small patch's).

The output keeps the mesh closed and printable: after VTA the exact check runs on the
float32 mesh (as written to STL); a feature whose refinement fails it is undone and the
report says why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from repair.check import check_printable
from repair.surface.fit import Surface, fit_surface
from repair.surface.patches import planar_patches
from repair.surface.refine import (
    error_summary,
    refine_feature,
    retriangulate_patches,
    start_state,
)
from repair.surface.regions import face_geometry, face_regions
from repair.topology import edge_ids, paired_half_edges

MODES = {"off": (), "holes": ("cylinder", "cone"), "all": ("sphere", "cylinder", "cone", "torus")}
#: a region needs this many facets to be offered to the fits
MIN_FACES = 12
#: share of the tolerance a feature's vertices may lie off the fitted surface
FIT_SHARE = 0.25
#: ... and at most this share of the region's size (a small patch of a scan fits anything
#: within a fixed distance); float32 rounding of a CAD export is ~1e-7 of the coordinates
FIT_RELATIVE = 1e-4
#: a face joins a fitted feature when its normal is within this of the surface's
ABSORB_ANGLE_DEG = 40.0


def surface_tolerance(epsilon: float) -> float:
    """The chordal error target for a printer of nozzle ``epsilon`` mm."""
    return min(0.01, epsilon / 40.0)


@dataclass(frozen=True)
class Feature:
    """One recognised design surface and what VTA did to it (errors in mm)."""

    surface: Surface
    faces_before: int
    faces_after: int
    max_error_before: float
    avg_error_before: float
    max_error_after: float
    avg_error_after: float
    status: str  # "refined", "within tolerance" or "undone: <reason>"

    def to_dict(self) -> dict:
        r = lambda x: round(float(x), 6)  # noqa: E731
        return {**self.surface.describe(), "status": self.status,
                "faces_before": self.faces_before, "faces_after": self.faces_after,
                "chordal_error_before": {"max": r(self.max_error_before),
                                         "avg": r(self.avg_error_before)},
                "chordal_error_after": {"max": r(self.max_error_after),
                                        "avg": r(self.avg_error_after)}}


@dataclass(frozen=True)
class SurfaceResult:
    """The mesh after the stage (the input arrays themselves when nothing was refined), each
    recognised feature's record, the tolerance (mm) and mode used."""

    vertices: np.ndarray
    faces: np.ndarray
    features: tuple[Feature, ...]
    tolerance: float
    mode: str

    triangles_before: int

    @property
    def triangles_added(self) -> int:
        """Triangles added in all: the features' and their neighbours' split along a rim."""
        return len(self.faces) - self.triangles_before

    @property
    def changed(self) -> bool:
        return any(f.status == "refined" for f in self.features)

    def to_dict(self) -> dict:
        return {"mode": self.mode, "tolerance_mm": self.tolerance,
                "triangles_added": self.triangles_added,
                "features": [f.to_dict() for f in self.features]}


def find_features(vertices: np.ndarray, faces: np.ndarray, *, tolerance: float,
                  kinds: tuple[str, ...], eid: np.ndarray | None = None
                  ) -> list[tuple[Surface, np.ndarray]]:
    """(fitted surface, face indices) of every region that is one of ``kinds``. ``eid``:
    the faces' :func:`repair.topology.edge_ids`, if the caller has them."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    if not kinds or len(f) == 0:
        return []
    normals, areas, centroids = geometry = face_geometry(v, f)
    labels = face_regions(v, f, geometry=geometry, eid=eid)
    order = np.argsort(labels, kind="stable")
    cuts = np.flatnonzero(np.diff(labels[order])) + 1
    found = []
    for group in np.split(order, cuts):
        if len(group) < MIN_FACES:
            continue
        pts = v[_used_vertices(f[group], len(v))]
        size = float(np.linalg.norm(np.ptp(pts, axis=0)))
        accept = min(FIT_SHARE * tolerance, FIT_RELATIVE * size)
        surface = fit_surface(pts, centroids[group], normals[group], areas[group], kinds,
                              accept=accept)
        if surface is not None:
            found.append((surface, group, accept))
    return _absorbed(v, f, found)


def _used_vertices(corners: np.ndarray, n_vertices: int) -> np.ndarray:
    """The sorted distinct vertex indices in ``corners`` (``np.unique``'s result): a mask
    over all vertices when the corners are many (no sort), else ``np.unique``."""
    if corners.size * 8 < n_vertices:
        return np.unique(corners)
    used = np.zeros(n_vertices, dtype=bool)
    used[corners.reshape(-1)] = True
    return np.flatnonzero(used)


def _absorbed(v: np.ndarray, f: np.ndarray, found: list) -> list[tuple[Surface, np.ndarray]]:
    """Each feature grown by the neighbouring faces that lie on its surface too (vertices
    within its fit's residual, normal within ``ABSORB_ANGLE_DEG`` of the surface's), which
    the region growing split off; a face goes to the first feature that claims it."""
    if not found:  # nothing to grow: skip the face geometry and edge pairing of the mesh
        return []
    owner = np.full(len(f), -1, dtype=np.int64)
    for fid, (_, group, _) in enumerate(found):
        owner[group] = fid
    normals, _, centroids = face_geometry(v, f)
    eid, _ = edge_ids(f)
    first, second, _ = paired_half_edges(eid)
    fa, fb = first // 3, second // 3
    for fid, (surface, group, accept) in enumerate(found):
        side = np.sign(np.einsum("ij,ij->i", normals[group],
                                 surface.normal(centroids[group])).sum())
        for _ in range(len(f)):
            mine = owner == fid
            cand = np.unique(np.r_[fb[mine[fa] & (owner[fb] < 0)], fa[mine[fb] & (owner[fa] < 0)]])
            if len(cand) == 0:
                break
            on = (np.abs(surface.distance(v[f[cand]].reshape(-1, 3))).reshape(-1, 3).max(1)
                  <= accept)
            facing = side * np.einsum("ij,ij->i", normals[cand], surface.normal(
                centroids[cand])) >= np.cos(np.radians(ABSORB_ANGLE_DEG))
            if not (on & facing).any():
                break
            owner[cand[on & facing]] = fid
    return [(s, np.flatnonzero(owner == fid)) for fid, (s, _, _) in enumerate(found)]


def _refine_one(surface: Surface, state, fid: int, tolerance: float,
                others: dict[int, Surface]) -> tuple[object, Feature]:
    """(the state after VTA on feature ``fid``, its Feature record); the state unchanged
    when the feature is already within tolerance or VTA fails."""
    mine = state.labels == fid
    before = error_summary(surface, state.v, state.f[mine])
    n0 = int(mine.sum())
    if before[0] <= tolerance:
        return state, Feature(surface, n0, n0, *before, *before, "within tolerance")
    try:
        new = refine_feature(surface, state, fid, tolerance, others)
    except ValueError as exc:
        return state, Feature(surface, n0, n0, *before, *before, f"undone: {exc}")
    mine = new.labels == fid
    after = error_summary(surface, new.v, new.f[mine])
    return new, Feature(surface, n0, int(mine.sum()), *before, *after, "refined")


def _undone(feat: Feature, reason: str) -> Feature:
    return Feature(feat.surface, feat.faces_before, feat.faces_before, feat.max_error_before,
                   feat.avg_error_before, feat.max_error_before, feat.avg_error_before,
                   f"undone: {reason}")


def _finished(state, planes: np.ndarray, check: bool):
    """The state with its touched flat patches re-triangulated, or the reason it cannot be
    kept (a patch cannot be re-triangulated, or, with ``check``, the float32 mesh fails the
    exact check)."""
    try:
        done = retriangulate_patches(state, planes)
    except ValueError as exc:
        return None, str(exc)
    if check:
        verdict = check_printable(done.v, done.f, as_float32=True)
        if not verdict.ok:
            return None, ("the refined mesh fails the printability check ("
                          + "; ".join(verdict.failures()) + ")")
    return done, ""


def _refine_group(found: list, fids: list[int], state, planes: np.ndarray, tol: float,
                  check: bool) -> tuple[object, dict[int, Feature]]:
    """Refine the features ``fids`` together; when the result cannot be kept, each half
    on its own (so one bad feature costs a few checks, not one per feature)."""
    new, records = state, {}
    surfaces = {i: s for i, (s, _) in enumerate(found)}
    for fid in fids:
        others = {i: s for i, s in surfaces.items() if i != fid}
        new, records[fid] = _refine_one(found[fid][0], new, fid, tol, others)
    if not any(r.status == "refined" for r in records.values()):
        return state, records
    done, why = _finished(new, planes, check)
    if done is not None:
        return done, records
    if len(fids) == 1:
        return state, {fids[0]: _undone(records[fids[0]], why)}
    half = len(fids) // 2
    state, first = _refine_group(found, fids[:half], state, planes, tol, check)
    state, second = _refine_group(found, fids[half:], state, planes, tol, check)
    return state, first | second


def refine_surfaces(vertices: np.ndarray, faces: np.ndarray, *, epsilon: float,
                    mode: str = "holes", tolerance: float | None = None,
                    found: list[tuple[Surface, np.ndarray]] | None = None) -> SurfaceResult:
    """FIA + VTA on a closed mesh: features of ``mode``'s kinds refined to ``tolerance``
    (default :func:`surface_tolerance` of ``epsilon``); the mesh is returned unchanged when
    none is found. A feature whose refinement would leave a printable input unprintable
    (the exact check on float32 coordinates) is undone. Raises ValueError for an unknown
    mode. ``found``: :func:`find_features` of these very arrays at this tolerance and
    mode's kinds, when already computed (e.g. while the input check ran)."""
    if mode not in MODES:
        raise ValueError(f"surface mode must be one of {', '.join(MODES)}, not {mode!r}")
    tol = surface_tolerance(epsilon) if tolerance is None else float(tolerance)
    v0 = np.asarray(vertices, dtype=float)
    f0 = np.asarray(faces, dtype=np.int64)
    if found is None:
        found = find_features(v0, f0, tolerance=tol, kinds=MODES[mode])
    if not found:
        return SurfaceResult(v0, f0, (), tol, mode, len(f0))
    labels = np.full(len(f0), -1, dtype=np.int64)
    for fid, (_, group) in enumerate(found):
        labels[group] = fid
    patch = planar_patches(v0, f0, labels < 0)
    normals = face_geometry(v0, f0)[0]
    planes = np.zeros((int(patch.max()) + 1, 3))
    planes[patch[patch >= 0]] = normals[patch >= 0]
    check = check_printable(v0, f0).ok  # keep a printable input printable
    state, records = _refine_group(found, list(range(len(found))),
                                   start_state(v0, f0, labels, patch), planes, tol, check)
    ordered = tuple(records[fid] for fid in range(len(found)))
    if not any(r.status == "refined" for r in ordered):
        return SurfaceResult(v0, f0, ordered, tol, mode, len(f0))
    v, f = _compact(state.v, state.f)
    return SurfaceResult(v, f, ordered, tol, mode, len(f0))


def _compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop the vertices no face uses (a re-triangulated flat patch's interior ones)."""
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(faces.shape).astype(np.int64)
