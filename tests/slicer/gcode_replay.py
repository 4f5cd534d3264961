"""A small, independent G-code interpreter for checking slicer output.

It knows nothing of the slicer: it replays G0/G1 with the G90/G91 (all axes), M82/M83 (E
only) and G92 state a Marlin firmware keeps, plus temperature commands, and records every
move. Units mm; E is filament length in mm. PrusaSlicer-style ``;TYPE:`` comments label the
moves after them (``feature``); moves before any label have the label "".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from printer.gcode import lex

SUPPORT = ("Support material", "Support material interface")
NOT_PART = (*SUPPORT, "Skirt/Brim")


@dataclass
class Replay:
    """Moves as arrays: start/end (n, 3) mm, de (n,) filament mm, feed (n,) mm/min."""

    start: np.ndarray
    end: np.ndarray
    de: np.ndarray
    feed: np.ndarray
    line_no: np.ndarray
    #: (line number, command, S value) of temperature commands
    temps: list[tuple[int, str, float]] = field(default_factory=list)
    #: (line number, P value) of M73
    progress: list[tuple[int, float]] = field(default_factory=list)
    fan: list[tuple[int, float]] = field(default_factory=list)
    #: per move, an index into ``labels`` (the ``;TYPE:`` in force)
    feature: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    labels: list[str] = field(default_factory=lambda: [""])

    def labelled(self, *names: str) -> np.ndarray:
        """Mask of moves under any of the ``;TYPE:`` labels ``names``."""
        ids = [i for i, name in enumerate(self.labels) if name in names]
        return np.isin(self.feature, ids)

    @property
    def part(self) -> np.ndarray:
        """Extruding moves that build the part (not support, skirt or brim)."""
        return self.extruding & ~self.labelled(*NOT_PART)

    @property
    def extruding(self) -> np.ndarray:
        """Mask of moves that lay down plastic while moving in XY."""
        xy = np.hypot(*(self.end[:, :2] - self.start[:, :2]).T)
        return (self.de > 1e-9) & (xy > 1e-9)

    def travel_chains(self) -> list[tuple[float, np.ndarray]]:
        """(z, indices) of each run of consecutive non-extruding XY moves between two
        extrusions at the same Z: the travel from where one extrusion ended to where the next
        began, leg by leg (retractions and hops inside the run are skipped)."""
        ext = self.extruding
        xy = np.hypot(*(self.end[:, :2] - self.start[:, :2]).T)
        out: list[tuple[float, np.ndarray]] = []
        e_idx = np.flatnonzero(ext)
        for a, b in zip(e_idx[:-1], e_idx[1:], strict=True):
            if b == a + 1 or abs(self.end[a, 2] - self.end[b, 2]) > 1e-9:
                continue
            legs = np.arange(a + 1, b)
            legs = legs[(xy[legs] > 1e-9) & (self.de[legs] <= 1e-9)]
            if len(legs):
                out.append((float(round(self.end[a, 2], 3)), legs))
        return out

    def layers(self, mask: np.ndarray | None = None) -> dict[float, np.ndarray]:
        """Indices of extruding moves (or of the moves in ``mask``) grouped by Z (rounded to
        1 µm)."""
        ext = np.flatnonzero(self.extruding if mask is None else mask)
        z = np.round(self.end[ext, 2], 3)
        out: dict[float, np.ndarray] = {}
        for zz in np.unique(z):
            out[float(zz)] = ext[z == zz]
        return out


def replay(text: str) -> Replay:
    """Interpret G-code text (lines read by the product's lexer, as Marlin reads them)."""
    pos = np.zeros(4)  # x y z e (logical, after G92 offsets: we track logical coordinates)
    abs_xyz = True
    abs_e = True
    feed = 0.0
    starts, ends, des, feeds, lines = [], [], [], [], []
    temps: list[tuple[int, str, float]] = []
    progress: list[tuple[int, float]] = []
    fan: list[tuple[int, float]] = []
    # physical position = logical + offset (G92 changes offset only)
    offset = np.zeros(4)
    labels = [""]
    label = 0
    kinds: list[int] = []
    for no, raw in enumerate(text.splitlines(), 1):
        if raw.startswith(";TYPE:"):
            name = raw[6:].strip()
            if name not in labels:
                labels.append(name)
            label = labels.index(name)
            continue
        lexed = lex(raw)
        cmd = lexed.word
        if cmd is None:
            continue
        words = {letter: value for letter, value in lexed.params if value is not None}
        if cmd in ("G0", "G1"):
            new = pos.copy()
            for i, axis in enumerate("XYZ"):
                if axis in words:
                    new[i] = words[axis] if abs_xyz else pos[i] + words[axis]
            if "E" in words:
                new[3] = words["E"] if abs_e else pos[3] + words["E"]
            if "F" in words:
                feed = words["F"]
            p0 = pos[:3] + offset[:3]
            p1 = new[:3] + offset[:3]
            starts.append(p0)
            ends.append(p1)
            des.append(new[3] - pos[3])
            feeds.append(feed)
            lines.append(no)
            kinds.append(label)
            pos = new
        elif cmd == "G90":
            abs_xyz = abs_e = True
        elif cmd == "G91":
            abs_xyz = abs_e = False
        elif cmd == "M82":
            abs_e = True
        elif cmd == "M83":
            abs_e = False
        elif cmd == "G92":
            for i, axis in enumerate("XYZE"):
                if axis in words:
                    phys = pos[i] + offset[i]
                    pos[i] = words[axis]
                    offset[i] = phys - pos[i]
        elif cmd == "G28":
            pos[:3] = 0.0
            offset[:3] = 0.0
        elif cmd in ("M104", "M109", "M140", "M190"):
            temps.append((no, cmd, words.get("S", float("nan"))))
        elif cmd == "M73":
            progress.append((no, words.get("P", float("nan"))))
        elif cmd == "M106":
            fan.append((no, words.get("S", 255.0)))
        elif cmd == "M107":
            fan.append((no, 0.0))
    arr = np.array
    return Replay(
        start=arr(starts, dtype=float).reshape(-1, 3), end=arr(ends, dtype=float).reshape(-1, 3),
        de=arr(des, dtype=float), feed=arr(feeds, dtype=float), line_no=arr(lines, dtype=int),
        temps=temps, progress=progress, fan=fan, feature=arr(kinds, dtype=int), labels=labels,
    )
