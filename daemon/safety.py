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

import os
import re
import stat
import unicodedata
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from printer.gcode import clean_lines, lex

MESH_SUFFIXES = frozenset({".stl", ".obj", ".ply", ".3mf"})
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


def check_gcode(lines: Sequence[str], *, forbidden: Iterable[str], allow_firmware: bool,
                build_volume: Sequence[float] | None) -> GcodeCheck:
    """Refuse forbidden commands and moves outside the build volume (mm, origin at 0,0,0).

    ``lines`` are stripped commands (see :func:`strip_gcode`). Positions follow
    G90/G91 and G92; only X/Y/Z of G0-G3 moves are checked.
    """
    forbidden_words = {lex(f).word or f.upper() for f in forbidden}
    absolute = True
    pos = [0.0, 0.0, 0.0]
    offset = [0.0, 0.0, 0.0]
    lo = [float("inf")] * 3
    hi = [float("-inf")] * 3
    moved = False
    for i, line in enumerate(lines, 1):
        lexed = lex(line)
        cmd = lexed.word
        if cmd is None:
            continue
        if not allow_firmware and cmd in forbidden_words:
            raise UnsafeEntry(f"refused: line {i} `{line.strip()[:40]}` is a firmware-altering "
                              f"command ({cmd}); set [safety] allow_firmware_commands = true "
                              "to allow it")
        if cmd == "G90":
            absolute = True
        elif cmd == "G91":
            absolute = False
        elif cmd == "G92":
            for axis, val in lexed.params:
                k = "XYZ".find(axis)
                if k >= 0 and val is not None:
                    offset[k] = pos[k] + offset[k] - val
                    pos[k] = val
        elif cmd in ("G0", "G1", "G2", "G3"):
            for axis, val in lexed.params:
                k = "XYZ".find(axis)
                if k < 0 or val is None:
                    continue
                pos[k] = val if absolute else pos[k] + val
                moved = True
            for k in range(3):
                m = pos[k] + offset[k]
                if m < lo[k]:
                    lo[k] = m
                if m > hi[k]:
                    hi[k] = m
        elif cmd == "G28":
            pos = [0.0, 0.0, 0.0]
            offset = [0.0, 0.0, 0.0]
    if not moved:
        return GcodeCheck(len(lines), None, None)
    if build_volume is not None:
        bv = [float(b) for b in build_volume]
        for k, axis in enumerate("XYZ"):
            if lo[k] < -BUILD_VOLUME_MARGIN or hi[k] > bv[k] + BUILD_VOLUME_MARGIN:
                raise UnsafeEntry(
                    f"refused: the G-code moves {axis} from {_mm(lo[k])} to {_mm(hi[k])} mm, "
                    f"outside the printer's build volume {bv[0]:g} x {bv[1]:g} x {bv[2]:g} mm")
    return GcodeCheck(len(lines), (lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))


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
