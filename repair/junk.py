"""Internal junk: shells of a printable mesh that a slicer should never see.

A mesh can pass every test of :func:`repair.check.check_printable` and still hold closed
inner shells of near-zero volume, or slit-thin voids whose faces lie back to back: each
is a legal cavity (an inverted shell inside exactly one solid), only thinner than
anything a printer can leave empty. The generalised winding number of the whole mesh
tells them: just outside a face (along its normal) it must be 0 and just inside it must
be 1. A probe a hair's breadth off a face of a slit void crosses the void and lands in
the solid again (winding 1 on the outside); off a face of a shell of near-zero volume it
does the same. :func:`face_winding_sides` measures both sides of every face;
:func:`drop_internal_junk` removes the cavity shells most of whose area fails (the
cavity fills: Attene Sec. 5.3 keeps no cavities at all; only those thinner than the
probe distance go here).

Units are mm; vertices float64 (n, 3), faces int64 (m, 3).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from repair.check import check_printable
from repair.meshes import shell_volumes
from repair.probe_grid import faces_near_points
from repair.report import RepairOutcome
from repair.topology import edge_components

__all__ = [
    "without_internal_junk", "PROBE_FRACTION", "WindingFromBase", "drop_internal_junk",
    "face_winding_sides"]  # fmt: skip

#: Probe distance off each face, as a fraction of the mesh's largest extent (mm):
#: about 2 float32 ulps of the largest coordinate of a centred part.
PROBE_FRACTION = 2.0**-22


def probe_distance(vertices: np.ndarray) -> float:
    """How far off each face :func:`face_winding_sides` probes (mm)."""
    v = np.asarray(vertices, dtype=np.float64)
    return float(np.ptp(v, axis=0).max()) * PROBE_FRACTION if len(v) else 0.0


#: Up to this many probes are summed exactly in numpy, probe by probe (~15 ms each on
#: 90k faces); libigl's exact ``winding_number`` costs ~0.35 s on 90k faces however few.
NUMPY_PROBES = 24


def _solid_angle_sum(v: np.ndarray, f: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Exact winding numbers at the few points ``q``: the faces' solid angles (Van
    Oosterom and Strackee) summed, one probe at a time over all faces."""
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    out = np.empty(len(q))
    for k, x in enumerate(q):
        a, b, c = p0 - x, p1 - x, p2 - x
        la, lb, lc = (np.sqrt(np.einsum("ij,ij->i", t, t)) for t in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
               + np.einsum("ij,ij->i", b, c) * la + np.einsum("ij,ij->i", c, a) * lb)  # fmt: skip
        out[k] = np.arctan2(det, den).sum() / (2.0 * np.pi)
    return out


#: On meshes of this many faces, the exact sums run over the faces near the probes only
#: (:func:`_near_exact_winding`).
SPLIT_MIN_FACES = 40_000
#: Up to this many probes, even more than :data:`NUMPY_PROBES`, go straight to
#: :func:`_near_exact_winding` on such meshes (a few clusters near a change).
SPLIT_MAX_PROBES = 512
#: Faces farther than this fraction of the mesh's extent from every probe are summed by
#: libigl's hierarchical approximation (errors there are far below half a unit).
NEAR_FRACTION = 2.0**-12
#: Probes whose near faces are gathered at a time (neighbours along x).
NEAR_RUN = 32


def _exact_winding(v: np.ndarray, f: np.ndarray, q: np.ndarray) -> np.ndarray:
    if len(f) >= SPLIT_MIN_FACES:
        return _near_exact_winding(v, f, q)
    if len(q) <= NUMPY_PROBES:
        return _solid_angle_sum(v, f, q)
    import igl

    return np.asarray(igl.winding_number(v, f, q), dtype=np.float64)


def _near_exact_winding(v: np.ndarray, f: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Winding numbers at ``q`` (exact once rounded to an integer): libigl's fast winding
    number with the faces near the probes summed exactly (:class:`WindingFromBase` of
    the mesh itself). A probe a hair off a face costs the near faces' exact sums, not all
    of a large mesh's."""
    none = np.zeros(0, dtype=np.int64)
    return WindingFromBase(v, f).at(q, v, none.reshape(0, 3), none)


def _winding(
    v: np.ndarray, f: np.ndarray, q: np.ndarray, expected: np.ndarray,
    doubtful: Callable[[], np.ndarray] | None = None,
) -> np.ndarray:
    """Winding numbers at ``q``: exact (:func:`_exact_winding`) for a modest
    probes x faces product; else libigl's hierarchical ``fast_winding_number``, which is
    approximate and a hair off a face can be wrong by a whole unit (float32 sums), so
    every probe where it differs from the ``expected`` value, and every probe
    ``doubtful()`` marks, is summed again exactly. The fast value is kept only where it
    is the expected one and the probe is not doubtful."""
    import igl

    v = np.ascontiguousarray(v, dtype=np.float64)
    f = np.ascontiguousarray(f, dtype=np.int64)
    q = np.ascontiguousarray(q, dtype=np.float64)
    if len(f) * len(q) <= 4_000_000 or len(q) <= NUMPY_PROBES:
        return _exact_winding(v, f, q)
    if len(f) >= SPLIT_MIN_FACES and len(q) <= SPLIT_MAX_PROBES:
        return _near_exact_winding(v, f, q)
    w = np.asarray(igl.fast_winding_number(v, f, q), dtype=np.float64)
    recheck = np.abs(w - expected) > 0.05
    if doubtful is not None:
        recheck |= doubtful()
    part = np.flatnonzero(recheck)
    if len(part):
        w[part] = _exact_winding(v, f, q[part])
    return w


def _crowded(
    v: np.ndarray, f: np.ndarray, q: np.ndarray, owner: np.ndarray, reach: np.ndarray
) -> np.ndarray:
    """Which probes ``q`` (each ``reach`` mm off its face ``owner``) have another face
    nearer than ``reach``: libigl's exact nearest-face query (a float64 AABB tree), over
    the faces whose box comes that near some probe when the probes are few. Its own face
    lies exactly ``reach`` away, so a nearer face is what the query finds.

    On a printable mesh (closed, oriented, not self-intersecting, shells nested right:
    :func:`repair.check.check_printable`) the winding number is 0 just outside every
    face and 1 just inside, so a probe's winding number is that plus the signed
    crossings of the segment from its face to it -- and a face crossing that segment
    lies nearer than ``reach``. Every other probe's winding number is the expected one,
    whatever a float32 approximation reads there."""
    import igl

    if len(q) == 0:
        return np.zeros(0, dtype=bool)
    rest = (faces_near_points(v, f, q, float(reach.max())) if 8 * len(q) < len(f)
            else np.arange(len(f)))  # fmt: skip
    sub = f if len(rest) == len(f) else np.ascontiguousarray(f[rest])
    sq, nearest, _ = igl.point_mesh_squared_distance(q, v, sub)
    return (rest[nearest] != owner) & (sq < reach * reach)


class WindingFromBase:
    """Winding numbers of meshes made from a closed base mesh ``(v0, f0)`` by removing
    some of its faces and adding others (vertices appended, none moved), at a few
    points: libigl's fast winding number of the base (its tree built once), less the
    same approximation over the base's faces near the points plus their exact solid
    angles (a hair off a face the float32 sums err by up to a unit; the two trees sum
    those faces alike), less the removed faces' exact solid angles, plus the added
    faces'. Exact once rounded to an integer (within 0.03 on the corpus's probes)."""

    def __init__(self, v0: np.ndarray, f0: np.ndarray) -> None:
        self.v0 = np.ascontiguousarray(v0, dtype=np.float64)
        self.f0 = np.ascontiguousarray(f0, dtype=np.int64)
        self.tree = None  # built at the first query

    def _build(self) -> None:
        import igl

        self.tree = igl.FastWindingNumberBVH()
        self.tree.init(self.v0, self.f0)
        a, b, c = (self.v0[self.f0[:, k]] for k in range(3))
        r = NEAR_FRACTION * float(np.ptp(self.v0, axis=0).max())
        self.lo = np.minimum(np.minimum(a, b), c) - r
        self.hi = np.maximum(np.maximum(a, b), c) + r

    def at(
        self, q: np.ndarray, v: np.ndarray, added: np.ndarray, removed: np.ndarray
    ) -> np.ndarray:
        """Winding numbers at ``q`` of the base less its faces ``removed`` (indices)
        plus the faces ``added`` (corners indexing ``v``, which starts with ``v0``)."""
        import igl

        q = np.ascontiguousarray(q, dtype=np.float64)
        if len(q) == 0:
            return np.zeros(0)
        if self.tree is None:
            self._build()
        w = np.asarray(self.tree.winding_number(q), dtype=np.float64)
        # Probes in runs along x: each run's near faces are few (a superset per run).
        order = np.argsort(q[:, 0], kind="stable")
        for s in range(0, len(q), NEAR_RUN):
            run = order[s : s + NEAR_RUN]
            near = np.ones(len(self.f0), dtype=bool)
            for k in range(3):  # a box near some probe along every axis
                x = np.sort(q[run, k])
                near &= np.searchsorted(x, self.hi[:, k], side="right") > np.searchsorted(
                    x, self.lo[:, k]
                )
            own = np.ascontiguousarray(self.f0[near])
            if len(own):
                w[run] -= np.asarray(igl.fast_winding_number(self.v0, own, q[run]))
                w[run] += _solid_angle_sum(self.v0, own, q[run])
        if len(removed):
            w -= _solid_angle_sum(self.v0, self.f0[np.asarray(removed, dtype=np.int64)], q)
        if len(added):
            w += _solid_angle_sum(np.asarray(v, dtype=np.float64), added, q)
        return w


def face_winding_sides(
    vertices: np.ndarray, faces: np.ndarray, which: np.ndarray | None = None,
    distance: float | None = None, winding: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised winding number of the whole mesh just outside (centroid + d n) and
    just inside (centroid - d n) each face (or the faces ``which``), d = ``distance``
    (default :func:`probe_distance`) or a tenth of the face's height if less.
    libigl's ``winding_number`` (exact solid angles) or, for many probes against many
    faces, its hierarchical ``fast_winding_number`` -- kept only where it reads the
    expected 0 or 1 at a probe no other face comes nearer to than its own
    (:func:`_crowded`: on a printable mesh the winding number there is the expected one);
    every other probe is summed exactly (a float32 sum a hair off a face can be a unit
    wrong either way, so reading the expected value proves nothing there).
    ``winding``: the winding numbers of this mesh at given points, when known a cheaper
    way (:meth:`WindingFromBase.at`).
    Faces too thin to probe (height under 2^-20 of the probe distance: a probe off them
    would sit within floating-point noise of the face itself) and degenerate faces get
    NaN."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    idx = np.arange(len(f)) if which is None else np.asarray(which, dtype=np.int64)
    d = probe_distance(v) if distance is None else float(distance)
    p = v[f[idx]]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    ok = length[:, 0] > 0
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    c = p.mean(axis=1)
    # Never farther off a face than a tenth of its height: off a sliver, a probe at
    # the global distance would land beyond its neighbours instead of just outside it.
    longest = np.linalg.norm(p - p[:, [1, 2, 0]], axis=2).max(axis=1)
    height = np.divide(length[:, 0], longest, out=np.zeros_like(longest), where=longest > 0)
    d = np.minimum(d, 0.1 * height)[:, None]
    # Below this a probe is within floating-point noise of the face itself: unmeasured.
    ok &= height >= probe_distance(v) * 2.0**-20
    expected = np.r_[np.zeros(len(idx)), np.ones(len(idx))]
    q = np.vstack([c + d * n, c - d * n])
    if winding is None:
        reach, owner = np.r_[d[:, 0], d[:, 0]], np.r_[idx, idx]
        w = _winding(v, f, q, expected, lambda: _crowded(v, f, q, owner, reach))
    else:
        w = winding(q)
    out, inside = w[: len(idx)], w[len(idx) :]
    out[~ok] = inside[~ok] = np.nan
    return out, inside


def failing_faces(outside: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Faces whose winding number is not 0 just outside or not 1 just inside (rounded
    to the nearest integer: the numbers are exact up to floating-point noise); faces
    that could not be probed (NaN) are not counted."""
    measured = ~np.isnan(outside) & ~np.isnan(inside)
    return measured & ((np.rint(outside) != 0) | (np.rint(inside) != 1))


def drop_internal_junk(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, tuple[int, int, float]]:
    """Remove the cavity shells (negative volume) of a closed, oriented mesh at least
    half of whose area fails :func:`failing_faces`: near-zero-volume inner shells and
    slit-thin voids. Whole closed shells go, so the rest stays closed and oriented.
    Returns ``(vertices, faces, (shells removed, faces removed, their volume mm³))``;
    the input arrays themselves when nothing goes (one shell: nothing to test)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return v, f, (0, 0, 0.0)
    lab = edge_components(f)
    n = int(lab.max()) + 1
    if n == 1:
        return v, f, (0, 0, 0.0)
    vol = shell_volumes(v, f, lab, n)
    cavity = np.flatnonzero(vol <= 0)
    if len(cavity) == 0:
        return v, f, (0, 0, 0.0)
    which = np.flatnonzero(np.isin(lab, cavity))
    outside, inside = face_winding_sides(v, f, which)
    p = v[f[which]]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    bad_area = np.bincount(lab[which], weights=area * failing_faces(outside, inside),
                           minlength=n)  # fmt: skip
    all_area = np.bincount(lab[which], weights=area, minlength=n)
    junk = np.zeros(n, dtype=bool)
    junk[cavity] = bad_area[cavity] >= 0.5 * all_area[cavity]
    if not junk.any():
        return v, f, (0, 0, 0.0)
    gone = junk[lab]
    from repair.clean import drop_unreferenced

    kv, kf = drop_unreferenced(v, f[~gone])
    return kv, kf, (int(np.count_nonzero(junk)), int(np.count_nonzero(gone)),
                    float(vol[junk].sum()))  # fmt: skip


def without_internal_junk(out: RepairOutcome) -> RepairOutcome:
    """``out`` with its junk cavity shells (:func:`drop_internal_junk`) removed and
    counted in its tally, when what is left still passes the exact check (a solid that
    sat in a removed cavity would now be nested: then nothing is removed). A written
    mesh of one shell cannot hold such junk and is returned as it is."""
    if out.verdict.components <= 1 or not out.verdict.ok:
        return out
    v, f, (shells, _, volume) = drop_internal_junk(out.vertices, out.faces)
    if shells == 0:
        return out
    verdict = check_printable(v, f)
    if not verdict.ok:
        return out
    out.vertices, out.faces, out.verdict = v, f, verdict
    out.tally.junk_shells += shells
    out.tally.junk_volume += volume
    return out
