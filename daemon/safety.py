"""What the daemon refuses: unsafe spool entries, unsafe names, unsafe G-code.

- Spool entries that are symlinks, not regular files, or whose real path is not
  directly inside the spool are refused (:func:`check_spool_entry`).
- Names with path separators, traversal (``..``), NUL or control characters are
  refused (:func:`check_name`); accepted names are sanitised for the outputs
  (:func:`sanitise_name`).
- G-code with firmware-altering commands (EEPROM, firmware update, network and
  Wi-Fi configuration) is refused unless the config allows them, and moves
  outside the build volume are refused (:func:`check_gcode`).
"""

from __future__ import annotations

import math
import os
import re
import stat
import unicodedata
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from printer.gcode import clean_lines, lex

MESH_SUFFIXES = frozenset({".stl", ".obj", ".ply", ".3mf", ".step", ".stp"})
GCODE_SUFFIXES = frozenset({".gcode", ".gco", ".g"})
ACCEPTED_SUFFIXES = MESH_SUFFIXES | GCODE_SUFFIXES
PARTIAL_SUFFIXES = (".part", ".tmp", ".crdownload", ".partial", ".swp", "~")

#: Moves may leave the build volume by this much (mm): purge lines at Y-3 and the like.
BUILD_VOLUME_MARGIN = 5.0


class UnsafeEntry(ValueError):
    """A spool entry or a G-code file the daemon refuses; the message says why."""


def is_partial_name(name: str) -> bool:
    """True for names that are still being written or are hidden: ignored, not refused."""
    low = name.lower()
    if low.endswith(PARTIAL_SUFFIXES):
        return True
    # "..\\x.stl" is a traversal attempt (refused), not a hidden file (ignored)
    return name.startswith(".") and "\\" not in name and "/" not in name


def display_name(name: str) -> str:
    """The name as text that can be stored and shown (undecodable bytes become U+FFFD)."""
    try:
        raw = name.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:  # a lone surrogate that no file system byte produced
        raw = name.encode("utf-8", "surrogatepass")
    return raw.decode("utf-8", "replace")


def check_name(name: str) -> None:
    """Refuse names that try to leave the spool or that carry control characters."""
    if not name or name in (".", ".."):
        raise UnsafeEntry(f"refused: {name!r} is not a file name")
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise UnsafeEntry(f"refused: the name {display_name(name)!r} is not valid UTF-8; "
                          "rename the file") from None
    if "\x00" in name or any(unicodedata.category(c) == "Cc" for c in name):
        raise UnsafeEntry(f"refused: the name {name!r} contains control characters")
    parts = re.split(r"[/\\]", name)
    if len(parts) > 1:
        if any(p == ".." for p in parts):
            raise UnsafeEntry(f"refused: the name {name!r} tries to leave the spool folder (..)")
        raise UnsafeEntry(f"refused: the name {name!r} contains a path separator")


def sanitise_name(name: str, max_len: int = 120) -> str:
    """A safe file name for the outputs: letters, digits, ``. _ - + ( )`` and spaces.

    Path separators and other characters become ``_``; leading dots and spaces are
    stripped; the length is capped keeping the suffix. Never empty.
    """
    name = unicodedata.normalize("NFC", name)
    out = re.sub(r"[^\w.\- +()]", "_", name)
    out = re.sub(r"\.{2,}", ".", out).lstrip(". ").rstrip(" ")
    if not out:
        out = "unnamed"
    if len(out) > max_len:
        stem, dot, suf = out.rpartition(".")
        if dot and len(suf) <= 8:
            out = stem[: max_len - len(suf) - 1] + "." + suf
        else:
            out = out[:max_len]
    return out


def check_spool_entry(spool: Path, path: Path) -> os.stat_result:
    """Refuse symlinks, non-regular files and anything resolving outside ``spool``.

    Returns the entry's lstat on success.
    """
    check_name(path.name)
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode):
        target = os.readlink(path)
        raise UnsafeEntry(f"refused: {path.name} is a symbolic link (to {target}); "
                          "copy the file itself into the spool")
    if not stat.S_ISREG(st.st_mode):
        raise UnsafeEntry(f"refused: {path.name} is not a regular file")
    real_parent = os.path.realpath(path.parent)
    if real_parent != os.path.realpath(spool) or os.path.realpath(path) != os.path.join(
            real_parent, path.name):
        raise UnsafeEntry(f"refused: {path.name} resolves outside the spool folder")
    return st


# --- G-code -----------------------------------------------------------------------------

def strip_gcode(lines: Iterable[str]) -> list[str]:
    """The commands exactly as the printer host streams them (comments ``;`` and ``( )``,
    checksums and blank lines removed), so the policy checks what is really sent."""
    return clean_lines(lines)


@dataclass(frozen=True)
class GcodeCheck:
    lines: int
    extents_min: tuple[float, float, float] | None
    extents_max: tuple[float, float, float] | None

    def to_dict(self) -> dict:
        return {"lines": self.lines, "extents_min": self.extents_min,
                "extents_max": self.extents_max}


def _mm(value: float) -> str:
    """A coordinate for a message: 0.1 mm, or 3 significant digits when it is absurd."""
    return f"{value:.1f}" if abs(value) < 1e6 else f"{value:.3g}"


def check_gcode(lines: Iterable[str], *, forbidden: Iterable[str], allow_firmware: bool,
                build_volume: Sequence[float] | None) -> GcodeCheck:
    """Refuse forbidden commands and moves outside the build volume (mm, origin at 0,0,0).

    ``lines`` may be raw file lines (an open file: read one line at a time, so memory
    stays bounded whatever the file's size) or stripped commands; either way each is
    read by the one lexer, as the firmware reads it. Positions follow G90/G91, G92 and
    G28; G0/G1 are checked at their end points, G2/G3 arcs along their whole sweep.
    """
    policy = GcodePolicy(forbidden=forbidden, allow_firmware=allow_firmware)
    for line in lines:
        policy.feed(line)
    return policy.finish(build_volume)


class GcodePolicy:
    """The G-code check, one line at a time (see :func:`check_gcode`)."""

    def __init__(self, *, forbidden: Iterable[str], allow_firmware: bool) -> None:
        self.forbidden = frozenset() if allow_firmware else frozenset(
            lex(f).word or f.upper() for f in forbidden)
        self.commands = 0
        self.absolute = True
        self.pos = [0.0, 0.0, 0.0]     # logical position
        self.offset = [0.0, 0.0, 0.0]  # machine = logical + offset
        self.plane = (0, 1)            # G17 (X, Y); G18 (Z, X); G19 (Y, Z)
        self.lo = [float("inf")] * 3
        self.hi = [float("-inf")] * 3
        self.moved = False

    def feed(self, raw: str) -> None:
        """Check one line; raises UnsafeEntry for a refused command."""
        lexed = lex(raw)
        cmd = lexed.word
        if cmd is None:
            return
        self.commands += 1
        if cmd in self.forbidden:
            raise UnsafeEntry(
                f"refused: line {self.commands} `{lexed.command[:40]}` is a firmware-altering "
                f"command ({cmd}); set [safety] allow_firmware_commands = true to allow it")
        if cmd in ("G0", "G1", "G2", "G3"):
            self._move(cmd, lexed)
        elif cmd in ("G90", "G91"):
            self.absolute = cmd == "G90"
        elif cmd == "G92":
            for axis, val in lexed.params:
                k = "XYZ".find(axis)
                if k >= 0 and val is not None:
                    self.offset[k] = self.pos[k] + self.offset[k] - val
                    self.pos[k] = val
        elif cmd == "G28":
            self.pos = [0.0, 0.0, 0.0]
            self.offset = [0.0, 0.0, 0.0]
        elif cmd in _PLANES:
            self.plane = _PLANES[cmd]

    def _move(self, cmd: str, lexed) -> None:
        pos, offset, lo, hi = self.pos, self.offset, self.lo, self.hi
        arc = cmd in ("G2", "G3")
        start = [pos[k] + offset[k] for k in range(3)] if arc else None
        for axis, val in lexed.params:
            k = _AXES.get(axis)
            if k is not None and val is not None:
                pos[k] = val if self.absolute else pos[k] + val
                self.moved = True
        for k in (0, 1, 2):
            m = pos[k] + offset[k]
            if m < lo[k]:
                lo[k] = m
            if m > hi[k]:
                hi[k] = m
        if start is not None:
            end = [pos[k] + offset[k] for k in range(3)]
            box = arc_extents(start, end, lexed, clockwise=cmd == "G2", plane=self.plane)
            for point in box:
                self._include(point)

    def _include(self, point: Sequence[float]) -> None:
        for k in range(3):
            if point[k] < self.lo[k]:
                self.lo[k] = point[k]
            if point[k] > self.hi[k]:
                self.hi[k] = point[k]

    def finish(self, build_volume: Sequence[float] | None) -> GcodeCheck:
        """The extents of every move; raises UnsafeEntry when they leave the volume."""
        lo, hi = self.lo, self.hi
        if not self.moved:
            return GcodeCheck(self.commands, None, None)
        if build_volume is not None:
            bv = [float(b) for b in build_volume]
            for k, axis in enumerate("XYZ"):
                if lo[k] < -BUILD_VOLUME_MARGIN or hi[k] > bv[k] + BUILD_VOLUME_MARGIN:
                    raise UnsafeEntry(
                        f"refused: the G-code moves {axis} from {_mm(lo[k])} to {_mm(hi[k])} "
                        f"mm, outside the printer's build volume {bv[0]:g} x {bv[1]:g} x "
                        f"{bv[2]:g} mm")
        return GcodeCheck(self.commands, (lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))


#: Marlin's arc planes (CNC_WORKSPACE_PLANES): the (P, Q) axes an arc turns in.
_PLANES = {"G17": (0, 1), "G18": (2, 0), "G19": (1, 2)}
_OFFSET_LETTERS = "IJK"  # the centre offset along X, Y, Z
_AXES = {"X": 0, "Y": 1, "Z": 2}


def arc_extents(start: Sequence[float], end: Sequence[float], lexed, *, clockwise: bool,
                plane: tuple[int, int] = (0, 1)) -> tuple[list[float], list[float]]:
    """The bounding box of a G2/G3 arc's whole sweep, as Marlin's ``plan_arc`` draws it.

    The centre comes from the ``I J K`` offsets or from ``R`` (negative R: the longer
    arc; an R too short for the chord gives a half circle, as Marlin does); an arc that
    ends where it starts is a full circle, and ``P`` adds full turns. The box is exact:
    the end points plus the circle's extreme points in each direction the sweep passes.
    """
    p, q = plane
    centre = _arc_centre(start, end, lexed, clockwise, p, q)
    lo = [min(a, b) for a, b in zip(start, end, strict=True)]
    hi = [max(a, b) for a, b in zip(start, end, strict=True)]
    if centre is None:
        return lo, hi
    cp, cq = centre
    sp, sq_ = start[p] - cp, start[q] - cq
    ep, eq = end[p] - cp, end[q] - cq
    radius = math.hypot(sp, sq_)
    sweep = math.atan2(sp * eq - sq_ * ep, sp * ep + sq_ * eq)
    if sweep < 0:
        sweep += 2 * math.pi
    if clockwise:
        sweep -= 2 * math.pi
    same_point = start[p] == end[p] and start[q] == end[q]
    turns = lexed.value("P", 0.0) or 0.0
    full = (sweep == 0 and same_point) or turns >= 1 or abs(sweep) >= 2 * math.pi
    a0 = math.atan2(sq_, sp)
    for k, theta in enumerate((0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi)):
        if full or _within_sweep(a0, sweep, theta):
            axis, value = (p, cp + radius * (1 - k)) if k % 2 == 0 else (q, cq + radius * (2 - k))
            lo[axis] = min(lo[axis], value)
            hi[axis] = max(hi[axis], value)
    return lo, hi


def _within_sweep(a0: float, sweep: float, theta: float) -> bool:
    if sweep >= 0:
        return (theta - a0) % (2 * math.pi) <= sweep
    return (a0 - theta) % (2 * math.pi) <= -sweep


def _arc_centre(start: Sequence[float], end: Sequence[float], lexed, clockwise: bool,
                p: int, q: int) -> tuple[float, float] | None:
    r = lexed.value("R")
    if r is not None and r != 0:
        dp, dq = end[p] - start[p], end[q] - start[q]
        d = math.hypot(dp, dq)
        if d == 0:
            return None  # Marlin refuses an R arc to its own start point
        h2 = (r - 0.5 * d) * (r + 0.5 * d)
        h = math.sqrt(h2) if h2 >= 0 else 0.0
        e = -1.0 if clockwise ^ (r < 0) else 1.0
        mp, mq = (start[p] + end[p]) / 2, (start[q] + end[q]) / 2
        return mp + e * h * (-dq / d), mq + e * h * (dp / d)
    op = lexed.value(_OFFSET_LETTERS[p], 0.0) or 0.0
    oq = lexed.value(_OFFSET_LETTERS[q], 0.0) or 0.0
    if op == 0 and oq == 0:
        return None  # no centre: Marlin refuses the arc, nothing moves beyond its ends
    return start[p] + op, start[q] + oq


def safe_output_path(folder: Path, name: str, job_id: int) -> Path:
    """``folder/name`` or, when taken, ``folder/<stem>-<job_id><suffix>``."""
    p = folder / name
    if not p.exists() and not p.is_symlink():
        return p
    stem, suffix = os.path.splitext(name)
    return folder / f"{stem}-{job_id}{suffix}"


def path_is_inside(root: Path, p: Path) -> bool:
    try:
        Path(os.path.realpath(p)).relative_to(os.path.realpath(root))
        return True
    except ValueError:
        return False
