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

import numpy as np

from slicer.geometry import bead_area, polygon_edges, segments_cross
from slicer.planner import LayerPlan, Path
from slicer.profile import Profile


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
        if first_layer or role == "skirt":
            return p.first_layer_speed
        return {
            "external_perimeter": p.external_perimeter_speed,
            "perimeter": p.perimeter_speed,
            "thin_wall": p.thin_wall_speed,
            "solid_infill": p.solid_infill_speed,
            "sparse_infill": p.infill_speed,
        }.get(role, p.perimeter_speed)

    def e_per_mm(self, width: float, height: float) -> float:
        return bead_area(width, height) / self.p.filament_area * self.p.extrusion_multiplier

    # ---- text pieces -------------------------------------------------------------------
    def _e_move(self, delta: float, feed: float) -> str:
        if self.p.relative_e:
            return f"G1 E{delta:.5f} F{feed:.0f}\n"
        self.e_abs += delta
        return f"G1 E{self.e_abs:.5f} F{feed:.0f}\n"

    def layer(self, plan: LayerPlan, ordered: list[tuple[np.ndarray, Path]],
              pos: np.ndarray) -> LayerCode:
        """G-code for one layer starting at XY ``pos`` (Z move already emitted)."""
        p = self.p
        first = plan.index == 0
        h = plan.height
        z = plan.z
        out: list[str] = []
        self.feed = -1.0  # the layer's Z move (emitted by the caller) changes the modal F
        if not p.relative_e:
            out.append("G92 E0\n")
            self.e_abs = 0.0
        # travels and whether each needs a retraction
        starts = np.array([o[0][0] for o in ordered]).reshape(-1, 2)
        prev = np.array([pos] + [o[0][-1] for o in ordered[:-1]]).reshape(-1, 2)[:len(starts)]
        dist = np.hypot(*(starts - prev).T) if len(starts) else np.zeros(0)
        retract = dist > p.retract_min_travel
        short = np.flatnonzero(~retract & (dist > 1e-6))
        if len(short) and plan.outline:
            a, b = polygon_edges(plan.outline)
            retract[short] = segments_cross(prev[short], starts[short], a, b)
        if p.retract_length <= 0:
            retract[:] = False

        travel_f = p.travel_speed * 60.0
        r_feed = p.retract_speed * 60.0
        seq_pts: list[np.ndarray] = [pos[None]]
        seq_v: list[np.ndarray] = []
        seq_a: list[np.ndarray] = []
        extra_t = 0.0
        filament = 0.0
        for i, (pts, path) in enumerate(ordered):
            if dist[i] > 1e-6:
                if retract[i]:
                    out.append(self._e_move(-p.retract_length, r_feed))
                    extra_t += p.retract_length / p.retract_speed
                    if p.retract_lift > 0:
                        out.append(f"G1 Z{z + p.retract_lift:.3f} F{travel_f:.0f}\n")
                        extra_t += 2 * p.retract_lift / p.travel_speed
                out.append(f"G0 X{pts[0, 0]:.3f} Y{pts[0, 1]:.3f} F{travel_f:.0f}\n")
                self.feed = travel_f
                seq_pts.append(pts[:1])
                seq_v.append(np.array([p.travel_speed]))
                seq_a.append(np.array([p.travel_acceleration]))
                if retract[i]:
                    if p.retract_lift > 0:
                        out.append(f"G1 Z{z:.3f} F{travel_f:.0f}\n")
                    out.append(self._e_move(p.retract_length, r_feed))
                    extra_t += p.retract_length / p.retract_speed
            seg = np.diff(pts, axis=0)
            seglen = np.hypot(seg[:, 0], seg[:, 1])
            keep = seglen > 1e-4
            if not keep.all():
                pts = np.vstack([pts[:1], pts[1:][keep]])
                seglen = seglen[keep]
            m = len(seglen)
            if m == 0:
                continue
            v = self.speed(path.role, first)
            f = v * 60.0
            if f != self.feed:
                out.append(f"G1 F{f:.0f}\n")
                self.feed = f
            e = seglen * self.e_per_mm(path.width, h)
            filament += float(e.sum())
            block = np.empty((m, 3))
            block[:, :2] = pts[1:]
            if p.relative_e:
                block[:, 2] = e
            else:
                block[:, 2] = self.e_abs + np.cumsum(e)
                self.e_abs = float(block[-1, 2])
            out.append(("G1 X%.3f Y%.3f E%.5f\n" * m) % tuple(block.ravel().tolist()))
            seq_pts.append(pts[1:])
            seq_v.append(np.full(m, v))
            seq_a.append(np.full(m, p.print_acceleration))
            pos = pts[-1]
        seconds = extra_t
        if seq_v:
            seconds += trapezoid_time(np.concatenate(seq_pts), np.concatenate(seq_v),
                                      np.concatenate(seq_a), p.max_jerk)
        return LayerCode("".join(out), seconds, filament, np.asarray(pos, dtype=np.float64))


_HEAT_WAIT = re.compile(r"^\s*M109\b", re.MULTILINE | re.IGNORECASE)
_BED_WAIT = re.compile(r"^\s*M190\b", re.MULTILINE | re.IGNORECASE)


def render_template(template: str, values: dict) -> str:
    """Fill ``{name}`` placeholders from ``values``; unknown names raise ValueError."""
    try:
        text = template.format_map(values)
    except (KeyError, IndexError, ValueError) as exc:
        raise ValueError(f"G-code template has an unknown or bad placeholder: {exc}") from None
    return text if text.endswith("\n") or not text else text + "\n"


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
