"""The soak's checks: every dropped file accounted for once, every print exactly once.

Inputs are what a person could look at after the run: the jobs as ``preflight jobs
list --all --json`` prints them, each job's transitions from the journal, the spool
folders and reports, and the log of executed commands that the virtual printer
process appends to (one command per line, without line number and checksum).

The executed log is cut into segments at each ``M110 N0``: the host sends it at every
handshake and at the start of every stream, so a print's executed lines are one
segment. Print attempts (transitions to ``printing``, in journal order) are matched to
the segments in order; a segment may also be a handshake's queries only.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.safety import strip_gcode
from printer.gcode import checksum, command_word

#: What the host itself sends outside a job's lines: handshake and info queries, the
#: lost-ok tickle (``M105``) and the cooldown after a cancelled stream.
HOST_WORDS = frozenset({"M110", "M115", "M105", "M211", "M200", "M862.1", "M208", "M155"})
COOLDOWN = frozenset({"M104 S0", "M140 S0", "M107", "M84"})
FINAL = ("done", "failed", "interrupted")
ATTEMPTS_REASON = "processing was interrupted"


@dataclass
class Attempt:
    """One print attempt of a job: from its ``printing`` transition to the next one."""

    job_id: int
    at: float
    ended_as: str
    executed: int = 0
    segment: int | None = None


@dataclass
class Findings:
    """Problems found (each one line) and the figures the report prints."""

    problems: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)

    def add(self, text: str) -> None:
        self.problems.append(text)


#: Unnumbered commands the host sends; line noise can alter them (they carry no checksum).
_HOST_TEXTS = ("M105", "M115", "M211", "M200", "M862.1 Q", "M208", *COOLDOWN)


def _noise(command: str) -> bool:
    """What line noise leaves behind, which the firmware answers "Unknown command": the
    checksum digits of a line whose start was flushed (Marlin empties its RX buffer
    after a line error; the tail still on the wire arrives as a line of its own), or an
    unnumbered host command with a byte or two altered."""
    if command.isdigit():
        return True
    return any(len(command) == len(text) and
               sum(a != b for a, b in zip(command, text, strict=True)) <= 2
               for text in _HOST_TEXTS)


def _host_command(command: str) -> bool:
    return command_word(command) in HOST_WORDS or command in COOLDOWN or _noise(command)


def split_segments(executed: list[str]) -> list[list[str]]:
    """The executed log cut at each ``M110 N0`` (the M110 itself dropped)."""
    segments: list[list[str]] = [[]]
    for command in executed:
        if command_word(command) == "M110":
            segments.append([])
        else:
            segments[-1].append(command)
    return segments


@dataclass
class Match:
    """What a segment ran of a print: ``done`` lines in order, the first problem (a line
    run twice, out of order or altered: None if there is none), and the line-noise
    artefacts the firmware ran (see :func:`_artefact`)."""

    done: int = 0
    problem: str | None = None
    artefacts: list[str] = field(default_factory=list)


_NOISE_CUT = re.compile(r"[*\x00-\x1f\x7f-\uffff]")


def _flushed_tail(command: str, expected: list[str], done: int) -> bool:
    """``command`` is the tail of a numbered line sent near line ``done + 1`` (lines
    ahead of it may be in flight), ending in that line's own checksum, whose ``*``
    noise changed into another byte."""
    cut = len(command.rstrip("0123456789"))
    head, digits = command[:cut - 1], command[cut:]
    if not head or not digits:
        return False
    for number in range(max(1, done - 8), min(len(expected), done + 8) + 1):
        line = expected[number - 1]
        if line.endswith(head) and digits == str(checksum(f"N{number} {line}")):
            return True
    return False


def _artefact(command: str, expected: list[str], done: int) -> int | None:
    """If line noise made ``command``, how many expected lines it stands for; else None.

    Two limits of the Marlin line protocol that no host can avoid show up under noise:
    a newline turned into another byte glues two lines into one whose 8-bit XOR
    checksum can still match (the due line runs, altered: 1); and the tail of a line
    whose start was flushed with the RX buffer after a line error arrives as a line
    without N, and runs if noise also changed its ``*`` (a piece of a line again: 0).
    A clean copy of a line never qualifies (that is a line run twice): a glued line
    carries a ``*`` or a control byte, a flushed tail ends in its own line's checksum."""
    if _flushed_tail(command, expected, done):
        return 0
    if _NOISE_CUT.search(command):
        head = _NOISE_CUT.split(command)[0].rstrip()
        if done < len(expected) and head == expected[done]:
            return 1
    return None


def match_prefix(segment: list[str], expected: list[str]) -> Match:
    """What ``segment`` (one stream's executed commands) ran of ``expected``."""
    match = Match()
    for position, command in enumerate(segment):
        if match.done < len(expected) and command == expected[match.done]:
            match.done += 1
        elif _host_command(command):
            continue
        elif (stands_for := _artefact(command, expected, match.done)) is not None:
            match.artefacts.append(command)
            match.done += stands_for
        elif match.problem is None:
            want = expected[match.done] if match.done < len(expected) else "(end of file)"
            match.problem = (f"executed {command!r} at position {position} where line "
                             f"{match.done + 1} {want!r} was due")
    return match


def account_files(dropped: dict[str, dict], jobs: list[dict], spool: Path,
                  found: Findings) -> dict[str, dict]:
    """Each dropped name must have exactly one job, in a final state, with its files
    and reports where they belong. Returns name -> job."""
    by_name: dict[str, list[dict]] = {}
    for job in jobs:
        by_name.setdefault(job["source_name"], []).append(job)
    lost = [name for name in dropped if name not in by_name]
    duplicated = [name for name, js in by_name.items() if name in dropped and len(js) > 1]
    stray = [name for name in by_name if name not in dropped]
    for name in lost:
        found.add(f"lost: {name} has no job")
    for name in duplicated:
        found.add(f"processed twice: {name} has jobs "
                  f"{', '.join(str(j['id']) for j in by_name[name])}")
    for name in stray:
        found.add(f"a job for a file that was never dropped: {name}")
    found.figures.update(lost=len(lost), duplicated=len(duplicated), stray=len(stray))
    outcome: dict[str, dict] = {}
    for name, info in dropped.items():
        js = by_name.get(name) or []
        if len(js) != 1:
            continue
        job = outcome[name] = js[0]
        _check_job_files(name, info, job, found)
    leftovers = [p.name for p in spool.iterdir() if p.is_file()]
    for name in leftovers:
        found.add(f"left in the spool: {name}")
    kept = {Path(j["work_dir"]).name for j in jobs if j["state"] == "interrupted"
            and j.get("work_dir")}
    work = spool / ".preflight" / "work"
    for folder in sorted(work.iterdir()) if work.is_dir() else ():
        if folder.name not in kept:
            found.add(f"work folder left behind: {folder.name} "
                      f"({', '.join(p.name for p in folder.iterdir())})")
    found.figures["interrupted_by"] = interrupted_causes(jobs)
    return outcome


#: reason fragment -> cause, for the figures
_CAUSES = (("daemon or the machine stopped", "daemon killed"), ("reset", "printer reset"),
           ("lost the printer", "unplugged"), ("stopped answering", "printer silent"),
           ("never accepts", "printer refuses lines"))


def interrupted_causes(jobs: list[dict]) -> dict[str, int]:
    causes: dict[str, int] = {}
    for job in jobs:
        if job["state"] != "interrupted":
            continue
        reason = job.get("reason") or ""
        cause = next((c for fragment, c in _CAUSES if fragment in reason), "other")
        causes[cause] = causes.get(cause, 0) + 1
    return causes


def _check_job_files(name: str, info: dict, job: dict, found: Findings) -> None:
    state = job["state"]
    if state not in FINAL:
        found.add(f"{name}: job {job['id']} ended {state}, not done/failed/interrupted")
        return
    outputs = job.get("outputs") or {}
    report = outputs.get("report_json")
    if not report or not Path(report).is_file():
        found.add(f"{name}: job {job['id']} ({state}) has no report")
    elif state != "done":
        reason = json.loads(Path(report).read_text()).get("reason") or ""
        text = Path(outputs.get("report_txt", "")).read_text() if outputs.get(
            "report_txt") else ""
        if not reason.strip() or reason not in text:
            found.add(f"{name}: job {job['id']} ({state}) has no human-readable reason")
    where = {"done": "done", "failed": "failed"}.get(state)
    kept = outputs.get("input")
    if where and not (kept and Path(kept).is_file() and Path(kept).parent.name == where):
        found.add(f"{name}: job {job['id']} is {state} but its file is not in {where}/")
    if state == "interrupted" and not Path(job.get("input_path") or "").is_file():
        found.add(f"{name}: job {job['id']} is interrupted but its input is gone")
    expect = info["expect"]
    reason = job.get("reason") or ""
    if expect == "ok" and state == "failed" and ATTEMPTS_REASON not in reason:
        found.add(f"{name}: a good {info['kind']} file failed: {reason}")
    if expect == "fail" and state != "failed":
        found.add(f"{name}: a bad {info['kind']} file ended {state}")


def expected_lines(job: dict) -> list[str] | None:
    """The commands the host streams for this job (its G-code, comments stripped)."""
    outputs = job.get("outputs") or {}
    key = "input" if job["kind"] == "gcode" else "gcode"
    for path in (job.get("gcode_path"), outputs.get(key)):
        if path and Path(path).is_file():
            with open(path, encoding="utf-8", errors="replace") as fh:
                return strip_gcode(fh)
    return None


def print_attempts(histories: dict[int, list[dict]]) -> list[Attempt]:
    """Every transition to ``printing``, in time order, with the state that ended it."""
    attempts = []
    for job_id, history in histories.items():
        for index, row in enumerate(history):
            if row["to_state"] != "printing":
                continue
            after = history[index + 1]["to_state"] if index + 1 < len(history) else "printing"
            attempts.append(Attempt(job_id, row["at"], after))
    return sorted(attempts, key=lambda a: a.at)


def check_prints(jobs: list[dict], histories: dict[int, list[dict]], executed: list[str],
                 found: Findings) -> None:
    """Match print attempts to executed segments; each line once, done prints whole."""
    by_id = {job["id"]: job for job in jobs}
    lines = {job_id: expected_lines(by_id[job_id]) for job_id in histories
             if any(r["to_state"] == "printing" for r in histories[job_id])}
    segments = split_segments(executed)
    attempts = print_attempts(histories)
    started = [a for a in attempts if a.ended_as != "ready"]  # "ready": nothing may have run
    cursor = 0
    artefacts: list[str] = []
    for index, attempt in enumerate(started):
        expected = lines.get(attempt.job_id)
        if expected is None:
            found.add(f"job {attempt.job_id}: its G-code is gone, cannot check its print")
            continue
        following = lines.get(started[index + 1].job_id) if index + 1 < len(started) else None
        probe = _find_segment(segments, cursor, expected, following)
        if probe is None:
            continue  # no line of it ran (stopped before its first line executed)
        match = match_prefix(segments[probe], expected)
        attempt.segment, attempt.executed, cursor = probe, match.done, probe + 1
        artefacts.extend(f"job {attempt.job_id}: {a!r}" for a in match.artefacts)
        if match.problem:
            found.add(f"job {attempt.job_id}: {match.problem}")
        if attempt.ended_as == "done" and match.done != len(expected):
            found.add(f"job {attempt.job_id}: printed as done but {match.done} of "
                      f"{len(expected)} lines executed")
    _unexplained(segments, attempts, lines, found)
    _resent(attempts, histories, found)
    found.figures["noise_artefacts"] = artefacts
    found.figures["print_attempts"] = len(attempts)
    found.figures["lines_executed"] = sum(a.executed for a in attempts)


def _score(match: Match) -> tuple[bool, int]:
    return match.problem is None, match.done


def _find_segment(segments: list[list[str]], cursor: int, expected: list[str],
                  following: list[str] | None) -> int | None:
    """The segment from ``cursor`` on that ran this attempt's lines, or None if it ran
    none. Prints share their start G-code, so a segment is this attempt's only if it
    fits it at least as well as the next attempt; one that fits the next attempt better
    means this one ran nothing. A segment that fits neither belongs to no attempt: it
    is skipped here and reported later."""
    for probe in range(cursor, len(segments)):
        segment = segments[probe]
        if all(_host_command(c) for c in segment):
            continue
        mine = match_prefix(segment, expected)
        theirs = match_prefix(segment, following) if following else Match()
        if mine.done and _score(mine) >= _score(theirs):
            return probe
        if theirs.done:
            return None
    return None


def _unexplained(segments: list[list[str]], attempts: list[Attempt],
                 lines: dict[int, list[str] | None], found: Findings) -> None:
    """Segments with job lines that no attempt explains. One whose lines are mostly in
    none of the soak's files came from another process that opened the printer's pty (a stale
    path to a recycled /dev/pts number on a shared machine): counted, not a failure."""
    used = {a.segment for a in attempts if a.segment is not None}
    known = set().union(*(ls for ls in lines.values() if ls))
    foreign = []
    for index, segment in enumerate(segments):
        jobs_lines = [c for c in segment if not _host_command(c)]
        if index in used or not jobs_lines:
            continue
        if 2 * sum(c not in known for c in jobs_lines) > len(jobs_lines):
            foreign.append(f"segment {index}: {len(jobs_lines)} lines, first "
                           f"{jobs_lines[0]!r}")
            continue
        found.add(f"executed segment {index} ({len(jobs_lines)} lines, first "
                  f"{jobs_lines[0]!r}) belongs to no print attempt")
    found.figures["foreign_segments"] = foreign


def _resent(attempts: list[Attempt], histories: dict[int, list[dict]],
            found: Findings) -> None:
    """An interrupted print is never started again by itself (the soak never requeues)."""
    for job_id, history in histories.items():
        pairs = [(r["from_state"], r["to_state"]) for r in history]
        if ("interrupted", "ready") in pairs:
            found.add(f"job {job_id}: an interrupted print went back to ready without a requeue")
        ran = [a for a in attempts if a.job_id == job_id and a.executed]
        if len(ran) > 1:
            found.add(f"job {job_id}: printed {len(ran)} times without a requeue")
