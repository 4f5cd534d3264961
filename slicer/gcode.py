"""G-code emission and the trapezoidal print-time estimate.

Units: mm, mm/s (F words are mm/min), °C. Extrusion per mm of path is the bead cross-section
``h·(w − h·(1 − π/4))`` divided by the filament area, times the extrusion multiplier. E is
relative (M83) or absolute (M82, reset with G92 E0 at each layer) per the profile. Whole
polylines are formatted with one ``%`` operation each; no per-point Python formatting.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from slicer.geometry import bead_area, polygon_edges, segments_cross
from slicer.planner import LayerPlan, Path
from slicer.profile import Profile
from slicer.templates import render_template
from slicer.travel import TravelRouter

#: PrusaSlicer's ``;TYPE:`` names for the planner's path roles (G-code viewers read them)
FEATURE_LABELS = {
    "external_perimeter": "External perimeter", "perimeter": "Perimeter",
    "thin_wall": "External perimeter", "sparse_infill": "Internal infill",
    "solid_infill": "Solid infill", "top_solid_infill": "Top solid infill",
    "bridge_infill": "Bridge infill", "support": "Support material",
    "support_interface": "Support material interface", "skirt": "Skirt/Brim",
    "brim": "Skirt/Brim",
}
SUPPORT_ROLES = ("support", "support_interface")


def trapezoid_time(pts: np.ndarray, speed: np.ndarray, accel: np.ndarray, jerk: float) -> float:
    """Seconds to run the XY polyline ``pts`` (n, 2) whose moves have cruise ``speed`` (n-1,)
    mm/s and acceleration ``accel`` (n-1,) mm/s², with jerk-limited junction speeds."""
    if len(pts) < 2:
        return 0.0
    d = np.diff(pts, axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    keep = length > 1e-9
    d, length, v, a = d[keep], length[keep], speed[keep], accel[keep]
    if len(length) == 0:
        return 0.0
    u = d / length[:, None]
    cosang = np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1.0, 1.0)
    sin_half = np.sqrt(np.maximum((1.0 - cosang) / 2.0, 1e-12))
    vj = np.minimum(np.minimum(v[:-1], v[1:]), jerk / (2.0 * sin_half))
    v0 = np.minimum(np.concatenate([[jerk / 2], vj]), v)
    v1 = np.minimum(np.concatenate([vj, [jerk / 2]]), v)
    d_acc = (v * v - v0 * v0) / (2 * a)
    d_dec = (v * v - v1 * v1) / (2 * a)
    trap = d_acc + d_dec <= length
    t_trap = (v - v0) / a + (v - v1) / a + (length - d_acc - d_dec) / v
    vp = np.sqrt(np.maximum((2 * a * length + v0 * v0 + v1 * v1) / 2, 0.0))
    feasible = vp >= np.maximum(v0, v1)
    t_tri = np.where(feasible, (vp - v0) / a + (vp - v1) / a,
                     2 * length / np.maximum(v0 + v1, 1e-9))
    return float(np.where(trap, t_trap, t_tri).sum())


@dataclass
class LayerCode:
    """One layer's G-code body (without the header) and what it costs."""

    text: str
    seconds: float
    filament_mm: float
    end_pos: np.ndarray
    support_mm: float = 0.0  # filament of support lines
    support_seconds: float = 0.0  # their share of ``seconds`` (by cruise time)


class GcodeWriter:
    """Turns ordered layer paths into G-code text; keeps E, feedrate and position state."""

    def __init__(self, profile: Profile) -> None:
        self.p = profile
        self.e_abs = 0.0
        self.feed = -1.0
        self.retracted = False

    # ---- per-role settings -------------------------------------------------------------
    def speed(self, role: str, first_layer: bool) -> float:
        p = self.p
        if first_layer or role in ("skirt", "brim"):
            return p.first_layer_speed
        return {
            "support": p.support_speed,
            "support_interface": p.support_interface_speed,
            "top_solid_infill": p.solid_infill_speed,
            "external_perimeter": p.external_perimeter_speed,
            "perimeter": p.perimeter_speed,
            "thin_wall": p.thin_wall_speed,
            "bridge_infill": p.bridge_speed,
            "solid_infill": p.solid_infill_speed,
            "sparse_infill": p.infill_speed,
        }.get(role, p.perimeter_speed)

    def e_per_mm(self, width: float, height: float) -> float:
        return bead_area(width, height) / self.p.filament_area * self.p.extrusion_multiplier

    def flow(self, role: str) -> float:
        """Per-role extrusion multiplier on top of the profile's (bridges, support)."""
        if role == "bridge_infill":
            return self.p.bridge_flow
        return self.p.support_flow if role in SUPPORT_ROLES else 1.0

    # ---- text pieces -------------------------------------------------------------------
    def _e_move(self, delta: float, feed: float) -> str:
        if self.p.relative_e:
            return f"G1 E{delta:.5f} F{feed:.0f}\n"
        self.e_abs += delta
        return f"G1 E{self.e_abs:.5f} F{feed:.0f}\n"

    def layer(self, plan: LayerPlan, ordered: list[tuple[np.ndarray, Path]],
              pos: np.ndarray, router: TravelRouter | None = None) -> LayerCode:
        """G-code for one layer starting at XY ``pos`` (its Z move is emitted by the caller).
        With a ``router``, travels that would cross the outline go around inside the part.

        All segment lengths, E values and the time estimate are computed for the whole layer
        at once; the text is produced by one ``%`` formatting of a layer-wide template.
        """
        first = plan.index == 0
        self.feed = -1.0  # the layer's Z move changes the modal F
        head = ""
        if not self.p.relative_e:
            head = "G92 E0\n"
            self.e_abs = 0.0
        pos = np.asarray(pos, dtype=np.float64)
        if not ordered:
            return LayerCode(head, 0.0, 0.0, pos)
        paths = _LayerPaths.of(ordered)
        # per (role, width), not per path: a layer has hundreds of paths, a handful of kinds
        kinds: dict[tuple[str, float], tuple[float, float]] = {}
        for o in ordered:
            kind = (o[1].role, o[1].width)
            if kind not in kinds:
                kinds[kind] = (self.speed(kind[0], first),
                               self.e_per_mm(kind[1], plan.height) * self.flow(kind[0]))
        per_path = np.array([kinds[(o[1].role, o[1].width)] for o in ordered])
        speeds, epm = per_path[:, 0].copy(), per_path[:, 1].copy()
        travels = self._travels(plan, paths, pos, router)
        beads = self._beads(paths, epm)
        seconds, speeds = self._timing(paths, travels, beads, pos, speeds)
        is_support = np.array([o[1].role in SUPPORT_ROLES for o in ordered])
        support_mm = support_s = 0.0
        if is_support.any():
            support_mm = float(beads.e[is_support[beads.path]].sum())
            cruise = np.bincount(beads.path, beads.length, minlength=paths.count) / speeds
            support_s = seconds * float(cruise[is_support].sum() / max(cruise.sum(), 1e-12))
        text = self._text(plan, ordered, travels, beads, speeds, head)
        return LayerCode(text, seconds, float(beads.e.sum()), paths.points[-1].copy(),
                         support_mm, support_s)

    def _travels(self, plan: LayerPlan, paths: _LayerPaths, pos: np.ndarray,
                 router: TravelRouter | None) -> _Travels:
        """The travel into each path, its route and whether it retracts: when it leaves the
        part or is long (with a router), else when long or crossing the outline."""
        p = self.p
        prev = np.vstack([pos[None], paths.points[paths.ends[:-1] - 1]])
        starts = paths.points[paths.begins]
        dist = np.hypot(*(starts - prev).T)
        moving = dist > 1e-6
        routes = router.plan(prev, starts, moving) if router is not None else None
        if routes is not None:
            retract = moving & (routes.leaves | (routes.length > p.retract_min_travel))
        else:
            retract = moving & (dist > p.retract_min_travel)
            short = np.flatnonzero(moving & ~retract)
            if len(short) and plan.outline:
                a, b = polygon_edges(plan.outline)
                retract[short] = segments_cross(prev[short], starts[short], a, b)
        if p.retract_length <= 0:
            retract[:] = False
        return _Travels(starts, dist, moving, retract, routes)

    def _beads(self, paths: _LayerPaths, epm: np.ndarray) -> _Beads:
        """The extrusion segments within paths (too short ones dropped), their E values and
        the flat ``x, y, e`` list the text is formatted from."""
        pts, ends = paths.points, paths.ends
        seg = np.diff(pts, axis=0)
        seglen = np.hypot(seg[:, 0], seg[:, 1])
        inside = np.ones(len(seglen), dtype=bool)
        inside[ends[:-1] - 1] = False  # boundary between paths: a travel, not a segment
        kept = np.flatnonzero(inside & (seglen > 1e-4))
        seg_path = np.repeat(np.arange(paths.count), paths.counts)[1:]
        kpath = seg_path[kept]
        e = seglen[kept] * epm[kpath]
        block = np.empty((len(kept), 3))
        block[:, :2] = pts[kept + 1]
        block[:, 2] = e if self.p.relative_e else self.e_abs + np.cumsum(e)
        return _Beads(kpath, seglen[kept], e, np.bincount(kpath, minlength=paths.count),
                      block.ravel().tolist())

    def _timing(self, paths: _LayerPaths, travels: _Travels, beads: _Beads, pos: np.ndarray,
                speeds: np.ndarray) -> tuple[float, np.ndarray]:
        """The layer's time (s), the whole layer as one polyline with travels, and the path
        speeds: a layer faster than min_layer_time is slowed down (not below
        min_print_speed) so it can cool."""
        p = self.p
        seq = np.vstack([pos[None], paths.points])
        active = travels.moving & (beads.per_path > 0)
        n_retract = int((travels.retract & active).sum())
        lift = p.retract_lift
        extra = n_retract * (2 * p.retract_length / p.retract_speed
                             + (2 * lift / p.travel_speed if lift > 0 else 0.0))
        if travels.routes is not None:  # detours, at travel speed
            extra += float((travels.routes.length - travels.dist)[active].sum()) / p.travel_speed
        accel = np.full(len(paths.points), p.print_acceleration)
        accel[paths.begins] = p.travel_acceleration

        def layer_seconds(path_speeds: np.ndarray) -> float:
            v = np.repeat(path_speeds, paths.counts)  # speed of the segment ending at each point
            v[paths.begins] = p.travel_speed
            return trapezoid_time(seq, v, accel, p.max_jerk) + extra

        seconds = layer_seconds(speeds)
        for _ in range(2):
            if p.min_layer_time <= 0 or seconds >= p.min_layer_time * 0.999:
                break
            floor = np.minimum(speeds, p.min_print_speed)
            speeds = np.maximum(speeds * (seconds / p.min_layer_time), floor)
            seconds = layer_seconds(speeds)
        return seconds, speeds

    def _travel_text(self, i: int, travels: _Travels, z: float, e_abs: float,
                     fmt: list[str], vals: list[float]) -> float:
        """Append the travel into path ``i`` (retract, lift, route, return); the feed left."""
        p = self.p
        travel_f = p.travel_speed * 60.0
        r_feed = p.retract_speed * 60.0
        lift = p.retract_lift
        if travels.retract[i]:
            fmt.append("G1 E%.5f F%.0f\n")
            vals += (-p.retract_length if p.relative_e else e_abs - p.retract_length, r_feed)
            if lift > 0:
                fmt.append("G1 Z%.3f F%.0f\n")
                vals += (z + lift, travel_f)
        way = travels.routes.waypoints[i] if travels.routes is not None else None
        if way is not None:
            fmt.append("G0 X%.3f Y%.3f F%.0f\n" * len(way))
            vals += [c for pt in way.tolist() for c in (pt[0], pt[1], travel_f)]
        fmt.append("G0 X%.3f Y%.3f F%.0f\n")
        vals += (float(travels.starts[i, 0]), float(travels.starts[i, 1]), travel_f)
        if not travels.retract[i]:
            return travel_f
        if lift > 0:
            fmt.append("G1 Z%.3f F%.0f\n")
            vals += (z, travel_f)
        fmt.append("G1 E%.5f F%.0f\n")
        vals += (p.retract_length if p.relative_e else e_abs, r_feed)
        return r_feed

    def _text(self, plan: LayerPlan, ordered: list[tuple[np.ndarray, Path]],
              travels: _Travels, beads: _Beads, speeds: np.ndarray, head: str) -> str:
        """The layer's text: travels, ``;TYPE:`` labels, bridge fan changes, feeds, beads."""
        p = self.p
        fmt: list[str] = [head]
        vals: list[float] = []
        cursor = 0
        e_abs = self.e_abs
        feed = -1.0
        # bridges get their own fan speed; the layer's own is restored after them
        normal_fan = p.fan_speed if plan.index >= p.disable_fan_first_layers else 0.0
        in_bridge = False
        label = ""
        for i in range(len(ordered)):
            m = int(beads.per_path[i])
            if m == 0:
                continue
            if travels.moving[i]:
                feed = self._travel_text(i, travels, plan.z, e_abs, fmt, vals)
            is_bridge = ordered[i][1].role == "bridge_infill"
            if is_bridge != in_bridge and p.bridge_fan_speed != normal_fan:
                fmt.append(fan_command(p.bridge_fan_speed if is_bridge else normal_fan))
            in_bridge = is_bridge
            name = FEATURE_LABELS.get(ordered[i][1].role, "")
            if name != label:
                fmt.append(";TYPE:" + name.replace("%", "%%") + "\n")
                label = name
            f = float(speeds[i]) * 60.0
            if f != feed:
                fmt.append("G1 F%.0f\n")
                vals.append(f)
                feed = f
            fmt.append("G1 X%.3f Y%.3f E%.5f\n" * m)
            vals += beads.flat[cursor:cursor + 3 * m]
            cursor += 3 * m
            if not p.relative_e:
                e_abs = beads.flat[cursor - 1]
        if in_bridge and p.bridge_fan_speed != normal_fan:
            fmt.append(fan_command(normal_fan))
        self.e_abs = e_abs
        return "".join(fmt) % tuple(vals)


@dataclass(frozen=True)
class _LayerPaths:
    """A layer's ordered paths as one point array: path k is ``points[begins[k]:ends[k]]``."""

    points: np.ndarray
    counts: np.ndarray
    begins: np.ndarray
    ends: np.ndarray

    @property
    def count(self) -> int:
        return len(self.counts)

    @classmethod
    def of(cls, ordered: list[tuple[np.ndarray, Path]]) -> _LayerPaths:
        counts = np.fromiter((len(o[0]) for o in ordered), dtype=np.int64, count=len(ordered))
        ends = np.cumsum(counts)
        return cls(np.concatenate([o[0] for o in ordered]), counts, ends - counts, ends)


@dataclass(frozen=True)
class _Travels:
    """Per path: where it starts, the straight travel's length, whether it moves, whether
    it retracts, and the router's detours (None without a router)."""

    starts: np.ndarray
    dist: np.ndarray
    moving: np.ndarray
    retract: np.ndarray
    routes: Any


@dataclass(frozen=True)
class _Beads:
    """The kept extrusion segments: their path, length (mm) and E (mm of filament), the
    segment count per path, and the flat ``x, y, e`` values for the text."""

    path: np.ndarray
    length: np.ndarray
    e: np.ndarray
    per_path: np.ndarray
    flat: list[float]


_HEAT_WAIT = re.compile(r"^\s*M109\b", re.MULTILINE | re.IGNORECASE)
_BED_WAIT = re.compile(r"^\s*M190\b", re.MULTILINE | re.IGNORECASE)


def start_block(profile: Profile, values: dict) -> str:
    """Start G-code: the template, with heat-and-wait commands added if it has none."""
    body = render_template(profile.start_gcode, values)
    pre = ""
    if not _BED_WAIT.search(body) and profile.first_layer_bed_temperature > 0:
        pre += f"M190 S{profile.first_layer_bed_temperature:.0f}\n"
    if not _HEAT_WAIT.search(body):
        pre += f"M109 S{profile.first_layer_temperature:.0f}\n"
    mode = "M83 ; relative E\n" if profile.relative_e else "M82 ; absolute E\n"
    return pre + body + "G21\nG90\n" + mode + "G92 E0\nM107\n"


def fan_command(percent: float) -> str:
    """M106 with a 0..255 PWM value (M107 for zero)."""
    pwm = int(round(255 * percent / 100.0))
    return "M107\n" if pwm <= 0 else f"M106 S{pwm}\n"


def m73(percent: float, remaining_s: float) -> str:
    """Progress report: percentage done and minutes remaining."""
    return f"M73 P{int(percent)} R{int(math.ceil(max(remaining_s, 0.0) / 60.0))}\n"
