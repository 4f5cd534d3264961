"""The farm's content-addressed artefact store: a directory every node mounts
(``[farm] artefacts``: NFS, SMB, or a local disk when all nodes share a machine).

Large files never travel through the broker: a job carries only keys.

- ``inputs/<sha256><suffix>``: a dropped model or G-code file, by its content;
- ``prepared/<key>.gcode`` and ``prepared/<key>.json``: the G-code and the reports of a
  repair+slice for one (input, ε, profile) key; the ``.json`` is written last, so a
  key whose ``.json`` exists is complete (a task redone elsewhere finds it and reuses it).

Every file is written under a temporary name and renamed into place (atomic on one
file system), so a reader never sees half a file and two writers of one key are harmless.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

CHUNK = 1 << 20


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def prepared_key(input_key: str, epsilon: float, profile: dict[str, Any],
                 printer: dict[str, Any]) -> str:
    """The idempotency key of a repair+slice: the input's hash, ε, the profile's hash and
    what of the printer the slicer uses (build volume, flavour, filament)."""
    text = json.dumps({"input": input_key, "epsilon": round(float(epsilon), 6),
                       "profile": profile, "printer": printer}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


class ArtefactStore:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.inputs = self.root / "inputs"
        self.prepared = self.root / "prepared"
        for folder in (self.inputs, self.prepared):
            folder.mkdir(parents=True, exist_ok=True)

    def _place(self, source: Path, dest: Path) -> None:
        tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex}.part")
        shutil.copyfile(source, tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, dest)

    def put_input(self, path: Path) -> str:
        """Copy a dropped file in (once per content); its key ``<sha256><suffix>``."""
        key = file_sha256(path) + path.suffix.lower()
        dest = self.inputs / key
        if not dest.exists():
            self._place(path, dest)
        return key

    def input_path(self, key: str) -> Path:
        if "/" in key or key.startswith("."):
            raise ValueError(f"not an artefact key: {key!r}")
        return self.inputs / key

    def prepared_paths(self, key: str) -> tuple[Path, Path]:
        return self.prepared / f"{key}.gcode", self.prepared / f"{key}.json"

    def get_prepared(self, key: str) -> dict[str, Any] | None:
        """The recorded outcome of a finished repair+slice for ``key``, or None."""
        gcode, meta = self.prepared_paths(key)
        try:
            result = json.loads(meta.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None
        if result.get("ok") and not gcode.is_file():
            return None
        return result

    def put_prepared(self, key: str, gcode: Path | None, result: dict[str, Any]) -> None:
        out_gcode, meta = self.prepared_paths(key)
        if gcode is not None:
            self._place(gcode, out_gcode)
        tmp = meta.with_name(f".{meta.name}.{uuid.uuid4().hex}.part")
        tmp.write_text(json.dumps(result))
        os.replace(tmp, meta)
