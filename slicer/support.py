"""Support material: columns under the overhangs (slicer.overhang), as lines that snap off.

Units mm. Built top-down, one layer at a time, with manifold3d booleans on cross-sections:

- an overhang found on layer k (grown by half a line so the support reaches under its edge)
  is carried down from layer k − 2: layer k − 1 stays empty, the **Z gap** of one layer
  between support and the part above;
- a column stops where it meets the part (it stands on the part's top, ``everywhere`` and
  ``auto``) and on every layer keeps ``support_xy_gap`` mm away from the part (**XY gap**);
  it also stays clear of the layer below's part, the Z gap under support standing on the part;
- ``buildplate`` keeps only columns with no part anywhere below them;
- the ``support_interface_layers`` layers under the part are **interface**: an outline and
  dense lines at ``support_interface_spacing``, across the base lines; the rest is base
  support: parallel lines ``support_spacing`` apart, in the same direction on every layer
  (stacked into thin walls that break off sideways), joined into serpentines where they
  can be, with no outline loop but on the first layer (and around an island too narrow
  for any line), as PrusaSlicer's support has none on its inner layers.

Support lines get their own role, so G-code has its own speed, flow and ``;TYPE:`` label.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from manifold3d import CrossSection, FillRule, JoinType, OpType

from slicer.geometry import bead_spacing, contours, hatch, points_inside, shape_key
from slicer.overhang import near_piece, overhangs
from slicer.planner import Path
from slicer.profile import Profile

MITER = JoinType.Miter
BASE_ANGLE = 0.0  # base lines along x; interface lines along y


@dataclass(slots=True)
class SupportLayer:
    """One layer's support: base region and interface (dense) region, disjoint.
    ``sheath``: the base gets an outline loop too (the first layer, for its grip on the bed)."""

    base: CrossSection
    interface: CrossSection
    sheath: bool = False

    def is_empty(self) -> bool:
        return self.base.is_empty() and self.interface.is_empty()

    def area(self) -> CrossSection:
        return self.base + self.interface


def bead_area_of(paths: list[Path]) -> CrossSection:
    """The area covered by the beads of ``paths`` (segments as rectangles, joints and ends
    as octagons around the points, of the path's width)."""
    if not paths:
        return CrossSection()
    shapes: list[np.ndarray] = []
    ring = np.linspace(0.0, 2 * np.pi, 9)[:-1]
    unit = np.stack([np.cos(ring), np.sin(ring)], axis=1)
    for path in paths:
        pts = np.vstack([path.points, path.points[:1]]) if path.closed else path.points
        r = path.width / 2
        d = np.diff(pts, axis=0)
        length = np.hypot(d[:, 0], d[:, 1])
        ok = length > 1e-9
        nrm = np.stack([-d[ok, 1], d[ok, 0]], axis=1) / length[ok, None] * r
        a, b = pts[:-1][ok], pts[1:][ok]
        shapes.extend(np.stack([a - nrm, b - nrm, b + nrm, a + nrm], axis=1))
        shapes.extend(pts[:, None, :] + unit[None] * r)
    return CrossSection(shapes, FillRule.Positive)


def support_regions(sections: list[CrossSection], heights: np.ndarray, profile: Profile,
                    widths: list[float], printed: list[CrossSection] | None = None,
                    ids: list[int] | None = None) -> list[SupportLayer] | None:
    """Support of every layer, or None when the model needs none (or support is off).
    ``printed``: per layer, part beads that stand out of the section (thin-wall ends), which
    the support keeps its XY gap from as well. ``ids``: the sections' geometry.shape_ids,
    where known (repeated layers are then worked out once)."""
    p = profile
    if p.support == "off":
        return None
    n = len(sections)
    min_area = 0.0 if p.support == "everywhere" else p.support_min_area
    s = bead_spacing(p.line_width, p.layer_height)
    need = overhangs(sections, heights, p.support_angle, s, min_area, ids)
    if all(o.is_empty() for o in need):
        return None
    tol = support_tolerance(p)
    # grow each overhang by half a line so the support reaches under its edge beads
    need = [o if o.is_empty() else o.offset(p.line_width / 2, MITER).simplify(tol)
            for o in need]
    regions = _columns(sections, need, p, widths, printed, ids)
    if p.support == "buildplate":
        below = CrossSection()
        for i in range(len(sections)):
            if not below.is_empty() and not regions[i].is_empty():
                regions[i] = _opened(regions[i] - below, widths[i] / 4)
            below = below + sections[i]
    k = max(p.support_interface_layers, 0)
    # the columns of layer i can reach into the part above (the interface) only with
    # overhangs of layers i + 2 .. i + k + 2, added to them less than k + 1 layers up: the
    # older ones had the part's layers i + 2 .. i + k + 1 cut out on their way down
    fresh = np.convolve([not o.is_empty() for o in need], np.ones(k + 1), "full")[k:]
    out = [_with_interface(r, sections[i + 2:i + 2 + k] if i + 2 < n and fresh[i + 2] else [])
           for i, r in enumerate(regions)]
    if all(layer.is_empty() for layer in out):
        return None
    out[0].sheath = True
    return out


def support_tolerance(profile: Profile) -> float:
    """How far (mm) the support columns' outlines may stray from the overhangs they hold up
    when simplified: an eighth of a line, well inside the half line they are grown by; their
    edges along the part (the XY gap) are not simplified."""
    return max(profile.resolution, profile.line_width / 8)


def _columns(sections: list[CrossSection], need: list[CrossSection], p: Profile,
             widths: list[float], printed: list[CrossSection] | None,
             ids: list[int] | None = None) -> list[CrossSection]:
    """Per layer, the support columns (before the interface split): the overhangs carried
    down, top to bottom, clear of the part by the XY gap and of the part below by the Z gap.
    Slivers are left in: support_paths' outline, half a bead in, drops whatever is narrower
    than a bead, so opening the region here (as before) changed no path. With the sections'
    ``ids``, a section just cut out of the columns is not cut out again on the layers below
    that repeat it (a column down a prism's side): the same shape again changes nothing but
    rounding, which made every layer's column differ from the one above by ~1e-7 mm."""
    n = len(sections)
    tol = support_tolerance(p)
    regions: list[CrossSection] = [CrossSection()] * n
    carried = CrossSection()
    cut_out = None  # the shape last cut out of ``carried``, nothing added to it since
    version = 0  # counts the changes of ``carried``
    done: dict[tuple, CrossSection] = {}  # a layer like one above: the same region
    for i in range(n - 1, -1, -1):
        if i + 2 < n and not need[i + 2].is_empty():
            carried = (carried + need[i + 2]).simplify(tol)
            cut_out, version = None, version + 1
        if carried.is_empty():
            continue
        box = carried.bounds()
        if _overlap(box, sections[i].bounds(), 0.0) and (ids is None or ids[i] != cut_out):
            carried = carried - sections[i]  # the column stands on the part here
            cut_out, version = (ids[i] if ids is not None else None), version + 1
            if carried.is_empty():
                continue
        key = None
        if ids is not None and (printed is None or printed[i].is_empty()):
            key = (version, ids[i], ids[i - 1] if i > 0 else -1)
            if key in done:
                regions[i] = done[key]
                continue
        part = sections[i]
        if printed is not None and not printed[i].is_empty():
            part = part + printed[i]
        cut = [c for c, grow in ((part, p.support_xy_gap),
                                 (sections[i - 1] if i > 0 else CrossSection(), 0.0))
               if not c.is_empty() and _overlap(box, c.bounds(), grow)]
        if cut and cut[0] is part:
            cut[0] = near_piece(part, box, p.support_xy_gap).offset(p.support_xy_gap, MITER)
        region = CrossSection.batch_boolean([carried, *cut], OpType.Subtract) if cut \
            else carried
        regions[i] = region
        if key is not None:
            done[key] = region
    return regions


def _overlap(a: tuple, b: tuple, grow: float) -> bool:
    """Whether bounding boxes ``a`` and ``b`` (x0, y0, x1, y1), ``b`` grown by ``grow``, meet."""
    return not (b[0] - grow > a[2] or b[2] + grow < a[0] or b[1] - grow > a[3]
                or b[3] + grow < a[1])


def _with_interface(region: CrossSection, roof: list[CrossSection]) -> SupportLayer:
    """Split a layer's support into base and interface: the interface is the part of it
    under the part's next layers above the Z gap (``roof``: those layers' sections)."""
    if region.is_empty() or not roof:
        return SupportLayer(region, CrossSection())
    box = region.bounds()
    roof = [r for r in roof if not r.is_empty() and _overlap(box, r.bounds(), 0.0)]
    if not roof:
        return SupportLayer(region, CrossSection())
    base = CrossSection.batch_boolean([region, *roof], OpType.Subtract)
    if base.area() >= region.area() - 1e-9:
        return SupportLayer(region, CrossSection())
    return SupportLayer(base, region - base)


def _opened(region: CrossSection, r: float) -> CrossSection:
    """``region`` without slivers narrower than 2·r."""
    if region.is_empty():
        return region
    shrunk = region.offset(-r, MITER)
    return shrunk if shrunk.is_empty() else shrunk.offset(r, MITER) ^ region


def support_paths(layer: SupportLayer, profile: Profile, width: float, height: float,
                  cache: dict | None = None) -> list[Path]:
    """Outline loops and lines of one layer's support (base and interface). Columns repeat
    from layer to layer: with a ``cache`` (one dict per job), a region identical to one
    seen before reuses its paths (they are never modified downstream)."""
    s = bead_spacing(width, height)
    out: list[Path] = []
    for region, role, spacing, angle in (
            (layer.base, "support", profile.support_spacing, BASE_ANGLE),
            (layer.interface, "support_interface", profile.support_interface_spacing,
             BASE_ANGLE + 90.0)):
        if region.is_empty():
            continue
        outline = layer.sheath or role == "support_interface"
        key = None
        if cache is not None:
            key = (role, outline, width, height, hash(shape_key(region)))
            if key in cache:
                out.extend(cache[key])
                continue
        paths = _region_paths(region, role, spacing, angle, width, s, profile.resolution,
                              outline)
        if key is not None:
            if len(cache) > 64:
                cache.clear()
            cache[key] = paths
        out.extend(paths)
    return out


def _region_paths(region: CrossSection, role: str, spacing: float, angle: float,
                  width: float, s: float, resolution: float, outline: bool) -> list[Path]:
    """Lines across ``region`` (joined where they can be) and, with ``outline``, a loop
    around it: every bead stays inside ``region``. Without ``outline``, an island too
    small for any line gets its loop instead, so that no column is left out."""
    ring = region.offset(-s / 2, MITER).simplify(resolution)  # where bead centres may go
    if ring.is_empty():
        return []
    step = max(spacing, s)
    if not outline:
        out: list[Path] = []
        for island in (ring.decompose() if ring.num_contour() > 1 else [ring]):
            edge = contours(island)
            segs = hatch(edge, angle, step, 0.0, s)
            if len(segs) == 0:
                out.extend(Path(q, True, width, role) for q in edge)
            out.extend(Path(line, False, width, role) for line in zigzag(segs, edge, step))
        return out
    edge = contours(ring)
    out = [Path(q, True, width, role) for q in edge]
    core = ring.offset(-s / 2, MITER)  # lines end on the outline's inner edge
    if core.is_empty():
        return out
    segs = hatch(contours(core), angle, step, 0.0, s)
    out.extend(Path(line, False, width, role) for line in zigzag(segs, edge, step))
    return out


def zigzag(segs: np.ndarray, region: list[np.ndarray], spacing: float) -> list[np.ndarray]:
    """Join serpentine hatch segments (k, 2, 2) into polylines where the step from one
    segment's end to the next one's start is short (≤ 2 spacings) and stays inside
    ``region``: fewer, longer paths, fewer travels and retractions."""
    if len(segs) == 0:
        return []
    a, b = segs[:-1, 1], segs[1:, 0]
    step = np.hypot(*(b - a).T)
    ok = step <= 2.0 * spacing
    idx = np.flatnonzero(ok)
    if len(idx):
        t = np.array([0.25, 0.5, 0.75])
        probe = a[idx, None, :] + (b[idx] - a[idx])[:, None, :] * t[None, :, None]
        inside = points_inside(region, probe.reshape(-1, 2)).reshape(len(idx), 3)
        ok[idx] = inside.all(axis=1)
    pts = segs.reshape(-1, 2)
    breaks = 2 * (np.flatnonzero(~ok) + 1)
    return np.split(pts, breaks)
