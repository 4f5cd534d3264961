"""The job journal: one SQLite database (WAL) shared by the daemon and the CLI.

Tables:
- ``jobs``: one row per dropped file, its state, paths, ε and its source, the
  printer info, the reports (JSON text) and the reason of a failure.
- ``transitions``: every state change with its time (seconds since the epoch).
- ``requests``: CLI -> daemon requests (print / requeue / cancel), polled by the daemon.
- ``temperatures``: heater readings sampled during a job's print.
- ``meta``: key/value; the daemon's status and heartbeat, the last printer info.

The state machine of :mod:`daemon.states` is enforced in :meth:`Journal.transition`.
All methods are thread-safe (one connection, one lock).

Durability (the journal may live on a Raspberry Pi's SD card): every write is durable
(``fsync`` at commit, WAL with ``synchronous = FULL``) except the *soft* ones, written
with ``durable=False``: progress, temperature samples and the status heartbeat. Those
are committed at once (readers see them) without an ``fsync`` of their own
(``synchronous = NORMAL``); at most one soft commit every ``soft_sync_seconds`` (10 s)
is made durable, and any durable commit (a state change) makes every earlier soft one
durable too, since the WAL is written in order. A power cut loses at most the last
10 s of progress, never a state change.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.states import JobState, check_transition

SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,            -- sanitised file name
    source_name TEXT NOT NULL,     -- the name as dropped
    kind TEXT NOT NULL,            -- 'mesh' | 'gcode'
    state TEXT NOT NULL,
    created REAL NOT NULL,
    updated REAL NOT NULL,
    work_dir TEXT,
    input_path TEXT,
    repaired_path TEXT,
    gcode_path TEXT,
    epsilon REAL,
    epsilon_source TEXT,
    printer_info TEXT,
    repair_report TEXT,
    slice_summary TEXT,
    print_result TEXT,
    reason TEXT,
    attempts INTEGER NOT NULL DEFAULT 0,
    print_requested INTEGER NOT NULL DEFAULT 0,
    progress REAL,
    outputs TEXT,
    nozzle REAL,                   -- the nozzle class (mm) it is routed to, or pinned to
    pinned INTEGER NOT NULL DEFAULT 0,  -- 1: nozzle was pinned (sidecar, nozzle-X/ folder)
    printer TEXT                   -- the printer that claimed it for printing
);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state);
CREATE TABLE IF NOT EXISTS transitions (
    job_id INTEGER NOT NULL,
    from_state TEXT,
    to_state TEXT NOT NULL,
    at REAL NOT NULL,
    note TEXT
);
CREATE INDEX IF NOT EXISTS transitions_job ON transitions(job_id);
CREATE TABLE IF NOT EXISTS requests (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id INTEGER NOT NULL,
    action TEXT NOT NULL,
    created REAL NOT NULL,
    handled REAL,
    ok INTEGER,
    message TEXT
);
CREATE TABLE IF NOT EXISTS temperatures (
    job_id INTEGER NOT NULL,
    at REAL NOT NULL,
    readings TEXT NOT NULL         -- JSON {"T": [current, target], "B": [...]}, degC
);
CREATE INDEX IF NOT EXISTS temperatures_job ON temperatures(job_id);
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""

#: Seconds between fsyncs for soft writes (progress, temperatures, the heartbeat).
SOFT_SYNC_SECONDS = 10.0

#: Columns added since the first journal format: (name, type), added at open if missing.
MIGRATIONS = (("nozzle", "REAL"), ("pinned", "INTEGER NOT NULL DEFAULT 0"),
              ("printer", "TEXT"))

JSON_FIELDS = ("printer_info", "repair_report", "slice_summary", "print_result", "outputs")


@dataclass(frozen=True)
class Job:
    """One row of ``jobs``; JSON fields are decoded."""

    id: int
    name: str
    source_name: str
    kind: str
    state: JobState
    created: float
    updated: float
    work_dir: str | None
    input_path: str | None
    repaired_path: str | None
    gcode_path: str | None
    epsilon: float | None
    epsilon_source: str | None
    printer_info: dict | None
    repair_report: dict | None
    slice_summary: dict | None
    print_result: dict | None
    reason: str | None
    attempts: int
    print_requested: bool
    progress: float | None
    outputs: dict | None
    nozzle: float | None = None
    pinned: bool = False
    printer: str | None = None

    def to_dict(self) -> dict[str, Any]:
        fields = dict(self.__dict__)
        fields["state"] = str(self.state)
        return fields


class Journal:
    """Thread-safe access to the journal database at ``path``."""

    def __init__(self, path: str | Path, *, readonly: bool = False) -> None:
        self.path = Path(path)
        if not readonly:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        #: Soft writes are made durable at most this often (seconds).
        self.soft_sync_seconds = SOFT_SYNC_SECONDS
        self._last_sync = 0.0
        self._synchronous = "FULL"
        self._db = sqlite3.connect(str(self.path), timeout=10.0, check_same_thread=False,
                                   isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA busy_timeout = 10000")
        if not readonly:
            self._db.execute("PRAGMA journal_mode = WAL")
            self._db.execute("PRAGMA synchronous = FULL")
            self._db.executescript(SCHEMA)
            self._migrate()

    def _migrate(self) -> None:
        """Add the columns a journal written by an older preflight lacks."""
        have = {r[1] for r in self._db.execute("PRAGMA table_info(jobs)")}
        for column, kind in MIGRATIONS:
            if column not in have:
                self._db.execute(f"ALTER TABLE jobs ADD COLUMN {column} {kind}")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # -- low level ------------------------------------------------------------------------
    def _tx(self, durable: bool = True):
        return _Tx(self, durable)

    def _begin(self, durable: bool) -> None:
        """BEGIN a transaction whose COMMIT fsyncs the WAL if it is durable, or if it is a
        soft one and no commit has been synced for ``soft_sync_seconds``."""
        now = time.monotonic()
        sync = durable or now - self._last_sync >= self.soft_sync_seconds
        level = "FULL" if sync else "NORMAL"
        if level != self._synchronous:
            self._db.execute(f"PRAGMA synchronous = {level}")
            self._synchronous = level
        if sync:
            self._last_sync = now
        self._db.execute("BEGIN IMMEDIATE")

    @staticmethod
    def _row_to_job(row: sqlite3.Row) -> Job:
        fields = dict(row)
        for name in JSON_FIELDS:
            fields[name] = json.loads(fields[name]) if fields[name] else None
        fields["state"] = JobState(fields["state"])
        fields["print_requested"] = bool(fields["print_requested"])
        fields["pinned"] = bool(fields["pinned"])
        return Job(**fields)

    # -- jobs -----------------------------------------------------------------------------
    def add_job(self, *, name: str, source_name: str, kind: str, work_dir: str,
                input_path: str, state: JobState = JobState.QUEUED, reason: str | None = None,
                print_requested: bool = False, note: str = "file taken from the spool",
                nozzle: float | None = None,
                while_recording: Callable[[], None] | None = None) -> int:
        """Record a new job (queued, or moved on at once to ``state`` with ``reason``).

        ``while_recording`` runs inside the same transaction: if it raises, no job is
        recorded (the spool moves the dropped file with it, so that a file is never both
        in the spool and in a job, nor in neither).
        """
        now = time.time()
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO jobs (name, source_name, kind, state, created, updated, work_dir,"
                " input_path, reason, print_requested, nozzle, pinned)"
                " VALUES (?,?,?,?,?,?,?,?,?,?,?,?)",
                (name, source_name, kind, str(JobState.QUEUED), now, now, work_dir, input_path,
                 None, int(print_requested), nozzle, int(nozzle is not None)))
            job_id = int(cur.lastrowid)
            db.execute("INSERT INTO transitions VALUES (?,?,?,?,?)",
                       (job_id, None, str(JobState.QUEUED), now, note))
            if state != JobState.QUEUED:
                check_transition(JobState.QUEUED, state)
                db.execute("UPDATE jobs SET state=?, reason=? WHERE id=?",
                           (str(state), reason, job_id))
                db.execute("INSERT INTO transitions VALUES (?,?,?,?,?)",
                           (job_id, str(JobState.QUEUED), str(state), now, reason))
            if while_recording is not None:
                while_recording()
        return job_id

    def get(self, job_id: int) -> Job | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM jobs WHERE id=?", (job_id,)).fetchone()
        return self._row_to_job(row) if row else None

    def jobs(self, states: set[JobState] | None = None, *, limit: int | None = None) -> list[Job]:
        query = "SELECT * FROM jobs"
        args: list[Any] = []
        if states:
            query += f" WHERE state IN ({','.join('?' * len(states))})"
            args += [str(s) for s in states]
        query += " ORDER BY id"
        if limit:
            inner = query.replace(" ORDER BY id", " ORDER BY id DESC")
            query = f"SELECT * FROM ({inner} LIMIT {int(limit)}) ORDER BY id"
        with self._lock:
            rows = self._db.execute(query, args).fetchall()
        return [self._row_to_job(r) for r in rows]

    def work_dirs(self) -> set[str]:
        """The work folders that jobs own (read without decoding every job's reports)."""
        with self._lock:
            rows = self._db.execute("SELECT DISTINCT work_dir FROM jobs WHERE work_dir IS NOT"
                                    " NULL AND work_dir != ''").fetchall()
        return {r[0] for r in rows}

    def unreported(self, states: set[JobState]) -> list[int]:
        """Ids of jobs in ``states`` whose reports were never written: the daemon died
        between their last state change and archiving them (reports come last)."""
        marks = ",".join("?" * len(states))
        with self._lock:
            rows = self._db.execute(
                f"SELECT id FROM jobs WHERE state IN ({marks}) AND (outputs IS NULL OR"
                " outputs NOT LIKE '%\"report_json\"%') ORDER BY id",
                [str(s) for s in states]).fetchall()
        return [int(r[0]) for r in rows]

    def change_mark(self) -> tuple[int, float]:
        """(number of jobs, latest update time): changes whenever any job does (a cheap
        look for watchers such as the status page's event stream)."""
        with self._lock:
            row = self._db.execute("SELECT COUNT(*), MAX(updated) FROM jobs").fetchone()
        return int(row[0]), float(row[1] or 0.0)

    def counts(self) -> dict[str, int]:
        with self._lock:
            rows = self._db.execute("SELECT state, COUNT(*) FROM jobs GROUP BY state").fetchall()
        return {r[0]: r[1] for r in rows}

    def transition(self, job_id: int, new: JobState, *, note: str | None = None,
                   expect: JobState | set[JobState] | None = None, **fields: Any) -> Job:
        """Move a job to ``new`` (checked against the state machine) and set ``fields``.

        ``expect``: the state(s) the job must be in, else TransitionError (guards races
        between the daemon and the CLI).
        """
        from daemon.states import TransitionError

        now = time.time()
        with self._tx() as db:
            row = db.execute("SELECT state FROM jobs WHERE id=?", (job_id,)).fetchone()
            if row is None:
                raise KeyError(f"no job {job_id}")
            old = JobState(row[0])
            if expect is not None:
                expected = {expect} if isinstance(expect, JobState) else set(expect)
                if old not in expected:
                    raise TransitionError(f"job {job_id} is {old}, not "
                                          f"{' or '.join(sorted(map(str, expected)))}")
            check_transition(old, new)
            self._set(db, job_id, state=str(new), updated=now, **fields)
            db.execute("INSERT INTO transitions VALUES (?,?,?,?,?)",
                       (job_id, str(old), str(new), now, note))
        job = self.get(job_id)
        assert job is not None
        return job

    def update(self, job_id: int, *, durable: bool = True, **fields: Any) -> None:
        """Set fields without a state change (progress, reports). ``durable=False``: a
        soft write (see the module docstring), for values rewritten every few seconds."""
        with self._tx(durable) as db:
            self._set(db, job_id, updated=time.time(), **fields)

    @staticmethod
    def _set(db: sqlite3.Connection, job_id: int, **fields: Any) -> None:
        if not fields:
            return
        cols, vals = [], []
        for k, v in fields.items():
            if k in JSON_FIELDS and v is not None:
                v = json.dumps(v)
            if isinstance(v, bool):
                v = int(v)
            cols.append(f"{k}=?")
            vals.append(v)
        db.execute(f"UPDATE jobs SET {', '.join(cols)} WHERE id=?", (*vals, job_id))

    # -- printers -------------------------------------------------------------------------
    def claim_for_printer(self, job_id: int, printer: str) -> bool:
        """Atomically give a ready job to ``printer``: True for exactly one caller, the
        first; False if another printer holds it or it is no longer ready."""
        with self._tx() as db:
            cur = db.execute("UPDATE jobs SET printer=?, updated=? WHERE id=? AND printer IS"
                             " NULL AND state=?", (printer, time.time(), job_id,
                                                   str(JobState.READY)))
            return cur.rowcount == 1

    def release_printer(self, job_id: int, printer: str) -> None:
        """Undo :meth:`claim_for_printer` of a job still ready (its print did not start):
        any printer may take it."""
        with self._tx() as db:
            db.execute("UPDATE jobs SET printer=NULL WHERE id=? AND printer=? AND state=?",
                       (job_id, printer, str(JobState.READY)))

    def release_unstarted_claims(self) -> int:
        """At start-up: ready jobs a printer claimed but never started (the daemon died
        in between) are free again. Returns how many."""
        with self._tx() as db:
            cur = db.execute("UPDATE jobs SET printer=NULL WHERE state=? AND printer IS NOT NULL",
                             (str(JobState.READY),))
            return cur.rowcount

    def queued_work(self, exclude: int | None = None) -> dict[float | None, int]:
        """Jobs not yet ended (queued to printing), by the nozzle class they are routed
        to; ``exclude``: a job id not to count."""
        from daemon.states import ACTIVE

        marks = ",".join("?" * len(ACTIVE))
        with self._lock:
            rows = self._db.execute(
                f"SELECT nozzle, COUNT(*) FROM jobs WHERE state IN ({marks}) AND id != ?"
                " GROUP BY nozzle", [*(str(s) for s in ACTIVE), -1 if exclude is None
                                     else exclude]).fetchall()
        return {r[0]: int(r[1]) for r in rows}

    def history(self, job_id: int) -> list[dict[str, Any]]:
        with self._lock:
            rows = self._db.execute(
                "SELECT from_state, to_state, at, note FROM transitions WHERE job_id=?"
                " ORDER BY rowid", (job_id,)).fetchall()
        return [dict(r) for r in rows]

    # -- requests -------------------------------------------------------------------------
    def add_request(self, job_id: int, action: str) -> int:
        with self._tx() as db:
            cur = db.execute("INSERT INTO requests (job_id, action, created) VALUES (?,?,?)",
                             (job_id, action, time.time()))
            return int(cur.lastrowid)

    def pending_requests(self) -> list[dict[str, Any]]:
        with self._lock:
            rows = self._db.execute(
                "SELECT * FROM requests WHERE handled IS NULL ORDER BY id").fetchall()
        return [dict(r) for r in rows]

    def finish_request(self, req_id: int, ok: bool, message: str) -> None:
        with self._tx() as db:
            db.execute("UPDATE requests SET handled=?, ok=?, message=? WHERE id=?",
                       (time.time(), int(ok), message, req_id))

    def request(self, req_id: int) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM requests WHERE id=?", (req_id,)).fetchone()
        return dict(row) if row else None

    # -- temperatures ---------------------------------------------------------------------
    def add_temperatures(self, job_id: int, readings: dict[str, Any]) -> None:
        """Record one sample of heater readings for a printing job (a soft write)."""
        with self._tx(durable=False) as db:
            db.execute("INSERT INTO temperatures VALUES (?,?,?)",
                       (job_id, time.time(), json.dumps(readings)))

    def temperatures(self, job_id: int) -> list[dict[str, Any]]:
        """The job's samples in order: ``{"at": epoch s, "T": [current, target], ...}``."""
        with self._lock:
            rows = self._db.execute("SELECT at, readings FROM temperatures WHERE job_id=?"
                                    " ORDER BY rowid", (job_id,)).fetchall()
        return [{"at": r[0], **json.loads(r[1])} for r in rows]

    # -- meta -----------------------------------------------------------------------------
    def set_meta(self, key: str, value: Any, *, durable: bool = True) -> None:
        """Set a meta value; ``durable=False`` for a soft write (the status heartbeat)."""
        with self._tx(durable) as db:
            db.execute("INSERT INTO meta (key, value) VALUES (?, ?) ON CONFLICT(key)"
                       " DO UPDATE SET value=excluded.value", (key, json.dumps(value)))

    def get_meta(self, key: str, default: Any = None) -> Any:
        with self._lock:
            try:
                row = self._db.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
            except sqlite3.OperationalError:  # a reader racing the daemon's first start
                return default
        return json.loads(row[0]) if row else default


class _Tx:
    """``with journal._tx() as db``: an IMMEDIATE transaction under the journal's lock."""

    def __init__(self, journal: Journal, durable: bool = True) -> None:
        self.journal = journal
        self.durable = durable

    def __enter__(self) -> sqlite3.Connection:
        self.journal._lock.acquire()
        try:
            self.journal._begin(self.durable)
        except BaseException:
            self.journal._lock.release()
            raise
        return self.journal._db

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.journal._db.execute("COMMIT" if exc_type is None else "ROLLBACK")
        finally:
            self.journal._lock.release()
