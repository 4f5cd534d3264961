"""Analytic design surfaces and their robust least-squares fits to a tessellation.

A CAD exporter puts the vertices of an STL on the design surface and lets the facets sag
between them (the chordal error). So a group of facets is recognised as a plane, sphere,
cylinder, cone or torus when its *vertices* lie on that surface within a small residual;
the facets' normals give the starting guess (axis, apex) and ``scipy.optimize`` refines it.

Each surface gives the signed distance of points to it and its unit normal there, which is
all the vertex translation (``refine.py``) needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the order fits are tried in: two coaxial circles (a cylinder's or cone's rims) also lie
#: on a sphere and a torus, so the ruled surfaces come first
KINDS = ("cylinder", "cone", "sphere", "torus")
#: vertices a fit is first tried on
SUBSAMPLE = 256
#: a guess whose median vertex distance exceeds this multiple of the fit's ``accept`` is not
#: refined: on a design surface the guesses from facet normals and circles are nearly exact
#: (every corpus feature's within 0.5 ``accept``), on a scan's small noisy regions they are
#: 10-1000 ``accept`` off, and refining each of those hundreds of guesses cost ~0.1 s CPU
GUESS_ACCEPT = 2.0


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _axial(p: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(height along the axis, radial vector from the axis) of points ``p`` (n, 3)."""
    d = p - origin
    t = d @ axis
    return t, d - t[:, None] * axis


@dataclass(frozen=True)
class Surface:
    """An analytic surface: ``kind`` and its parameters (``origin``, ``axis``, radii ...)."""

    kind: str
    origin: np.ndarray  # sphere/torus centre, a point on a cylinder's axis, a cone's apex
    axis: np.ndarray  # unit axis (unused for a sphere)
    radius: float = 0.0  # sphere, cylinder; the torus tube radius
    major: float = 0.0  # torus: distance from the axis to the tube's centre circle
    half_angle: float = 0.0  # cone, radians

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Signed distance of points ``p`` (n, 3): positive away from the axis/centre."""
        p = np.asarray(p, dtype=float)
        if self.kind == "sphere":
            return np.linalg.norm(p - self.origin, axis=1) - self.radius
        t, rad = _axial(p, self.origin, self.axis)
        rho = np.linalg.norm(rad, axis=1)
        if self.kind == "cylinder":
            return rho - self.radius
        if self.kind == "cone":
            return rho * np.cos(self.half_angle) - t * np.sin(self.half_angle)
        return np.hypot(rho - self.major, t) - self.radius  # torus

    def normal(self, p: np.ndarray) -> np.ndarray:
        """Unit gradient of :meth:`distance` at ``p`` (n, 3)."""
        p = np.asarray(p, dtype=float)
        if self.kind == "sphere":
            return _unit(p - self.origin)
        t, rad = _axial(p, self.origin, self.axis)
        rho = np.maximum(np.linalg.norm(rad, axis=1), 1e-12)
        out = rad / rho[:, None]
        if self.kind == "cylinder":
            return out
        if self.kind == "cone":
            c, s = np.cos(self.half_angle), np.sin(self.half_angle)
            return c * out - s * self.axis
        return _unit((rho - self.major)[:, None] * out + t[:, None] * self.axis)  # torus

    def describe(self) -> dict:
        """JSON-ready parameters (mm, degrees)."""
        r = lambda v: [round(float(x), 6) for x in v]  # noqa: E731
        out: dict = {"kind": self.kind}
        if self.kind == "sphere":
            return out | {"centre": r(self.origin), "radius": round(self.radius, 6)}
        out["axis"] = r(self.axis)
        if self.kind == "cylinder":
            return out | {"point_on_axis": r(self.origin), "radius": round(self.radius, 6)}
        if self.kind == "cone":
            return out | {"apex": r(self.origin),
                          "half_angle_deg": round(float(np.degrees(self.half_angle)), 6)}
        return out | {"centre": r(self.origin), "major_radius": round(self.major, 6),
                      "minor_radius": round(self.radius, 6)}


# --------------------------------------------------------------------------- initial guesses


def _axis_from_normals(normals: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The axis a for which n·a varies least over the facets (cylinder: n·a = 0, cone: const)."""
    w = weights / weights.sum()
    mean = w @ normals
    cov = (normals - mean).T @ ((normals - mean) * w[:, None])
    return np.linalg.eigh(cov)[1][:, 0]


def _circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    a = np.column_stack([2 * xy, np.ones(len(xy))])
    (cx, cy, c), *_ = np.linalg.lstsq(a, (xy**2).sum(1), rcond=None)
    return np.array([cx, cy]), float(np.sqrt(max(c + cx * cx + cy * cy, 0.0)))


def _frame(axis: np.ndarray) -> np.ndarray:
    """Two unit vectors perpendicular to ``axis`` (2, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    u = _unit(np.cross(axis, helper))
    return np.stack([u, np.cross(axis, u)])


def _angles(a: np.ndarray) -> np.ndarray:
    return np.array([np.arccos(np.clip(a[2], -1, 1)), np.arctan2(a[1], a[0])])


def _from_angles(th: float, ph: float) -> np.ndarray:
    return np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


def _guess_sphere(p: np.ndarray, *_) -> Surface:
    a = np.column_stack([2 * p, np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(a, (p**2).sum(1), rcond=None)
    c = sol[:3]
    return Surface("sphere", c, np.array([0.0, 0.0, 1.0]),
                   radius=float(np.sqrt(max(sol[3] + c @ c, 0.0))))


def _guess_cylinder(p: np.ndarray, _c: np.ndarray, normals: np.ndarray, weights: np.ndarray
                    ) -> Surface:
    axis = _axis_from_normals(normals, weights)
    frame = _frame(axis)
    centre, r = _circle(p @ frame.T)
    return Surface("cylinder", centre @ frame + (p.mean(0) @ axis) * axis, axis, radius=r)


def _guess_cone(p: np.ndarray, centroids: np.ndarray, normals: np.ndarray, weights: np.ndarray
                ) -> Surface:
    axis = _axis_from_normals(normals, weights)
    # every tangent plane passes through the apex: n_i · apex = n_i · c_i (least squares)
    apex, *_ = np.linalg.lstsq(normals, np.einsum("ij,ij->i", normals, centroids), rcond=None)
    t, rad = _axial(p, apex, axis)
    if np.median(t) < 0:
        axis, t = -axis, -t
    rho = np.linalg.norm(rad, axis=1)
    half = float(np.arctan2(np.median(rho), max(float(np.median(t)), 1e-9)))
    return Surface("cone", apex, axis, half_angle=half)


def _guess_torus(p: np.ndarray, *_) -> Surface:
    # a torus's normals all cross its axis; its centre is the vertices' centroid for a
    # full ring, and the axis is the direction the vertices spread least along
    c = p.mean(0)
    axis = np.linalg.eigh(np.cov((p - c).T))[1][:, 0]
    t, rad = _axial(p, c, axis)
    rho = np.linalg.norm(rad, axis=1)
    # the tube's centre circle in the (rho, t) half-plane
    (cr, ct), r = _circle(np.column_stack([rho, t]))
    return Surface("torus", c + ct * axis, axis, radius=r, major=float(cr))


# --------------------------------------------------------------------------- refinement


def _pack(s: Surface) -> np.ndarray:
    if s.kind == "sphere":
        return np.r_[s.origin, s.radius]
    ang = _angles(s.axis)
    if s.kind == "cylinder":
        return np.r_[s.origin, ang, s.radius]
    if s.kind == "cone":
        return np.r_[s.origin, ang, s.half_angle]
    return np.r_[s.origin, ang, s.major, s.radius]


def _unpack(kind: str, x: np.ndarray) -> Surface:
    if kind == "sphere":
        return Surface(kind, x[:3], np.array([0.0, 0.0, 1.0]), radius=float(x[3]))
    axis = _from_angles(x[3], x[4])
    if kind == "cylinder":
        return Surface(kind, x[:3], axis, radius=float(x[5]))
    if kind == "cone":
        return Surface(kind, x[:3], axis, half_angle=float(x[5]))
    return Surface(kind, x[:3], axis, major=float(x[5]), radius=float(x[6]))


_GUESS = {"sphere": _guess_sphere, "cylinder": _guess_cylinder, "cone": _guess_cone,
          "torus": _guess_torus}


def _sane(s: Surface, extent: float) -> bool:
    """Reject the degenerate fits a nearly flat patch allows (huge radii, flat cones)."""
    if not np.all(np.isfinite(s.origin)) or not np.all(np.isfinite(s.axis)):
        return False
    if s.kind == "cone":
        return np.radians(2.0) < s.half_angle < np.radians(88.0) and bool(
            np.linalg.norm(s.origin) < 1e6)
    big = max(s.radius, s.major)
    return 0.0 < s.radius and big < 5.0 * extent and (s.kind != "torus" or s.major > 0.0)


def fit_surface(points: np.ndarray, centroids: np.ndarray, normals: np.ndarray,
                areas: np.ndarray, kinds: tuple[str, ...], accept: float) -> Surface | None:
    """The simplest surface of ``kinds`` (in :data:`KINDS` order) whose distance to every
    vertex in ``points`` is at most ``accept`` mm, or None (a plane or a freeform patch).

    ``centroids``, ``normals``, ``areas``: the facets', for the initial guess."""
    p = np.asarray(points, dtype=float)
    lo, hi = p.min(0), p.max(0)
    extent = float(np.linalg.norm(hi - lo))
    if len(p) < 8 or extent <= 0:
        return None
    # a plane (every vertex within ``accept`` of the best plane) is not a curved feature
    c = p.mean(0)
    spread, directions = np.linalg.eigh(np.cov((p - c).T))
    if spread[0] ** 0.5 < accept / 3 and np.abs((p - c) @ directions[:, 0]).max() <= accept:
        return None
    # fit a few hundred vertices first: a region that is no such surface fails cheaply
    few = p[np.linspace(0, len(p) - 1, min(len(p), SUBSAMPLE)).astype(int)]
    for kind in (k for k in KINDS if k in kinds):
        with np.errstate(all="ignore"):
            guess = _GUESS[kind](p, centroids, normals, areas)
            if not _sane(guess, extent * 10) or np.median(
                    np.abs(guess.distance(few))) > GUESS_ACCEPT * accept:
                continue  # the normals' guess is far off: not this kind of surface
            # scipy.optimize takes ~1 s to import: only a guess worth refining pays for it
            from scipy.optimize import least_squares

            x = _pack(guess)
            for pts in (few, p) if len(p) > len(few) else (p,):
                sol = least_squares(lambda x, k=kind, q=pts: _unpack(k, x).distance(q), x,
                                    method="lm", max_nfev=50 * (len(x) + 1))
                x = sol.x
                if np.abs(_unpack(kind, x).distance(pts)).max() > accept:
                    break
        fitted = _unpack(kind, sol.x)
        if kind == "cone" and fitted.half_angle < 0:  # the same cone, axis the other way
            fitted = Surface(kind, fitted.origin, -fitted.axis, half_angle=-fitted.half_angle)
        elif kind in ("cylinder", "torus") and fitted.axis @ guess.axis < 0:
            fitted = Surface(kind, fitted.origin, -fitted.axis, fitted.radius, fitted.major)
        if _sane(fitted, extent) and np.abs(fitted.distance(p)).max() <= accept:
            return fitted
    return None
