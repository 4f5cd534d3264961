"""The virtual printer's physics: heaters that take time to heat, moves that take time.

Simulated time runs ``speedup`` times faster than real time.
"""

from __future__ import annotations

import math
from collections import deque

AMBIENT = 25.0
PLANNER_BLOCKS = 16


#: A heater at full power approaches ``ceiling`` °C with time constant ``heat_tau`` s;
#: switched off it cools towards ambient with ``cool_tau`` s. With these a 40 W hotend
#: reaches 210 °C in about 45 s and a 24 V bed 60 °C in about 35 s, as real ones do.
HEATER_MODEL = {
    "T": {"ceiling": 320.0, "heat_tau": 45.0, "cool_tau": 120.0},
    "B": {"ceiling": 130.0, "heat_tau": 85.0, "cool_tau": 400.0},
}


class Heaters:
    """Hotend ``T`` and bed ``B``: current and target °C. A first-order model: below
    its target a heater runs at full power (exponential approach to its ceiling) and
    the controller holds it at the target; above, it cools towards ambient."""

    def __init__(self, now: float) -> None:
        self.current = {"T": AMBIENT, "B": AMBIENT}
        self.target = {"T": 0.0, "B": 0.0}
        self.last_tick = now

    def tick(self, now: float, speedup: float) -> None:
        seconds = (now - self.last_tick) * speedup
        self.last_tick = now
        if seconds <= 0:
            return
        for heater, model in HEATER_MODEL.items():
            goal = max(self.target[heater], AMBIENT)
            current = self.current[heater]
            if goal > current:
                ceiling = model["ceiling"]
                step = (ceiling - current) * -math.expm1(-seconds / model["heat_tau"])
                self.current[heater] = min(goal, current + step)
            else:
                step = (current - AMBIENT) * -math.expm1(-seconds / model["cool_tau"])
                self.current[heater] = max(goal, current - step - 0.01 * seconds)

    def settled(self, heater: str, cooling_too: bool = False) -> bool:
        """True when a wait for ``heater`` is over: it is within 1 °C of its target (M109 R,
        M190 R), or at least at its target less 1 °C when only heating is waited for
        (M109 S, M190 S); at once for a target at or below ambient (a switched-off one)."""
        target = self.target[heater]
        if target <= AMBIENT:
            return True
        current = self.current[heater]
        if cooling_too:
            return abs(current - target) <= 1.0
        return current >= target - 1.0

    def switch_off(self) -> None:
        self.target = {"T": 0.0, "B": 0.0}

    def report(self, firmware: str) -> str:
        """The temperature report as ``firmware`` prints it (M105, auto-report, M109 wait)."""
        t, b = self.current["T"], self.current["B"]
        tt, bt = self.target["T"], self.target["B"]
        if firmware == "klipper":
            return f"B:{b:.1f} /{bt:.1f} T0:{t:.1f} /{tt:.1f}"
        if firmware == "prusa":
            return (
                f"T:{t:.1f} /{tt:.1f} B:{b:.1f} /{bt:.1f} T0:{t:.1f} /{tt:.1f}"
                " @:0 B@:0 P:0.0 A:26.4"
            )
        if firmware == "rrf":
            return f"T:{t:.1f} /{tt:.1f} B:{b:.1f} /{bt:.1f}"
        return f"T:{t:.2f} /{tt:.2f} B:{b:.2f} /{bt:.2f} @:0 B@:0"


class Motion:
    """Position (mm), feed rate, absolute/relative modes and a planner of
    ``PLANNER_BLOCKS`` moves, each finishing at a simulated-clock time."""

    def __init__(self) -> None:
        self.position = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        self.feed = 1500.0  # mm/min
        self.relative = False
        self.relative_e = False
        self.planner: deque[float] = deque()

    def move_seconds(self, params: dict[str, float], speedup: float) -> float:
        """Update the position for a G0-G3 move; return its real duration in seconds."""
        if "F" in params and params["F"] > 0:
            self.feed = params["F"]
        dist2 = 0.0
        for axis in "XYZE":
            if axis not in params:
                continue
            relative = self.relative_e if axis == "E" else self.relative
            target = self.position[axis] + params[axis] if relative else params[axis]
            delta = target - self.position[axis]
            self.position[axis] = target
            if axis != "E" or dist2 == 0.0:
                dist2 += delta * delta
        return math.sqrt(dist2) / (self.feed / 60.0) / speedup

    def retire(self, now: float) -> None:
        """Forget the planned moves that have finished by ``now``."""
        while self.planner and self.planner[0] <= now:
            self.planner.popleft()

    def plan(self, seconds: float, now: float) -> bool:
        """Queue a move of ``seconds``; False while the planner is full."""
        if len(self.planner) >= PLANNER_BLOCKS:
            return False
        start = self.planner[-1] if self.planner else now
        self.planner.append(max(start, now) + seconds)
        return True

    def free_blocks(self) -> int:
        return PLANNER_BLOCKS - len(self.planner)

    def report(self) -> str:
        """The M114 reply."""
        pos = self.position
        return (f"X:{pos['X']:.2f} Y:{pos['Y']:.2f} Z:{pos['Z']:.2f} E:{pos['E']:.2f}"
                " Count X:0 Y:0 Z:0")
