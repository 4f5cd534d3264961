"""Overhang detection, layer by layer: what of each layer the layer below does not hold up.

Units mm, angles in degrees from vertical. A layer's area is *unsupported* where the layer
below, grown by ``layer_height · tan(support_angle)``, does not cover it. Each connected piece
of unsupported area is then either a **bridge** — straight lines across it, in the best of
twelve directions, end on the layer below at both sides for at least ``BRIDGE_ANCHORED`` of
their length; the planner prints those as bridge infill (across the gap, bridge speed, flow
and fan) and they get no support — or an **overhang** that needs support. Pieces smaller than
``min_area`` mm² are left alone (``support = auto``; ``everywhere`` passes 0).
"""

from __future__ import annotations

import math

import numpy as np
from manifold3d import CrossSection, JoinType

from slicer.geometry import contours, hatch, points_inside

#: share of a piece's line length that must be anchored at both ends for it to be a bridge
BRIDGE_ANCHORED = 0.8
BRIDGE_ANGLES = tuple(float(a) for a in range(0, 180, 15))


def unsupported(section: CrossSection, below: CrossSection, reach: float) -> CrossSection:
    """Part of ``section`` not within ``reach`` mm (horizontally) of the layer ``below``."""
    if section.is_empty():
        return section
    if below.is_empty():
        return section
    return section - below.offset(reach, JoinType.Miter)


def near_piece(part: CrossSection, box: tuple, grow: float) -> CrossSection:
    """The piece of ``part`` that can reach into ``box`` (x0, y0, x1, y1) when grown by
    ``grow`` with mitred corners (at most 2·grow out, manifold3d's miter limit). The cut
    edges, 3·grow and more outside the box, grow no nearer to it than 2·grow, so inside the
    box the grown piece and the grown part agree."""
    reach = 3.0 * grow + 1e-3
    pb = part.bounds()
    x0, y0, x1, y1 = box[0] - reach, box[1] - reach, box[2] + reach, box[3] + reach
    if (min(pb[2], x1) - max(pb[0], x0)) * (min(pb[3], y1) - max(pb[1], y0)) \
            > 0.5 * (pb[2] - pb[0]) * (pb[3] - pb[1]):
        return part  # most of it is near: cutting it would cost more than it saves
    window = CrossSection.square((x1 - x0, y1 - y0)).translate((x0, y0))
    return part ^ window


def anchored_share(piece: CrossSection, below: CrossSection, spacing: float) -> float:
    """Largest share (0..1), over the candidate directions, of line length across ``piece``
    whose two ends, one ``spacing`` beyond the piece, both land on ``below``. Test lines are
    at least 1/16 of the piece's size apart; only the part of ``below`` near the piece is
    looked at. Stops early once a direction reaches ``BRIDGE_ANCHORED``."""
    polys = contours(piece)
    if not polys:
        return 0.0
    pts = np.concatenate(polys)
    lo, hi = pts.min(axis=0) - 2 * spacing, pts.max(axis=0) + 2 * spacing
    window = CrossSection.square((float(hi[0] - lo[0]), float(hi[1] - lo[1]))).translate(
        (float(lo[0]), float(lo[1])))
    support = contours(below ^ window)
    if not support:
        return 0.0
    step = max(spacing, float(np.max(hi - lo)) / 16.0)
    best = 0.0
    for ang in BRIDGE_ANGLES:
        best = max(best, line_anchoring(polys, support, ang, step, spacing))
        if best >= BRIDGE_ANCHORED:
            break
    return best


def line_anchoring(polys: list[np.ndarray], support: list[np.ndarray], angle: float,
                   step: float, reach: float) -> float:
    """Share (0..1) of the length of lines at ``angle`` degrees, ``step`` mm apart, across
    ``polys`` whose two ends, ``reach`` mm beyond them, both land inside ``support``
    (-1 when no line crosses ``polys``)."""
    segs = hatch(polys, angle, step)
    if len(segs) == 0:
        return -1.0
    d = segs[:, 1] - segs[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(length, 1e-12)[:, None]
    ends = np.concatenate([segs[:, 0] - u * reach, segs[:, 1] + u * reach])
    inside = points_inside(support, ends)
    k = len(segs)
    return float(length[inside[:k] & inside[k:]].sum() / length.sum())


def needs_support(section: CrossSection, below: CrossSection, height: float, angle: float,
                  spacing: float, min_area: float) -> CrossSection:
    """The overhang of one layer that needs support: unsupported area that is not a bridge,
    in pieces of at least ``min_area`` mm²."""
    air = unsupported(section, below, height * math.tan(math.radians(angle)))
    if air.is_empty():
        return air
    keep: list[CrossSection] = []
    for piece in air.decompose():
        area = piece.area()
        if area < max(min_area, 1e-4):
            continue
        # a piece two lines or more wide (mean width 2·area / perimeter) might be a bridge;
        # slivers along a sloping wall are not
        if not below.is_empty() and 2 * area / _perimeter(piece) >= 2 * spacing \
                and anchored_share(piece, below, spacing) >= BRIDGE_ANCHORED:
            continue
        keep.append(piece)
    if not keep:
        return CrossSection()
    return CrossSection.compose(keep)


def _perimeter(cs: CrossSection) -> float:
    return float(sum(np.hypot(*(np.roll(q, -1, axis=0) - q).T).sum() for q in contours(cs)))


def overhangs(sections: list[CrossSection], heights: np.ndarray, angle: float,
              spacing: float, min_area: float, ids: list[int] | None = None
              ) -> list[CrossSection]:
    """Per layer, the area that needs support (layer 0 stands on the bed: empty).
    ``ids``: the sections' geometry.shape_ids, where known: a layer whose section, the one
    below and height repeat an earlier layer's has that layer's overhang (the same function
    of the same shapes; prismatic parts repeat most of their layers)."""
    out = [CrossSection()]
    seen: dict[tuple, CrossSection] = {}
    for i in range(1, len(sections)):
        key = (ids[i], ids[i - 1], float(heights[i])) if ids is not None else None
        found = seen.get(key) if key is not None else None
        if found is None:
            found = needs_support(sections[i], sections[i - 1], float(heights[i]), angle,
                                  spacing, min_area)
            if key is not None:
                seen[key] = found
        out.append(found)
    return out
