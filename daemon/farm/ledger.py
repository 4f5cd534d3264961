"""The journal's farm tables: what this node owes the farm and what it holds.

- ``farm_outbox``: files this node took from its spool (or its HTTP API) for the
  farm. A row is written in the same transaction that removes the file from the spool
  (its content is already in the artefact store), and is published to the broker
  later: a broker outage loses nothing, it only delays. ``published`` is set once the
  broker has the job (publishing is idempotent, so a crash in between is harmless).
- ``farm_jobs``: the farm jobs this node's printers claimed, mapped to the local job
  (by its work folder, recorded in the transaction that creates the job) and its
  printer; ``reported`` is set once the broker has the job's outcome.

The SQL lives with the journal's connection and transactions (the journal owns all
SQL); it is in its own module so the farm's tables read in one place.
"""

from __future__ import annotations

import json
import time
from typing import Any

from daemon.journal import Journal

SCHEMA = """
CREATE TABLE IF NOT EXISTS farm_outbox (
    fid TEXT PRIMARY KEY,
    fields TEXT NOT NULL,          -- JSON: what is published
    created REAL NOT NULL,
    published REAL
);
CREATE TABLE IF NOT EXISTS farm_jobs (
    fid TEXT NOT NULL,
    work_dir TEXT PRIMARY KEY,     -- the local job's work folder
    printer TEXT NOT NULL,
    reported INTEGER NOT NULL DEFAULT 0
);
"""


class FarmLedger:
    def __init__(self, journal: Journal, *, create: bool = True) -> None:
        """``create=False``: a reader (the CLI, tests) of a journal the daemon writes."""
        self.journal = journal
        if not create:
            return
        with journal._tx() as db:
            for statement in filter(str.strip, SCHEMA.split(";")):
                db.execute(statement)

    # -- outbox ---------------------------------------------------------------------------
    def add_outbox(self, fid: str, fields: dict[str, Any], while_recording) -> None:
        """Record a job for the farm; ``while_recording`` (removing the spool file) runs
        in the same transaction: if it raises, nothing is recorded."""
        with self.journal._tx() as db:
            db.execute("INSERT INTO farm_outbox (fid, fields, created) VALUES (?,?,?)",
                       (fid, json.dumps(fields), time.time()))
            while_recording()

    def unpublished(self) -> list[tuple[str, dict[str, Any]]]:
        with self.journal._lock:
            rows = self.journal._db.execute(
                "SELECT fid, fields FROM farm_outbox WHERE published IS NULL ORDER BY rowid"
            ).fetchall()
        return [(r[0], json.loads(r[1])) for r in rows]

    def mark_published(self, fid: str) -> None:
        with self.journal._tx() as db:
            db.execute("UPDATE farm_outbox SET published=? WHERE fid=?", (time.time(), fid))

    def outbox_counts(self) -> dict[str, int]:
        with self.journal._lock:
            row = self.journal._db.execute(
                "SELECT COUNT(*), SUM(published IS NULL) FROM farm_outbox").fetchone()
        return {"taken": int(row[0] or 0), "unpublished": int(row[1] or 0)}

    # -- claimed jobs ---------------------------------------------------------------------
    def record_claim_in_tx(self, fid: str, work_dir: str, printer: str) -> None:
        """Inside the journal transaction that adds the local job (``add_job``'s
        ``while_recording``): map it to its farm job."""
        self.journal._db.execute(
            "INSERT INTO farm_jobs (fid, work_dir, printer) VALUES (?,?,?)",
            (fid, work_dir, printer))

    def claims(self) -> list[dict[str, Any]]:
        """Every claimed farm job with its local job's id, state and ε."""
        with self.journal._lock:
            rows = self.journal._db.execute(
                "SELECT f.fid, f.work_dir, f.printer, f.reported, j.id, j.state, j.reason,"
                " j.epsilon "
                "FROM farm_jobs f JOIN jobs j ON j.work_dir = f.work_dir ORDER BY j.id"
            ).fetchall()
        return [dict(zip(("fid", "work_dir", "printer", "reported", "job_id", "state", "reason",
                          "epsilon"), r, strict=True)) for r in rows]

    def claim_of(self, work_dir: str | None) -> tuple[str, str] | None:
        """(farm id, printer) of a local job, or None if it is not a farm job."""
        with self.journal._lock:
            row = self.journal._db.execute(
                "SELECT fid, printer FROM farm_jobs WHERE work_dir=?", (work_dir,)).fetchone()
        return (row[0], row[1]) if row else None

    def set_reported(self, work_dir: str, reported: bool) -> None:
        with self.journal._tx() as db:
            db.execute("UPDATE farm_jobs SET reported=? WHERE work_dir=?",
                       (int(reported), work_dir))
