"""Uploads: a multipart body streamed to a hidden file in the spool, then taken in
as a job through the spool's intake, so the job is in the journal before the answer.

The body never sits in memory: each chunk goes to ``<spool>/.upload-<uuid>.part``
(hidden and partial, so the spool watcher ignores it). When the last byte is on disk
the file is linked under its real name in the spool (``link`` never replaces an
existing file) and handed to :meth:`daemon.pipeline.Spool.intake` (with the print choice), which
moves it into a work folder inside the journal transaction that records the job.
Repair, slicing and the G-code policy run later, as for a spool drop.

In farm mode an upload that is to print goes where a spool drop goes: the farm's
outbox (:meth:`daemon.farm.node.FarmNode.take`), then a free printer of the farm that
fits it. One that is not to print stays a job of this node, waiting for the user's
"print"; a compute-only node refuses it (it has no printer to keep it for).
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
import shutil
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aiohttp import BodyPartReader, web
from aiohttp.http_exceptions import HttpProcessingError

from daemon.safety import ACCEPTED_SUFFIXES, UnsafeEntry, check_name, sanitise_name
from daemon.states import JobState

log = logging.getLogger("preflight.web")

CHUNK = 256 * 1024
MAX_FIELD_BYTES = 4096          # a form field (print, select, path, root) is short text
MAX_FIELDS = 32
MAX_REASON = 300
MAX_NAME_BYTES = 255            # one path component on Linux file systems
FREE_MARGIN = 16 * 1024 * 1024  # keep this much free on the spool's file system
TEMP_PREFIX = ".upload-"
BINARY_GCODE = ".bgcode"


class Refused(Exception):
    """An upload or request the server answers with ``status`` and a one-line reason."""

    def __init__(self, status: int, reason: str) -> None:
        # names are echoed in reasons: keep an answer to a hostile name one short line
        reason = " ".join(reason.split())
        if len(reason) > MAX_REASON:
            reason = reason[:MAX_REASON - 3] + "..."
        super().__init__(reason)
        self.status = status
        self.reason = reason


@dataclass
class Upload:
    """A received multipart upload: its text fields and the file on disk."""

    fields: dict[str, str] = field(default_factory=dict)
    name: str | None = None
    temp: Path | None = None
    size: int = 0

    def flag(self, key: str, default: bool = False) -> bool:
        value = self.fields.get(key)
        if value is None:
            return default
        return value.strip().lower() in ("true", "1", "yes", "on")

    def discard(self) -> None:
        if self.temp is not None:
            self.temp.unlink(missing_ok=True)
            self.temp = None


def check_upload_name(name: str) -> None:
    """Refuse (400) a file name with a path, traversal, NUL or control characters,
    or too long; refuse (415) a file type the spool does not take."""
    try:
        check_name(name)
    except UnsafeEntry as e:
        raise Refused(400, str(e)) from None
    if len(name.encode("utf-8")) > MAX_NAME_BYTES:
        raise Refused(400, f"refused: the file name is longer than {MAX_NAME_BYTES} bytes")
    suffix = Path(name).suffix.lower()
    if suffix == BINARY_GCODE:
        raise Refused(415, f"refused: {name} is binary G-code, which preflight cannot check; "
                           "turn off binary G-code in the slicer's printer settings "
                           "(PrusaSlicer: Printer Settings > General > Supports binary G-code)")
    if suffix not in ACCEPTED_SUFFIXES:
        raise Refused(415, f"refused: {name} is not a model or G-code file (accepted: "
                           f"{' '.join(sorted(ACCEPTED_SUFFIXES))})")


def check_folder(folder: str) -> None:
    """The ``path`` field names a folder under the upload root: relative, no ``..``,
    no NUL. The spool is flat, so an accepted folder is only checked, never created."""
    if not folder or folder in ("/", "."):
        return
    if folder.startswith(("/", "\\")) or (len(folder) > 1 and folder[1] == ":"):
        raise Refused(400, f"refused: the path {folder!r} is absolute")
    for part in folder.replace("\\", "/").strip("/").split("/"):
        if part in ("", "."):
            continue
        try:
            check_name(part)
        except UnsafeEntry as e:
            why = str(e).removeprefix("refused: ")
            raise Refused(400, f"refused: the path {folder!r}: {why}") from None
        if len(part.encode("utf-8")) > MAX_NAME_BYTES:
            raise Refused(400, "refused: a folder name in the path is too long")


@dataclass(frozen=True)
class SizeLimit:
    """The largest file an upload may carry, and the config key that sets it."""

    max_bytes: int
    key: str

    def refusal(self, what: str) -> Refused:
        return Refused(413, f"refused: {what} is over the limit of "
                            f"{self.max_bytes / 1048576:.4g} MB ({self.key})")


def size_limit(cfg: Any) -> SizeLimit:
    """``[web] max_upload_mb``, or ``[limits] max_file_mb`` when that is smaller (the
    spool's intake would refuse the file anyway: better before the body is sent)."""
    if cfg.limits.max_file_mb < cfg.web.max_upload_mb:
        return SizeLimit(int(cfg.limits.max_file_mb * 1048576), "[limits] max_file_mb")
    return SizeLimit(int(cfg.web.max_upload_mb * 1048576), "[web] max_upload_mb")


def check_declared_size(request: web.Request, limit: SizeLimit, spool: Path) -> None:
    """Before reading the body: 413 if ``Content-Length`` is over the limit, 507 if the
    spool's file system cannot hold it."""
    length = request.content_length
    if length is not None and length > limit.max_bytes + 64 * 1024:  # multipart framing
        raise limit.refusal(f"the upload ({length / 1048576:.1f} MB)")
    free = shutil.disk_usage(spool).free
    if free < (length or 0) + FREE_MARGIN:
        raise Refused(507, f"refused: the spool's disk has {free / 1048576:.0f} MB free, "
                           "not enough for this upload")


def printing_name(journal: Any) -> str | None:
    """The (sanitised) name of the file printing (or paused) now, if any."""
    for job in journal.jobs({JobState.PRINTING, JobState.PAUSED}):
        return job.name
    return None


async def receive(request: web.Request, spool: Path, limit: SizeLimit, busy_name: str | None
                  ) -> Upload:
    """Read the multipart body: text fields into ``fields``, the ``file`` part to a hidden
    temp file in the spool. Refuses as soon as what is known allows it."""
    check_declared_size(request, limit, spool)
    try:
        reader = await request.multipart()
    except (AssertionError, ValueError, KeyError) as e:
        raise Refused(400, f"expected a multipart/form-data body ({e})") from None
    up = Upload()
    try:
        while True:
            try:
                part = await reader.next()
            except (HttpProcessingError, ValueError) as e:
                why = " ".join(str(e).split())
                raise Refused(400, f"refused: the multipart body is malformed: {why}"[:300]
                              ) from None
            if part is None:
                break
            if not isinstance(part, BodyPartReader):
                raise Refused(400, "nested multipart bodies are not accepted")
            if part.name == "file" and part.filename is not None:
                if up.temp is not None:
                    raise Refused(400, "only one file per upload")
                up.name = part.filename
                check_upload_name(up.name)
                if busy_name is not None and sanitise_name(up.name) == busy_name:
                    raise Refused(409, f"refused: {up.name} is printing now; wait for it to "
                                       "finish or cancel it, or upload under another name")
                await _stream_to_disk(part, spool, limit, up)
            else:
                if len(up.fields) >= MAX_FIELDS:
                    raise Refused(400, f"more than {MAX_FIELDS} form fields")
                up.fields[part.name or ""] = await _read_field(part)
                if part.name == "path":  # refuse traversal before any file byte is stored
                    check_folder(up.fields["path"])
    except BaseException:
        up.discard()
        raise
    if up.temp is None or up.name is None:
        raise Refused(400, "the upload has no file part (a form field named \"file\" "
                           "with a filename)")
    return up


async def _next_chunk(part: BodyPartReader, size: int) -> bytes:
    """The next piece of a part; a body that ends inside the part is refused (400)."""
    try:
        return await part.read_chunk(size)
    except (HttpProcessingError, ValueError) as e:
        raise Refused(400, f"refused: the multipart body is malformed: {e}") from None


async def _read_field(part: BodyPartReader) -> str:
    data = bytearray()
    while True:
        chunk = await _next_chunk(part, 1024)
        if not chunk:
            break
        data += chunk
        if len(data) > MAX_FIELD_BYTES:
            raise Refused(400, f"the form field {part.name!r} is longer than "
                               f"{MAX_FIELD_BYTES} bytes")
    return data.decode("utf-8", "replace")


async def _stream_to_disk(part: BodyPartReader, spool: Path, limit: SizeLimit,
                          up: Upload) -> None:
    up.temp = spool / f"{TEMP_PREFIX}{uuid.uuid4().hex}.part"
    fd = os.open(up.temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        while True:
            chunk = await _next_chunk(part, CHUNK)
            if not chunk:
                break
            up.size += len(chunk)
            if up.size > limit.max_bytes:
                raise limit.refusal("the file")
            try:
                view = memoryview(chunk)
                while view:
                    view = view[os.write(fd, view):]
            except OSError as e:
                if e.errno in (errno.ENOSPC, errno.EDQUOT):
                    raise Refused(507, "refused: the spool's disk filled up during the "
                                       "upload") from None
                raise
        os.fsync(fd)
    finally:
        os.close(fd)


def take_in(spool_obj: Any, up: Upload, print_requested: bool, farm: Any = None
            ) -> dict[str, Any]:
    """Give the received file its name in the spool and take it in (blocking: run it in
    an executor): as a job of this node, or, in farm mode with ``print_requested``,
    for the farm's queue exactly as a file dropped into the spool is. Returns what the
    answer's ``preflight`` object says (``job``, or ``farm`` and ``farm_job``);
    refusals become :class:`Refused`."""
    assert up.temp is not None and up.name is not None
    final = spool_obj.root / up.name
    try:
        os.link(up.temp, final)
    except FileExistsError:
        raise Refused(409, f"refused: a file named {up.name} is already waiting in the "
                           "spool; upload under another name") from None
    finally:
        up.discard()
    if farm is not None and print_requested:
        taken = _take_for_farm(farm, final)
        if taken is not None:
            return taken
    job_id = spool_obj.intake(final, print_requested)
    if job_id is None:  # someone moved the file away between the link and the intake
        raise Refused(500, f"{up.name} vanished from the spool before it was taken in")
    job = spool_obj.journal.get(job_id)
    if job is not None and job.kind == "refused":
        raise Refused(400, job.reason or "refused")
    return {"job": job_id}


def _take_for_farm(farm: Any, path: Path) -> dict[str, Any] | None:
    """The farm's outbox takes the file (None: the local spool refuses it with the
    reason); it prints on the first free printer of the farm that fits it."""
    from daemon.farm.node import NotForFarm

    try:
        fid = farm.take(path)
    except NotForFarm:
        return None
    if fid is None and not path.exists():
        raise Refused(500, f"{path.name} vanished from the spool before it was taken in")
    where = f"farm {farm.cfg.farm.name!r}"
    return {"farm": farm.cfg.farm.name, "farm_job": fid, "message": (
        f"sent to the queue of {where}: it prints on the first free printer that fits it"
        if fid else f"the shared artefact store of {where} is unreachable: the file waits "
                    "in this node's spool and goes to the farm's queue when it is back")}


def check_compute_only(backend: Any, print_requested: bool) -> None:
    """A compute-only farm node has no printer to keep a file for: an upload that is not
    to print now is refused (one that is goes to the farm's queue)."""
    farm = getattr(backend, "farm", None)
    if farm is not None and not print_requested and farm.compute_only:
        raise Refused(409, f"refused: this is a compute-only node of farm "
                           f"{backend.cfg.farm.name!r}, with no printer to keep the file for; "
                           "upload it with \"print after upload\" to send it to the farm's "
                           "queue")


async def accept(request: web.Request, backend: Any, print_requested_field: str = "print", *,
                 check_fields: Callable[[dict[str, str]], None] | None = None
                 ) -> tuple[Upload, dict[str, Any], str]:
    """Receive an upload and take it in. Returns (upload, what the answer's ``preflight``
    object says, the job's name). ``check_fields`` may refuse the form's fields before
    the job is recorded."""
    cfg = backend.cfg
    up = await receive(request, cfg.spool.path, size_limit(cfg), printing_name(backend.journal))
    print_requested = up.flag(print_requested_field)
    try:
        check_folder(up.fields.get("path", ""))
        if check_fields is not None:
            check_fields(up.fields)
        check_compute_only(backend, print_requested)
    except Refused:
        up.discard()
        raise
    loop = asyncio.get_running_loop()
    taken = await loop.run_in_executor(None, take_in, backend.spool, up, print_requested,
                                       getattr(backend, "farm", None))
    job = backend.journal.get(taken["job"]) if "job" in taken else None
    log.info("%s: uploaded %s (%d bytes) by %s",
             f"job {taken['job']}" if job else f"farm job {taken.get('farm_job')}", up.name,
             up.size, request.remote)
    return up, taken, job.name if job else sanitise_name(up.name or "")


def remove_stale_temps(spool: Path) -> int:
    """Delete temp files a killed daemon left behind mid-upload; returns how many."""
    gone = 0
    for p in spool.glob(f"{TEMP_PREFIX}*.part"):
        p.unlink(missing_ok=True)
        gone += 1
    return gone
