"""Spool watching: which files in the spool folder are complete and may be taken.

A file is taken only once it is complete:

- on Linux (inotify) after close-after-write (``IN_CLOSE_WRITE``) or after it was
  renamed within the spool (``x.part`` -> ``x.stl``), and then ``close_grace_seconds``
  without a new write;
- a file renamed in from outside the spool (inotify reports a creation without
  writes) once its size and mtime have been stable for ``settle_seconds``;
- a file found by a scan (at start-up, or on a network share watched by polling)
  once its size and mtime have been stable for ``settle_seconds``;
- a file that inotify saw being written but never saw closed (a lost event), or
  an empty one, only after it has been stable for ``max(60 s, 12 x settle_seconds)``.

Hidden files and partial names (``.part``, ``.tmp``, ``~``...) are ignored; only
entries directly in the spool are considered (``done/``, ``failed/`` and the
work area are sub-folders).
"""

from __future__ import annotations

import logging
import os
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from watchdog.events import (
    FileClosedEvent,
    FileSystemEvent,
    FileSystemEventHandler,
    FileSystemMovedEvent,
)

from daemon.safety import is_partial_name

log = logging.getLogger("preflight.watcher")


@dataclass
class _Candidate:
    first_seen: float
    last_change: float
    signature: tuple[int, int] | None = None
    closed_at: float | None = None      # close-after-write or rename-in seen
    writing: bool = False               # inotify saw writes without a close since


class SpoolWatcher:
    """Tracks candidate files in ``spool``; :meth:`due` returns the complete ones."""

    def __init__(self, spool: Path, *, settle_seconds: float = 5.0,
                 close_grace_seconds: float = 0.3, poll: bool = False) -> None:
        self.spool = Path(spool)
        self.settle = float(settle_seconds)
        self.grace = float(close_grace_seconds)
        self.poll = poll
        self._lock = threading.Lock()
        self._candidates: dict[str, _Candidate] = {}
        self._handed: dict[str, int] = {}   # name -> inode handed over, still in the spool
        self._observer = None
        self._last_scan = 0.0
        self.wakeup = threading.Event()   # set when an event arrives

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        """Scan what is already waiting, then start watching."""
        if self.poll:
            from watchdog.observers.polling import PollingObserver as Obs
        else:
            from watchdog.observers import Observer as Obs
        self._observer = Obs()
        self._observer.schedule(_Handler(self), str(self.spool), recursive=False)
        self._observer.daemon = True
        self._observer.start()
        self.scan()

    def stop(self) -> None:
        if self._observer is not None:
            self._observer.stop()
            self._observer.join(timeout=5)
            self._observer = None

    # -- events ---------------------------------------------------------------------------
    def _relevant(self, path: str) -> str | None:
        entry = Path(path)
        if entry.parent != self.spool:
            return None
        if is_partial_name(entry.name):
            return None
        return entry.name

    def on_event(self, event: FileSystemEvent) -> None:
        if event.is_directory:
            return
        now = time.monotonic()
        with self._lock:
            if isinstance(event, FileSystemMovedEvent):
                gone = self._relevant(event.src_path)
                if gone:
                    self._candidates.pop(gone, None)
                name = self._relevant(event.dest_path)
                if name:
                    self._handed.pop(name, None)
                    candidate = self._candidates.setdefault(name, _Candidate(now, now))
                    candidate.closed_at, candidate.writing, candidate.last_change = now, False, now
            else:
                name = self._relevant(event.src_path)
                if not name:
                    return
                if event.event_type == "deleted":
                    self._candidates.pop(name, None)
                    self._handed.pop(name, None)
                    return
                if event.event_type == "created":
                    self._handed.pop(name, None)
                elif name in self._handed:
                    return
                candidate = self._candidates.setdefault(name, _Candidate(now, now))
                if isinstance(event, FileClosedEvent):
                    candidate.closed_at, candidate.writing = now, False
                elif self.poll:
                    candidate.last_change = now
                elif event.event_type == "created":
                    # a new file, or one renamed in from outside the spool (inotify then
                    # reports a creation): writes that follow mark it as being written
                    candidate.closed_at, candidate.last_change = None, now
                elif candidate.closed_at is None:
                    candidate.writing, candidate.last_change = True, now
                else:  # written/touched again after a close (scp -p sets times): wait again
                    candidate.last_change = now
        self.wakeup.set()

    def scan(self) -> None:
        """Add every relevant entry of the spool that is not tracked yet."""
        now = time.monotonic()
        self._last_scan = now
        try:
            names = os.listdir(self.spool)
        except FileNotFoundError:
            return
        with self._lock:
            present = set(names)
            for name in list(self._handed):
                if name not in present:
                    del self._handed[name]
            for name in names:
                if is_partial_name(name) or name in self._candidates:
                    continue
                try:
                    entry = os.lstat(self.spool / name)
                except FileNotFoundError:
                    continue
                if self._handed.get(name) == entry.st_ino:
                    continue
                if stat.S_ISDIR(entry.st_mode):
                    continue
                self._candidates[name] = _Candidate(now, now)

    def forget(self, name: str) -> None:
        with self._lock:
            self._candidates.pop(name, None)

    def pending(self) -> int:
        with self._lock:
            return len(self._candidates)

    # -- completeness ---------------------------------------------------------------------
    def due(self) -> list[Path]:
        """The candidates that are complete now (removed from tracking), oldest first."""
        now = time.monotonic()
        if now - self._last_scan >= max(1.0, self.settle):
            self.scan()
        ready: list[tuple[float, str]] = []
        with self._lock:
            for name, candidate in list(self._candidates.items()):
                try:
                    entry = os.lstat(self.spool / name)
                except FileNotFoundError:
                    del self._candidates[name]
                    continue
                if not stat.S_ISREG(entry.st_mode):
                    if stat.S_ISDIR(entry.st_mode):
                        del self._candidates[name]
                    else:  # symlinks and other oddities: hand over, intake refuses them
                        ready.append((candidate.first_seen, name))
                        del self._candidates[name]
                        self._handed[name] = entry.st_ino
                    continue
                signature = (entry.st_size, entry.st_mtime_ns)
                if signature != candidate.signature:
                    if candidate.signature is not None:
                        candidate.last_change = now
                    candidate.signature = signature
                quiet = now - candidate.last_change
                if candidate.closed_at is not None:
                    ok = now - max(candidate.closed_at, candidate.last_change) >= self.grace
                elif candidate.writing:
                    ok = quiet >= max(60.0, 12 * self.settle)
                elif entry.st_size == 0:  # created, nothing written yet: wait for a close
                    ok = quiet >= max(60.0, 12 * self.settle)
                else:
                    ok = quiet >= self.settle and now - candidate.first_seen >= self.settle
                if ok:
                    ready.append((candidate.first_seen, name))
                    del self._candidates[name]
                    self._handed[name] = entry.st_ino
        return [self.spool / name for _, name in sorted(ready)]


class _Handler(FileSystemEventHandler):
    def __init__(self, watcher: SpoolWatcher) -> None:
        self.watcher = watcher

    def on_any_event(self, event: FileSystemEvent) -> None:
        try:
            self.watcher.on_event(event)
        except Exception:  # never let the observer thread die
            log.exception("spool event %r", event)
