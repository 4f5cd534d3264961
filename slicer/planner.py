"""Per-layer toolpath planning: perimeters, thin walls, top/bottom skins, infill, skirt.

Units mm. Every layer's cross-section is a manifold3d CrossSection; shells are inward offsets
at the bead spacing ``s = w − h·(1 − π/4)`` so that touching beads fill the area exactly.
Parts of a region too narrow for a full loop (thinner than two spacings, e.g. a repaired
sheet exactly one nozzle thick) are never dropped: they become *thin walls*, printed as a loop
around the region's middle with beads of half the local width, which deposits the region's
area.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from manifold3d import CrossSection, JoinType, OpType

from slicer.geometry import bead_spacing, contours, hatch
from slicer.overhang import BRIDGE_ANGLES, line_anchoring
from slicer.profile import Profile

MITER = JoinType.Miter


@dataclass(slots=True)
class Path:
    """One extrusion path: points (n, 2) mm; ``closed`` loops return to their first point."""

    points: np.ndarray
    closed: bool
    width: float
    role: str


@dataclass(slots=True)
class LayerPlan:
    """Everything printed at one layer (z = top of the layer, mm)."""

    index: int
    z: float
    height: float
    paths: list[Path] = field(default_factory=list)
    outline: list[np.ndarray] = field(default_factory=list)


@dataclass(slots=True)
class _Shells:
    loops: list[Path]
    thin: list[Path]
    inner: CrossSection  # region left for infill


def _loops(cs: CrossSection, width: float, role: str) -> list[Path]:
    return [Path(p, True, width, role) for p in contours(cs)]


def _thin_paths(lost: CrossSection, spacing: float, height: float) -> list[Path]:
    """Print each narrow component (mean width t = 2·area / perimeter): a closed thin ring
    narrower than 1.5 spacings as one bead along its middle; anything else as a loop at t/4
    inside its edge with beads of spacing t/2, so that the two passes deposit its area."""
    out: list[Path] = []
    if lost.is_empty():
        return out
    min_area = _min_thin_area(spacing)
    for comp in lost.decompose():
        area = comp.area()
        if area < min_area:
            continue
        polys = contours(comp)
        perim = sum(float(np.linalg.norm(np.diff(p, axis=0, append=p[:1]), axis=1).sum())
                    for p in polys)
        if perim <= 0:
            continue
        t = 2.0 * area / perim  # mean width of a ring (no ends)
        if len(polys) == 1:
            # an open strip: area = L·t, perimeter = 2L + 2t
            t = (perim - math.sqrt(max(perim * perim - 16.0 * area, 0.0))) / 4.0
        if t < 0.2 * spacing:
            continue
        shape = height * (1.0 - math.pi / 4.0)
        if len(polys) >= 2 and t <= 1.5 * spacing:
            # a closed thin ring (e.g. a hollow box with walls one nozzle thick): one bead
            # along the middle, as wide as the wall
            mid = comp.offset(-0.45 * t, MITER).simplify(spacing * 0.03)
            mid_polys = contours(mid)
            if len(mid_polys) == len(polys):
                outer = [q for q in mid_polys if _signed_area(q) > 0]
                out.extend(Path(q, True, t + shape, "thin_wall") for q in outer)
                continue
        if len(polys) == 1 and t <= 1.5 * spacing:
            # an open strip (e.g. a repaired sheet one nozzle thick): one bead along the middle
            line = _strip_midline(comp, t, area / t)
            if line is not None:
                out.append(Path(line, False, t + shape, "thin_wall"))
                continue
        core = comp.offset(-t / 4.0, MITER).simplify(spacing * 0.03)
        if core.is_empty():
            continue
        width = t / 2.0 + shape  # spacing of this bead = t / 2: two beads fill the width
        out.extend(Path(p, True, width, "thin_wall") for p in contours(core))
    return out


def _strip_midline(comp: CrossSection, t: float, length: float) -> np.ndarray | None:
    """Middle line of a strip of mean width ``t`` and length ``length`` (mm), or None if it is
    not a simple strip.

    The strip is shrunk to a sliver 0.1·t wide whose outline runs along the middle line and
    back; the outline turns through ≈ 180° at each of the two tips and nowhere else, so the
    tips are found as the two places of largest turning over a short arc, and one side of
    the outline between them, moved half the sliver's width inwards, is the middle line. Its
    ends are extended towards the tips until it is ``length`` long (at most to the tips).
    Branching or uneven strips (a third tip, a sliver in pieces) return None.
    """
    inset = 0.45 * t
    sliver = comp.offset(-inset, MITER)
    polys = contours(sliver)
    if len(polys) != 1:
        return None
    p = polys[0]
    if _signed_area(p) < 0:
        p = p[::-1]
    n = len(p)
    if n < 4:
        return None
    e = np.roll(p, -1, axis=0) - p  # edge i: p[i] → p[i+1]
    seg = np.hypot(e[:, 0], e[:, 1])
    total = float(seg.sum())
    ep = np.roll(e, 1, axis=0)  # edge arriving at vertex i
    turn = np.arctan2(ep[:, 0] * e[:, 1] - ep[:, 1] * e[:, 0], np.einsum("ij,ij->i", ep, e))
    arc = np.concatenate([[0.0], np.cumsum(seg)])[:-1]  # arc position of vertex i
    arc3 = np.concatenate([arc, arc + total, arc + 2 * total])
    cum = np.concatenate([[0.0], np.cumsum(np.tile(turn, 3))])
    window = 0.5 * t  # the sliver is 0.1·t wide: a tip's two corners fall in one window
    lo = np.searchsorted(arc3, arc + total - window / 2, side="left")
    hi = np.searchsorted(arc3, arc + total + window / 2, side="right")
    wsum = cum[hi] - cum[lo]
    i1 = int(np.argmax(wsum))
    dist = np.abs(arc - arc[i1])
    dist = np.minimum(dist, total - dist)
    far = dist > 0.25 * total
    if not far.any():
        return None
    i2 = int(np.flatnonzero(far)[np.argmax(wsum[far])])
    if wsum[i1] < 2.6 or wsum[i2] < 2.6:
        return None
    d2 = np.abs(arc - arc[i2])
    d2 = np.minimum(d2, total - d2)
    third = (dist > 0.1 * total) & (d2 > 0.1 * total) & (wsum > 2.0)
    if third.any():
        return None
    idx = np.arange(i1, i2 + 1) if i2 > i1 else np.concatenate([np.arange(i1, n),
                                                                  np.arange(0, i2 + 1)])
    line = p[idx].copy()
    if len(line) < 2:
        return None
    # move onto the middle: the sliver side lies (t − 2·inset)/2 off it, interior on the left
    d = np.diff(line, axis=0)
    nrm = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(np.hypot(d[:, 0], d[:, 1]),
                                                             1e-12)[:, None]
    vn = np.vstack([nrm[:1], nrm[:-1] + nrm[1:], nrm[-1:]])
    vn /= np.maximum(np.hypot(vn[:, 0], vn[:, 1]), 1e-12)[:, None]
    line += vn * (t / 2 - inset)
    have = float(np.hypot(*np.diff(line, axis=0).T).sum())
    ext = min(max((length - have) / 2, 0.0), inset)
    for end, nxt in ((0, 1), (-1, -2)):
        d = line[end] - line[nxt]
        norm = float(np.hypot(*d))
        if norm > 0:
            line[end] = line[end] + d / norm * ext
    return line


def _signed_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def plan_shells(
    section: CrossSection, width: float, height: float, perimeters: int, thin_walls: bool,
    resolution: float,
) -> _Shells:
    """Perimeter loops (outermost first), thin-wall loops and the region left for infill."""
    s = bead_spacing(width, height)
    half = s / 2.0
    region = section
    loops: list[Path] = []
    lost_parts: list[CrossSection] = []
    for k in range(perimeters):
        if region.is_empty():
            break
        centre = region.offset(-half, MITER)
        # parts of the centre-line region narrower than one spacing would make a loop whose
        # two sides overlap: treat them as thin walls instead
        inner = centre.offset(-half, MITER)
        ok = inner.offset(half, MITER) if not inner.is_empty() else inner
        if not ok.is_empty():
            ok = ok ^ centre  # a miter re-grown at a sharp corner may poke out of the centre
        if not ok.is_empty():
            ok = ok.simplify(resolution)
            loops.extend(_loops(ok, width, "external_perimeter" if k == 0 else "perimeter"))
            if thin_walls:  # what the loops leave uncovered is printed as thin walls
                lost_parts.append(region - ok.offset(half, MITER))
            region = inner
        else:
            lost_parts.append(region)
            region = CrossSection()
    thin: list[Path] = []
    if thin_walls and _may_hold_thin_walls(lost_parts, s):
        lost = CrossSection.batch_boolean(lost_parts, OpType.Add) if len(lost_parts) > 1 \
            else lost_parts[0]
        thin = _thin_paths(lost, s, height)
    return _Shells(loops, thin, region)


def _may_hold_thin_walls(lost_parts: list[CrossSection], spacing: float) -> bool:
    """Whether the union of ``lost_parts`` can have a component as large as the smallest
    thin wall ``_thin_paths`` prints (half a spacing squared). The union's area is at most
    the parts' summed areas, so when those fall short, every component does: most layers
    lose only slivers at their corners, and their union and decomposition are skipped."""
    total = sum(part.area() for part in lost_parts)
    return total >= _min_thin_area(spacing) * (1.0 - 1e-6)


def _min_thin_area(spacing: float) -> float:
    """Area (mm²) below which a lost piece is too small to print as a thin wall."""
    return 0.5 * spacing * spacing


def skin_regions(
    inner: list[CrossSection], sections: list[CrossSection], top: int, bottom: int,
    spacing: list[float], all_solid: bool, ids: list[int] | None = None,
) -> list[CrossSection]:
    """Solid part of each layer's infill region: what is not covered by the ``top`` layers
    above and the ``bottom`` layers below (outside the model counts as uncovered).
    ``ids``: the sections' geometry.shape_ids, where known: a layer whose infill region
    (the same object) and sections from ``bottom`` below to ``top`` above repeat an earlier
    layer's has that layer's skin (a prism's layers)."""
    n = len(inner)
    out: list[CrossSection] = []
    common = _RunIntersections(sections)
    seen: dict[tuple, CrossSection] = {}
    for i in range(n):
        r = inner[i]
        if r.is_empty() or all_solid:
            out.append(r)
            continue
        if i - bottom < 0 or i + top >= n:
            out.append(r)
            continue
        if top + bottom == 0:  # no top or bottom layers asked for
            out.append(CrossSection())
            continue
        key = (id(r), spacing[i], tuple(ids[i - bottom:i + top + 1])) if ids else None
        if key in seen:
            out.append(seen[key])
            continue
        out.append(_skin(r, common.of(i - bottom, i + top + 1), spacing[i]))
        if key is not None:
            seen[key] = out[-1]
    return out


def _skin(r: CrossSection, covered: CrossSection, s: float) -> CrossSection:
    """The solid skin of infill region ``r`` where the layers around cover only
    ``covered``."""
    # the layer's own section joins the run: it holds ``r``, so it covers nothing less,
    # and one run of consecutive layers costs fewer intersections than two
    solid = r - covered
    if solid.is_empty():
        return solid
    # drop slivers, then grow a little into the sparse region to anchor the skin
    solid = solid.offset(-s / 2, MITER)
    if solid.is_empty():
        return solid
    return solid.offset(1.5 * s, MITER) ^ r


class _RunIntersections:
    """Intersections of runs of consecutive sections, ``of(lo, hi)`` = sections lo .. hi − 1,
    from a table of power-of-two runs built as asked: each run is the intersection of the two
    power-of-two runs that cover it (they may overlap: intersecting is idempotent), and each
    power-of-two run of two smaller ones. The skins of every layer look at the same few
    layers above and below, so each layer costs about three intersections, not one per
    neighbour."""

    def __init__(self, sections: list[CrossSection]) -> None:
        self.sections = sections
        self.table: dict[tuple[int, int], CrossSection] = {}

    def _power(self, lo: int, level: int) -> CrossSection:
        """Sections lo .. lo + 2**level − 1."""
        if level == 0:
            return self.sections[lo]
        key = (lo, level)
        got = self.table.get(key)
        if got is None:
            half = 1 << (level - 1)
            got = self._power(lo, level - 1) ^ self._power(lo + half, level - 1)
            self.table[key] = got
        return got

    def of(self, lo: int, hi: int) -> CrossSection:
        level = (hi - lo).bit_length() - 1
        first = self._power(lo, level)
        if hi - lo == 1 << level:
            return first
        return first ^ self._power(hi - (1 << level), level)


def bridge_region(solid: CrossSection, below: CrossSection | None, spacing: float
                  ) -> CrossSection:
    """The part of a layer's solid skin printed over air (not over the layer below)."""
    if below is None or solid.is_empty():
        return CrossSection()
    air = solid - below if not below.is_empty() else solid
    if air.is_empty():
        return air
    opened = air.offset(-spacing / 2, MITER)  # ignore slivers along the walls
    if opened.is_empty():
        return opened
    return opened.offset(spacing / 2, MITER) ^ solid


def bridge_angle(bridge: CrossSection, below: CrossSection, spacing: float) -> float:
    """Hatch angle (degrees) whose lines over ``bridge`` are best anchored on ``below``:
    the largest length fraction of lines with both ends (one spacing beyond) supported."""
    polys = contours(bridge)
    support = contours(below)
    best, best_score = 0.0, -1.0
    for ang in BRIDGE_ANGLES:
        score = line_anchoring(polys, support, ang, spacing, spacing)
        if score >= 0 and score > best_score + 1e-9:
            best, best_score = ang, score
    return best


def _hatch_paths(region: CrossSection, angles: list[float], spacing: float, width: float,
                 role: str, min_length: float) -> list[Path]:
    if region.is_empty():
        return []
    polys = contours(region)
    out: list[Path] = []
    for ang in angles:
        segs = hatch(polys, ang, spacing, 0.0, min_length)
        out.extend(Path(seg, False, width, role) for seg in segs)
    return out


def infill_paths(
    profile: Profile, layer_index: int, region: CrossSection, solid: CrossSection,
    width: float, height: float, below: CrossSection | None = None,
    above: CrossSection | None = None,
) -> list[Path]:
    """Bridges (solid skin over air, lines anchored across the gap), solid infill (100 %,
    alternating ±angle) and sparse infill (rectilinear/grid at infill_percent). Given the
    layer ``above`` (empty on the last layer), solid skin it does not cover is labelled
    top solid infill (the same lines, their own role)."""
    s = bead_spacing(width, height)
    base = profile.infill_angle
    alt = base if layer_index % 2 == 0 else base + 90.0
    out: list[Path] = []
    taken = solid  # everything printed solid on this layer, bridges included
    bridge = bridge_region(solid, below, s)
    if not bridge.is_empty():
        angle = bridge_angle(bridge, below, s)
        # anchor the bridge lines two spacings into the supported part of the region
        bridge = bridge.offset(2.0 * s, MITER) ^ region
        out += _hatch_paths(bridge, [angle], s, width, "bridge_infill", 0.25 * s)
        solid = solid - bridge
        taken = taken + bridge
    if above is not None and not solid.is_empty():
        top = solid - above if not above.is_empty() else solid
        out += _hatch_paths(top, [alt], s, width, "top_solid_infill", 0.25 * s)
        solid = solid - top
    out += _hatch_paths(solid, [alt], s, width, "solid_infill", 0.25 * s)
    pct = profile.infill_percent
    if pct <= 0 or region.is_empty():
        return out
    sparse = region - taken if not taken.is_empty() else region
    if sparse.is_empty():
        return out
    if pct >= 100:
        return out + _hatch_paths(sparse, [alt], s, width, "solid_infill", 0.25 * s)
    if profile.infill_pattern == "grid":
        return out + _hatch_paths(sparse, [base, base + 90.0], 2.0 * s * 100.0 / pct, width,
                                  "sparse_infill", s)
    return out + _hatch_paths(sparse, [alt], s * 100.0 / pct, width, "sparse_infill", s)


def skirt_paths(profile: Profile, first: CrossSection, width: float, height: float
                ) -> list[Path]:
    """Skirt loops around the first layer's convex hull, dropped if they would leave the bed."""
    if profile.skirts <= 0 or first.is_empty():
        return []
    s = bead_spacing(width, height)
    hull = first.hull()
    bx, by = profile.build_volume[0], profile.build_volume[1]
    out: list[Path] = []
    for j in range(profile.skirts):
        ring = hull.offset(profile.skirt_distance + s / 2 + j * s, JoinType.Round)
        polys = contours(ring.simplify(profile.resolution))
        if not polys:
            continue
        pts = np.concatenate(polys)
        m = width / 2
        if pts[:, 0].min() < m or pts[:, 1].min() < m or pts[:, 0].max() > bx - m \
                or pts[:, 1].max() > by - m:
            break
        out.extend(Path(p, True, width, "skirt") for p in polys)
    return out[::-1]  # outermost first
