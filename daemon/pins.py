"""Pinning a model to a nozzle class: a sidecar file, or a spool subfolder.

* A sidecar ``<name>.toml`` next to the model (``part.toml`` or ``part.stl.toml`` for
  ``part.stl``) holding ``nozzle = 0.6``. It travels with the model (into its work
  folder, then ``done/``/``failed/`` as ``<stem>.toml``); it is never a job itself. Drop
  it before the model, or with it: a model taken before its sidecar arrived is not
  pinned. A sidecar that is not valid (not TOML, an unknown key, a nozzle that is not a
  size in mm) fails the model's job with the reason.
* The spool subfolder ``nozzle-0.6/`` (created by the user; the daemon creates none):
  every model dropped into it is pinned to a 0.6 mm nozzle. It is watched like the
  spool itself (:class:`PinnedFolders`).
"""

from __future__ import annotations

import os
import re
import stat
import tomllib
from pathlib import Path

from daemon.watcher import SpoolWatcher

SIDECAR_SUFFIX = ".toml"
NOZZLE_FOLDER = re.compile(r"^nozzle-(\d+(?:\.\d+)?)$")
NOZZLE_RANGE = (0.05, 3.0)


class BadSidecar(ValueError):
    """The sidecar cannot be used; the message says why, naming the file."""


def is_sidecar(path: Path) -> bool:
    return path.name.lower().endswith(SIDECAR_SUFFIX)


def folder_nozzle(root: Path, folder: Path) -> float | None:
    """The nozzle a spool subfolder pins to (``nozzle-0.6`` -> 0.6), or None if
    ``folder`` is not such a folder directly inside ``root`` (a symlink is not)."""
    match = NOZZLE_FOLDER.match(folder.name)
    if match is None or os.path.realpath(folder.parent) != os.path.realpath(root):
        return None
    try:
        if not stat.S_ISDIR(os.lstat(folder).st_mode):
            return None
    except OSError:
        return None
    nozzle = float(match.group(1))
    return nozzle if NOZZLE_RANGE[0] < nozzle <= NOZZLE_RANGE[1] else None


def find_sidecar(model: Path) -> Path | None:
    """The sidecar of ``model`` in its folder, if one is there (a regular file)."""
    for candidate in (model.with_name(model.name + SIDECAR_SUFFIX),
                      model.with_name(Path(model.name).stem + SIDECAR_SUFFIX)):
        try:
            if stat.S_ISREG(os.lstat(candidate).st_mode):
                return candidate
        except OSError:
            continue
    return None


def read_sidecar(path: Path) -> float:
    """The nozzle (mm) a sidecar pins to; BadSidecar (one line, naming it) if invalid."""
    try:
        if os.path.getsize(path) > 64 * 1024:
            raise BadSidecar(f"sidecar {path.name} is over 64 kB; it holds one line, "
                             "nozzle = 0.6")
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise BadSidecar(f"sidecar {path.name} is not readable TOML ({e})") from None
    unknown = sorted(set(data) - {"nozzle"})
    if unknown:
        raise BadSidecar(f"sidecar {path.name}: unknown key {unknown[0]!r} (known: nozzle)")
    nozzle = data.get("nozzle")
    low, high = NOZZLE_RANGE
    if (isinstance(nozzle, bool) or not isinstance(nozzle, (int, float))
            or not low < nozzle <= high):
        raise BadSidecar(f"sidecar {path.name}: nozzle must be a nozzle diameter in mm "
                         f"(> {low} and <= {high}), like nozzle = 0.6; got {nozzle!r}")
    return float(nozzle)


class PinnedFolders:
    """Watches the ``nozzle-*`` subfolders of the spool (those present, and new ones
    looked for at each :meth:`refresh`) with one :class:`SpoolWatcher` each."""

    def __init__(self, root: Path, **watcher_options) -> None:
        self.root = root
        self.options = watcher_options
        self.watchers: dict[str, SpoolWatcher] = {}

    def refresh(self) -> None:
        try:
            names = os.listdir(self.root)
        except OSError:
            return
        for name in names:
            folder = self.root / name
            if name in self.watchers or folder_nozzle(self.root, folder) is None:
                continue
            watcher = SpoolWatcher(folder, **self.options)
            watcher.start()
            self.watchers[name] = watcher

    def due(self) -> list[Path]:
        return [path for watcher in self.watchers.values() for path in watcher.due()]

    def pending(self) -> int:
        return sum(watcher.pending() for watcher in self.watchers.values())

    def stop(self) -> None:
        for watcher in self.watchers.values():
            watcher.stop()
