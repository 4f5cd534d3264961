"""Brim: loops around the first layer's outer outline, so that a part with a small footprint
against its height does not come loose from the bed.

The rule (``brim = auto``): a brim is printed when the part is more than
``TALL_RATIO`` times as tall as the square root of its first layer's contact area (a
5 × 5 × 80 mm pin: 80 > 3 · 5, brim; a 20 mm cube: 20 < 3 · 20, none). ``brim = on`` always
prints one, ``off`` never; its width is ``brim_width`` mm. Holes in the first layer get no
brim (it would be trapped inside the part).
"""

from __future__ import annotations

import math

import numpy as np
from manifold3d import CrossSection, FillRule, JoinType

from slicer.geometry import bead_spacing, contours
from slicer.planner import Path
from slicer.profile import Profile

TALL_RATIO = 3.0


def needs_brim(profile: Profile, first: CrossSection, height: float) -> bool:
    """Whether the profile and the part's shape ask for a brim (see the module's rule)."""
    if profile.brim == "off" or profile.brim_width <= 0 or first.is_empty():
        return False
    if profile.brim == "on":
        return True
    return height > TALL_RATIO * math.sqrt(max(first.area(), 1e-12))


def _outer(first: CrossSection) -> CrossSection:
    """The first layer with its holes filled (outer contours only)."""
    outer = [p for p in contours(first) if _signed_area(p) > 0]
    return CrossSection(outer, FillRule.Positive) if outer else CrossSection()


def _signed_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def brim_paths(profile: Profile, first: CrossSection, width: float, height: float
               ) -> tuple[list[Path], CrossSection]:
    """Brim loops, innermost first, touching the part's outer outline, and the area they
    cover (for the skirt to go around). Loops that would leave the bed are dropped."""
    s = bead_spacing(width, height)
    base = _outer(first)
    if base.is_empty():
        return [], CrossSection()
    count = max(1, int(round(profile.brim_width / s)))
    bx, by = profile.build_volume[0], profile.build_volume[1]
    m = width / 2
    out: list[Path] = []
    reach = 0.0
    for j in range(count):
        ring = base.offset(s / 2 + j * s, JoinType.Round).simplify(profile.resolution)
        polys = [q for q in contours(ring) if _signed_area(q) > 0]
        if not polys:
            continue
        pts = np.concatenate(polys)
        if pts[:, 0].min() < m or pts[:, 1].min() < m or pts[:, 0].max() > bx - m \
                or pts[:, 1].max() > by - m:
            break
        out.extend(Path(q, True, width, "brim") for q in polys)
        reach = s / 2 + j * s + s / 2
    covered = base.offset(reach, JoinType.Round) if out else CrossSection()
    return out, covered
