"""Acting on jobs from the web: the same journal requests the CLI writes
(``preflight jobs print|cancel``), answered by the daemon's main loop."""

from __future__ import annotations

import asyncio
import time
from typing import Any

from daemon.journal import Job, Journal
from daemon.states import ACTIVE, ON_PRINTER, JobState
from daemon.web.uploads import Refused

S = JobState

#: How long a web request waits for the daemon's main loop to answer (it polls every 0.2 s).
ANSWER_WAIT = 15.0



async def ask_daemon(journal: Journal, job_id: int, action: str) -> tuple[bool, str]:
    """Write a request row and wait for the daemon's answer (ok, message)."""
    req = journal.add_request(job_id, action)
    end = time.monotonic() + ANSWER_WAIT
    while time.monotonic() < end:
        row = journal.request(req)
        if row and row["handled"]:
            return bool(row["ok"]), str(row["message"])
        await asyncio.sleep(0.05)
    return False, f"the daemon did not answer within {ANSWER_WAIT:g} s; the request stays recorded"


def printing_job(journal: Journal) -> Job | None:
    """The job on the printer (printing or paused), if any."""
    jobs = journal.jobs(set(ON_PRINTER))
    return jobs[0] if jobs else None


def current_job(journal: Journal) -> Job | None:
    """What OctoPrint would call the selected job: the one printing, else the newest
    active one, else the newest job of all."""
    job = printing_job(journal)
    if job is not None:
        return job
    active = journal.jobs(set(ACTIVE))
    if active:
        return active[-1]
    recent = journal.jobs(limit=1)
    return recent[-1] if recent else None


def job_by_name(journal: Journal, name: str) -> Job | None:
    """The newest job for a file name (as stored, or as uploaded)."""
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    for job in reversed(journal.jobs(limit=200)):
        if base in (job.name, job.source_name):
            return job
    return None


async def start_printing(journal: Journal, job: Job) -> str:
    """Have ``job`` print when it is ready; idempotent (a job already printing or
    already going to print is fine)."""
    if job.state in ON_PRINTER or (job.print_requested and job.state in ACTIVE):
        return f"job {job.id} is already printing or going to print"
    if job.state not in (S.READY, S.QUEUED, S.REPAIRING, S.SLICING):
        raise Refused(409, f"job {job.id} ({job.name}) is {job.state}"
                           + (f": {job.reason}" if job.reason else ""))
    ok, msg = await ask_daemon(journal, job.id, "print")
    if not ok:
        raise Refused(409, msg)
    return msg


async def control_print(journal: Journal, action: str) -> str:
    """Pause, resume, cancel or emergency-stop (``stop``) the print on the printer."""
    job = printing_job(journal)
    if job is None:
        raise Refused(409, f"there is no print to {action}")
    ok, msg = await ask_daemon(journal, job.id, action)
    if not ok:
        raise Refused(409, msg)
    return msg


async def job_command(journal: Journal, command: str, action: str | None = None) -> str:
    """OctoPrint's ``POST /api/job`` commands on the current job (``pause`` takes the
    ``action`` pause, resume or toggle, as OctoPrint's does; toggle when absent)."""
    if command == "start":
        ready = [j for j in journal.jobs({S.READY}) if not j.print_requested]
        if not ready:
            raise Refused(409, "there is no ready job waiting to be started")
        return await start_printing(journal, ready[0])
    if command == "cancel":
        job = printing_job(journal) or next(iter(reversed(journal.jobs(set(ACTIVE)))), None)
        if job is None:
            raise Refused(409, "there is no job to cancel")
        ok, msg = await ask_daemon(journal, job.id, "cancel")
        if not ok:
            raise Refused(409, msg)
        return msg
    if command == "pause":
        action = action or "toggle"
        if action not in ("pause", "resume", "toggle"):
            raise Refused(400, f"unknown pause action {action!r} (known: pause, resume, toggle)")
        if action == "toggle":
            job = printing_job(journal)
            action = "resume" if job is not None and job.state == S.PAUSED else "pause"
        return await control_print(journal, action)
    if command == "restart":
        raise Refused(409, "restarting a paused print from the start is not supported: cancel "
                           "it, clear the bed, then `preflight jobs requeue ID`")
    raise Refused(400, f"unknown job command {command!r} (known: start, cancel, pause)")


def print_times(journal: Journal, job: Job) -> tuple[float | None, float | None]:
    """(seconds printing so far, linear estimate of the seconds left) for a printing job."""
    if job.state not in ON_PRINTER:
        return None, None
    started = [h["at"] for h in journal.history(job.id) if h["to_state"] == str(S.PRINTING)]
    if not started:
        return None, None
    elapsed = max(0.0, time.time() - started[-1])
    done = job.progress or 0.0
    left = elapsed * (1.0 - done) / done if done > 0 else None
    return elapsed, left


def job_summary(journal: Journal, job: Job | None) -> dict[str, Any]:
    """The job fields both APIs report."""
    if job is None:
        return {"name": None, "state": None, "progress": None, "elapsed": None, "left": None}
    elapsed, left = print_times(journal, job)
    return {"name": job.name, "state": str(job.state), "progress": job.progress,
            "elapsed": elapsed, "left": left, "id": job.id}
