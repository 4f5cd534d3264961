"""Overhanging test models and the support checks (independent of slicer code).

**Unsupported extrusion.** For every part extrusion above the first layer: the share of its
length with no material (part or support) below it within ``reach = layer_height ·
tan(60°)`` horizontally. The part below is the model's own cross-section of the layer
underneath (its sparse infill holds up the skin over it, as in every slicer), grown by
``reach``; support is what the G-code deposited (``;TYPE:Support material...`` and any other
bead) on the layer underneath or the one under that: support ends one layer under the part
(the Z gap the issue asks for), so what holds up an overhang is two layers down. Segments
are sampled every ``STEP`` mm; a layer's beads are the sampled centre lines of its moves
(a k-d tree), a sample being held up when a centre line lies within ``reach + w/2``.

**Fusion.** No support bead comes closer to a part bead on the same layer than the XY gap:
the distance between their centre lines less half of each bead's spacing (the width its
deposited area stands for, from its E: ``de · filament area / (length · layer height)``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh
from gcode_replay import SUPPORT, Replay
from manifold3d import CrossSection, JoinType, Manifold
from scipy.spatial import cKDTree
from slice_checks import mesh_of

STEP = 0.1  # mm between samples along a segment
CORPUS = Path(__file__).resolve().parents[2].parent / "shared" / "corpus"
BUNNY = CORPUS / "mikedh_bunny.ply"


# ---- models ---------------------------------------------------------------------------
def mushroom():
    """A cap 28 mm across on a stem 8 mm across: 10 mm of overhang all round."""
    stem = Manifold.cylinder(15, 4, 4, 48)
    cap = Manifold.cylinder(5, 14, 14, 96).translate([0, 0, 15])
    return mesh_of(stem + cap)


def t_bracket():
    """A 6 mm web 16 mm tall under a 30 mm flange: 12 mm overhangs on both sides."""
    web = Manifold.cube([6, 20, 16]).translate([12, 0, 0])
    flange = Manifold.cube([30, 20, 4]).translate([0, 0, 16])
    return mesh_of(web + flange)


def arch():
    """A 40 mm wide, 10 mm deep block with a semicircular opening of radius 14 mm."""
    block = Manifold.cube([40, 10, 20])
    hole = Manifold.cylinder(30, 14, 14, 96).rotate([-90, 0, 0]).translate([20, -10, 0])
    return mesh_of(block - hole)


def comb():
    """A 10 × 20 × 10 mm block with five fins 1.6 mm wide and 8 mm long sticking out of its
    top, 4 mm apart: narrow overhangs, at every offset from the support lines across them."""
    block = Manifold.cube([10, 20, 10])
    for j in range(5):
        block = block + Manifold.cube([8, 1.6, 2]).translate([10, 4 * j, 8])
    return mesh_of(block)


def ramp(angle: float, height: float = 10.0):
    """A 20 mm wide block whose front face leans out at ``angle`` degrees from vertical."""
    run = height * math.tan(math.radians(angle))
    base = 6.0
    profile = CrossSection([np.array([[0, 0], [base, 0], [base + run, height], [0, height]])])
    solid = Manifold.extrude(profile, 20.0)  # along z: x-profile in the xy plane
    return mesh_of(solid.rotate([90, 0, 0]))


def rotated_bunny():
    """The corpus bunny (an open scan), repaired, in mm, upright and tipped 20° forward
    so that its chin and chest overhang."""
    from repair.pipeline import repair_mesh

    scan = trimesh.load(BUNNY)
    v = np.asarray(scan.vertices) * 250.0  # about 39 × 30 × 38 mm
    v = v[:, [0, 2, 1]] * [1.0, -1.0, 1.0]  # the scan's y is up
    tip = trimesh.transformations.rotation_matrix(math.radians(-20), [0, 1, 0])[:3, :3]
    repaired = repair_mesh(v @ tip.T, np.asarray(scan.faces))
    return repaired.vertices, repaired.faces


# ---- checks ---------------------------------------------------------------------------
def _samples(rep: Replay, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points every STEP mm along moves ``idx`` (segment midpoints of the pieces) and the
    move each belongs to."""
    p0 = rep.start[idx, :2]
    d = rep.end[idx, :2] - p0
    length = np.hypot(d[:, 0], d[:, 1])
    count = np.maximum(np.ceil(length / STEP).astype(np.int64), 1)
    owner = np.repeat(np.arange(len(idx)), count)
    first = np.cumsum(count) - count
    t = (np.arange(count.sum()) - first[owner] + 0.5) / count[owner]
    return p0[owner] + d[owner] * t[:, None], idx[owner]


def inside(polys: list[np.ndarray], pts: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test, vectorised over points and edges."""
    out = np.zeros(len(pts), dtype=bool)
    if not polys or len(pts) == 0:
        return out
    a = np.concatenate(polys)
    b = np.concatenate([np.roll(q, -1, axis=0) for q in polys])
    step = max(1, 4_000_000 // len(a))
    for i0 in range(0, len(pts), step):
        px, py = pts[i0:i0 + step, :1], pts[i0:i0 + step, 1:]
        straddle = (a[None, :, 1] > py) != (b[None, :, 1] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        out[i0:i0 + step] = np.count_nonzero(straddle & (px < x), axis=1) % 2 == 1
    return out


def unsupported_share(rep: Replay, solid: Manifold, line_width: float, angle: float = 60.0
                      ) -> tuple[float, dict[float, float]]:
    """(unsupported share of all part extrusion above the first layer, per-layer share);
    ``solid`` is the model as placed on the bed."""
    layers = rep.layers()
    zs = sorted(layers)
    part = rep.part
    trees: list[cKDTree | None] = []
    for z in zs:
        pts, _ = _samples(rep, layers[z])
        trees.append(cKDTree(pts) if len(pts) else None)
    seglen = np.hypot(*(rep.end[:, :2] - rep.start[:, :2]).T)
    bad = total = 0.0
    per_layer: dict[float, float] = {}
    for k in range(1, len(zs)):
        idx = layers[zs[k]]
        idx = idx[part[idx]]
        if len(idx) == 0:
            continue
        h = zs[k] - zs[k - 1]
        reach = h * math.tan(math.radians(angle)) + line_width / 2
        pts, owner = _samples(rep, idx)
        held = np.zeros(len(pts), dtype=bool)
        for j in (k - 1, k - 2):
            if j >= 0 and trees[j] is not None:
                dist, _ = trees[j].query(pts, distance_upper_bound=reach)
                held |= np.isfinite(dist)
        below = solid.slice(zs[k - 1] - (zs[k - 1] - (zs[k - 2] if k > 1 else 0.0)) / 2)
        grown = below.offset(h * math.tan(math.radians(angle)), JoinType.Round)
        rest = np.flatnonzero(~held)
        held[rest] = inside([np.asarray(q, float) for q in grown.to_polygons()], pts[rest])
        # each sample stands for an equal share of its move's length
        weight = seglen[owner] / np.bincount(owner, minlength=len(seglen))[owner]
        layer_bad = float(weight[~held].sum())
        layer_total = float(seglen[idx].sum())
        per_layer[zs[k]] = layer_bad / layer_total
        bad += layer_bad
        total += layer_total
    return (bad / total if total else 0.0), per_layer


def support_clearance(rep: Replay, filament_diameter: float) -> float:
    """Smallest gap (mm) between the edges of a support bead and a part bead on the same
    layer (inf without support)."""
    support = rep.extruding & rep.labelled(*SUPPORT)
    part = rep.part
    layers = rep.layers()
    zs = sorted(layers)
    area = math.pi * (filament_diameter / 2) ** 2
    length = np.maximum(np.hypot(*(rep.end[:, :2] - rep.start[:, :2]).T), 1e-12)
    best = math.inf
    for z, h in zip(zs, np.diff(zs, prepend=0.0), strict=True):
        idx = layers[z]
        s_idx, p_idx = idx[support[idx]], idx[part[idx]]
        if len(s_idx) == 0 or len(p_idx) == 0:
            continue
        half = rep.de * area / (length * h) / 2  # half the bead spacing of each move
        p_pts, p_own = _samples(rep, p_idx)
        s_pts, s_own = _samples(rep, s_idx)
        dist, j = cKDTree(p_pts).query(s_pts, k=min(8, len(p_pts)))
        dist, j = dist.reshape(len(s_pts), -1), j.reshape(len(s_pts), -1)
        gap = dist - half[p_own[j]] - half[s_own][:, None]
        best = min(best, float(gap.min()))
    return best


def floating_support_share(rep: Replay, reach: float) -> float:
    """Share of the support extrusion above the first layer (length) with nothing extruded
    on the layer below within ``reach`` mm of it: a column left out under support above
    it. Base lines stack on the base lines below; interface lines cross them, so ``reach``
    is half the base line spacing and a bead."""
    support = rep.extruding & rep.labelled(*SUPPORT)
    layers = rep.layers()
    zs = sorted(layers)
    bad = total = 0.0
    for k in range(1, len(zs)):
        idx = layers[zs[k]]
        idx = idx[support[idx]]
        if len(idx) == 0:
            continue
        pts, owner = _samples(rep, idx)
        below, _ = _samples(rep, layers[zs[k - 1]])
        dist, _ = cKDTree(below).query(pts, distance_upper_bound=reach)
        weight = 1.0 / np.bincount(owner, minlength=len(rep.de))[owner]
        seglen = np.hypot(*(rep.end[owner, :2] - rep.start[owner, :2]).T)
        bad += float((seglen * weight)[~np.isfinite(dist)].sum())
        total += float((seglen * weight).sum())
    return bad / total if total else 0.0
