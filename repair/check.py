"""Printability check: prove a triangle mesh is a printable solid.

A mesh ``(vertices, faces)`` (units mm; ``vertices`` float (n, 3), ``faces`` int (m, 3))
is *printable* when it is

- **closed**: no undirected edge is used by only one face;
- **edge-manifold**: no undirected edge is used by more than two faces;
- **consistently oriented**: each edge used by two faces is traversed once in each direction;
- of **positive volume** (signed volume by the divergence theorem, outward normals);
- free of **degenerate faces**: no repeated vertex index and no three exactly collinear
  corners (decided with exact arithmetic on the given coordinates, no tolerance);
- free of **duplicate faces** (two faces on the same three vertices);
- made of **outward shells**: each shell is a solid outside all others or a cavity inside
  exactly one solid (winding numbers), so no inverted bodies and no shells nested in solids;
- free of **self-intersections**: tested with CGAL's exact kernel through libigl
  (``igl.copyleft.cgal.remesh_self_intersections(..., detect_only=True)``). Faces that
  share a vertex or an edge and otherwise only touch along it are not intersecting; any
  other contact (crossing, touching at a point, coplanar overlap) is.

A binary STL stores float32: pass ``as_float32=True`` (or check
``round_to_float32(vertices)``) to verify the coordinates that are actually written.
All work is vectorised numpy except the exact intersection test (C++).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from repair.pending_pairs import start_face_pairs
from repair.topology import count_duplicate_faces, edge_stats, unique_faces, weld_exact
from repair.winding import misnested_shells

__all__ = [
    "Printability",
    "check_printable",
    "check_printable_pairs",
    "degenerate_face_mask",
    "round_to_float32",
    "verdict_given_pairs",
]


@dataclass(frozen=True)
class Printability:
    """The verdict of :func:`check_printable`: named booleans and the counts behind them.

    Counts are of undirected edges (``boundary_edges``, ``nonmanifold_edges``,
    ``misoriented_edges``), of faces (``degenerate_faces``, ``duplicate_faces``,
    ``triangles``), of unordered face pairs (``intersecting_pairs``) and of edge-connected
    face components (``components``, i.e. shells). ``volume`` is the signed volume in mm³.
    ``shells_outward``/``misnested_shells``: every shell is an outward solid lying outside
    all others, or an inverted cavity lying inside exactly one solid (winding number of
    the other shells 0 resp. 1). Only assessed (else None) when the mesh is closed,
    edge-manifold, oriented, free of degenerate faces and of self-intersections, since the
    winding number is only meaningful then; the other failures already decide ``ok``.
    ``float32`` says the check ran on float32-rounded (as written to STL) coordinates.
    """

    closed: bool
    edge_manifold: bool
    oriented: bool
    positive_volume: bool
    no_degenerate_faces: bool
    no_duplicate_faces: bool
    no_self_intersections: bool
    shells_outward: bool | None
    triangles: int
    boundary_edges: int
    nonmanifold_edges: int
    misoriented_edges: int
    degenerate_faces: int
    duplicate_faces: int
    intersecting_pairs: int
    misnested_shells: int | None
    components: int
    volume: float
    float32: bool = False
    #: Label (0..components-1) of each face's shell; not part of :meth:`to_dict`.
    shells: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def ok(self) -> bool:
        """True when every check passed (and the mesh has at least one triangle)."""
        return (
            self.triangles > 0
            and self.closed
            and self.edge_manifold
            and self.oriented
            and self.positive_volume
            and self.no_degenerate_faces
            and self.no_duplicate_faces
            and self.no_self_intersections
            and self.shells_outward is not False
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict of every field plus ``"ok"``."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "shells"}
        d["ok"] = self.ok
        return d

    def failures(self) -> list[str]:
        """Human-readable reasons the mesh is not printable (empty when ``ok``)."""
        out: list[str] = []
        if self.triangles == 0:
            out.append("the mesh has no triangles")
            return out
        if not self.closed:
            out.append(f"not closed: {self.boundary_edges} boundary edge(s)")
        if not self.edge_manifold:
            out.append(f"not edge-manifold: {self.nonmanifold_edges} edge(s) shared by >2 faces")
        if not self.oriented:
            out.append(
                f"inconsistently oriented: {self.misoriented_edges} edge(s) traversed "
                "twice in the same direction"
            )
        if not self.positive_volume:
            out.append(f"volume is not positive ({self.volume:.6g} mm³)")
        if not self.no_degenerate_faces:
            out.append(f"{self.degenerate_faces} degenerate (zero-area) face(s)")
        if not self.no_duplicate_faces:
            out.append(f"{self.duplicate_faces} duplicate face(s)")
        if not self.no_self_intersections:
            out.append(f"self-intersecting: {self.intersecting_pairs} intersecting face pair(s)")
        if self.shells_outward is False:
            out.append(f"{self.misnested_shells} shell(s) inverted or nested inside another solid")
        return out


def round_to_float32(vertices: np.ndarray) -> np.ndarray:
    """Vertices rounded to float32 (as a binary STL stores them), returned as float64."""
    return np.asarray(vertices, dtype=np.float64).astype(np.float32).astype(np.float64)


# --------------------------------------------------------------------------- degeneracy

# Shewchuk's bound for a 2x2 orientation determinant evaluated in doubles from
# differences of doubles: when |det| exceeds it, the sign (hence non-zero) is exact.
_EPS = np.ldexp(1.0, -53)
_ORIENT2D_ERRBOUND = (3.0 + 16.0 * _EPS) * _EPS


def _exact_int_coords(p: np.ndarray) -> np.ndarray:
    """Float64 array -> object array of Python ints, all scaled by one common power of 2."""
    mant, exp = np.frexp(p)  # p = mant * 2**exp, 0.5 <= |mant| < 1
    imant = np.ldexp(mant, 53).astype(np.int64)  # exact: 53-bit integer mantissa
    exp = exp.astype(np.int64) - 53
    nz = imant != 0
    emin = int(exp[nz].min()) if np.any(nz) else 0
    shift = np.where(nz, exp - emin, 0)
    out = imant.astype(object) * (np.full(shift.shape, 2, dtype=object) ** shift.astype(object))
    return out


def degenerate_face_mask(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Boolean mask (m,) of faces with a repeated index or exactly collinear corners.

    Decided exactly on the given float64 coordinates: a floating-point filter settles
    almost every face, the rest are evaluated with integer arithmetic. No tolerance.
    """
    return _degeneracy_and_volume(vertices, faces)[0]


def _degeneracy_and_volume(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, float]:
    """(degenerate face mask, signed volume in mm³), sharing the corner gathers and the
    edge cross products (volume = sum of (a - centre) . ((b - a) x (c - a)) / 6, which
    equals the divergence-theorem sum; centring on the bounding box limits cancellation).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    f0, f1, f2 = (np.ascontiguousarray(faces[:, k]) for k in range(3))
    repeated = (f0 == f1) | (f1 == f2) | (f2 == f0)
    # One contiguous array per coordinate: 1-D gathers and unit-stride arithmetic (the
    # same operations on the same values as on (m, 3) rows, several times faster).
    cols = [np.ascontiguousarray(vertices[:, d]) for d in range(3)]
    a = [x[f0] for x in cols]
    u = [x[f1] - ad for x, ad in zip(cols, a, strict=True)]
    w = [x[f2] - ad for x, ad in zip(cols, a, strict=True)]
    # The cross product is zero exactly iff all three 2D orientations are zero.
    certain_nonzero = np.zeros(len(faces), dtype=bool)
    volume = 0.0
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0)) if len(faces) else None
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        left = u[i] * w[j]
        right = u[j] * w[i]
        det = left - right
        volume += float(np.dot(a[k] - centre[k], det)) if len(faces) else 0.0
        bound = _ORIENT2D_ERRBOUND * (np.abs(left) + np.abs(right))
        certain_nonzero |= (det != 0.0) & (np.abs(det) > bound)
    unsure = np.flatnonzero(~certain_nonzero & ~repeated)
    degenerate = repeated.copy()
    if len(unsure):
        pts = vertices[faces[unsure]]  # (k, 3, 3)
        ints = _exact_int_coords(pts)
        ua = ints[:, 1, :] - ints[:, 0, :]
        wa = ints[:, 2, :] - ints[:, 0, :]
        zero = np.ones(len(unsure), dtype=bool)
        for i, j in ((1, 2), (2, 0), (0, 1)):
            d = ua[:, i] * wa[:, j] - ua[:, j] * wa[:, i]
            zero &= d == 0
        degenerate[unsure] = zero
    return degenerate, volume / 6.0


# --------------------------------------------------------------------------- entry point


def check_printable(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    as_float32: bool = False,
) -> Printability:
    """Check that ``(vertices, faces)`` is a printable solid; see the module docstring.

    ``vertices``: (n, 3) float coordinates in mm, all finite. ``faces``: (m, 3) integer
    indices into ``vertices``. With ``as_float32=True`` the coordinates are first rounded
    to float32 and exactly coincident vertices merged, i.e. the check runs on exactly the
    mesh that :func:`repair.io.write_stl` writes and :func:`repair.io.load_mesh` reads back.

    Raises ``ValueError`` for malformed input (bad shapes, out-of-range indices,
    non-finite coordinates); a mesh that is merely broken gets a verdict, not an error.
    """
    return check_printable_pairs(vertices, faces, as_float32=as_float32)[0]


def check_printable_pairs(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    as_float32: bool = False,
    unwanted: Callable[[], object] | None = None,
) -> tuple[Printability, np.ndarray]:
    """:func:`check_printable`, also returning the intersecting face pairs (k, 2) as
    indices into ``faces`` (into the welded faces when ``as_float32``), so that a repair
    loop does not test them twice.

    ``unwanted``: called (its value ignored) as soon as degenerate or duplicate faces or
    the edge census show that the mesh is not printable, before the exact intersection
    test is waited for: work started ahead for a printable verdict (the stage that would
    follow it, in a forked child) stops there instead of competing with the test's
    children for the CPUs."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or (v.size and v.shape[1] != 3):
        raise ValueError(f"vertices must have shape (n, 3), got {v.shape}")
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (m, 3), got {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be integer indices, got {f.dtype}")
    f = f.astype(np.int64, copy=False)
    v = v.reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("face indices out of range")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertex coordinates are not all finite")
    if as_float32:
        v, f = weld_exact(round_to_float32(v), f)

    m = len(f)
    if m == 0:
        return _empty_verdict(as_float32), np.zeros((0, 2), dtype=np.int64)
    return _verdict(v, f, as_float32, unwanted=unwanted)


def _empty_verdict(as_float32: bool) -> Printability:
    return Printability(
            closed=False, edge_manifold=True, oriented=True, positive_volume=False,
            no_degenerate_faces=True, no_duplicate_faces=True, no_self_intersections=True,
            shells_outward=None, triangles=0, boundary_edges=0, nonmanifold_edges=0,
            misoriented_edges=0, degenerate_faces=0, duplicate_faces=0, intersecting_pairs=0,
            misnested_shells=None, components=0,
            volume=0.0, float32=as_float32,
        )  # fmt: skip


def verdict_given_pairs(
    vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray
) -> tuple[Printability, np.ndarray]:
    """:func:`check_printable_pairs` (``as_float32=False``) on float32-valued vertices
    whose intersecting face pairs are already known: ``pairs`` must be every pair that
    :func:`intersecting_face_pairs` finds among the non-degenerate faces at exactly these
    coordinates (e.g. from :func:`repair.rounding.round_finding_crossings`); copies of a face
    may be in them (libigl's test is pairwise and never pairs two copies), the verdict
    counts those of the first copies, as a test of its own would."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return _empty_verdict(True), np.zeros((0, 2), dtype=np.int64)
    return _verdict(v, f, True, np.asarray(pairs, dtype=np.int64).reshape(-1, 2))


def _verdict(
    v: np.ndarray, f: np.ndarray, as_float32: bool, known_pairs: np.ndarray | None = None,
    unwanted: Callable[[], object] | None = None,
) -> tuple[Printability, np.ndarray]:
    m = len(f)
    # Started before the faces are known proper and distinct, as they mostly are: a large
    # mesh's test then runs in children beside that work too, and starts again without
    # the faces it must not see when there are any.
    early = start_face_pairs(v, f) if known_pairs is None else None
    degenerate, volume = _degeneracy_and_volume(v, f)
    n_degenerate = int(np.count_nonzero(degenerate))
    n_duplicate = count_duplicate_faces(f)

    pending = None
    if known_pairs is not None:
        pairs = known_pairs
        if n_duplicate:  # the test is pairwise: keep the pairs one test of the first copies finds
            first = np.zeros(m, dtype=bool)
            nondeg = np.flatnonzero(~degenerate)
            first[nondeg[unique_faces(f[nondeg])]] = True
            pairs = pairs[first[pairs].all(axis=1)]
    else:
        # The exact intersection test needs proper triangles, each vertex triple once.
        keep = np.flatnonzero(~degenerate)
        pending = early
        if n_degenerate or n_duplicate:
            if unwanted is not None:
                unwanted()
            early.cancel()
            fk = f[keep]
            if n_duplicate:
                keep = keep[unique_faces(fk)]
                fk = f[keep]
            pending = start_face_pairs(v, fk)  # in forked children on a large mesh
    # The edge census runs here while the children test the pairs.
    boundary, nonmanifold, misoriented, components, labels = edge_stats(f)
    if pending is not None:
        if unwanted is not None and n_degenerate == n_duplicate == 0 and (
            boundary or nonmanifold or misoriented
        ):
            unwanted()
        pairs = keep[pending.result()]

    solid_so_far = (
        boundary == 0 and nonmanifold == 0 and misoriented == 0
        and n_degenerate == 0 and n_duplicate == 0 and len(pairs) == 0
    )  # fmt: skip
    if not solid_so_far:
        misnested = None
    elif components == 1:
        misnested = int(volume <= 0.0)
    else:
        misnested = misnested_shells(v, f, labels, components)

    verdict = Printability(
        closed=boundary == 0,
        edge_manifold=nonmanifold == 0,
        oriented=misoriented == 0,
        positive_volume=volume > 0.0,
        no_degenerate_faces=n_degenerate == 0,
        no_duplicate_faces=n_duplicate == 0,
        no_self_intersections=len(pairs) == 0,
        shells_outward=None if misnested is None else misnested == 0,
        triangles=m,
        boundary_edges=boundary,
        nonmanifold_edges=nonmanifold,
        misoriented_edges=misoriented,
        degenerate_faces=n_degenerate,
        duplicate_faces=n_duplicate,
        intersecting_pairs=int(len(pairs)),
        misnested_shells=misnested,
        components=components,
        volume=volume,
        float32=as_float32,
        shells=labels.astype(np.int64),
    )
    return verdict, pairs
