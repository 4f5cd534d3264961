"""What a farm test asserts once every job has ended: each job ended exactly once
(the broker's record and exactly one node's journal agree), and the virtual printers
executed each printed file exactly once."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

from daemon_helpers import gcode_commands
from farm_helpers import local_farm_jobs, print_blocks

from daemon.farm.node import LOST_CLAIM
from daemon.farm.queue import FINAL_STATES, FarmQueue


def all_ended(queue: FarmQueue, expected: int) -> bool:
    jobs = queue.all_jobs()
    return len(jobs) == expected and all(j.get("state") in FINAL_STATES for j in jobs.values())


def check_farm(queue: FarmQueue, nodes: list, expected: int, *,
               partial_prints: int = 0) -> dict[str, dict]:
    """Assert the farm's end state; returns fid -> {"job": hash, "node", "local": Job}."""
    jobs = queue.all_jobs()
    assert len(jobs) == expected, f"{len(jobs)} farm jobs, {expected} dropped"
    owners: dict[str, list] = {}
    for node in nodes:
        for claim in local_farm_jobs(node):
            if claim["reason"] != LOST_CLAIM:  # cancelled here: never sent, printed elsewhere
                owners.setdefault(claim["fid"], []).append((node, claim))
    out = {}
    for fid, job in jobs.items():
        assert job["state"] in FINAL_STATES, (fid, job)
        assert job.get("ends") == "1", (fid, job)  # one outcome, recorded once
        held = owners.get(fid, [])
        assert len(held) == 1, f"{job['name']} is held by {len(held)} journals: {held}"
        node, claim = held[0]
        assert str(claim["state"]) == job["state"], (claim, job)
        out[fid] = {"job": job, "node": node, "local": node.journal.get(claim["job_id"]),
                    "printer": claim["printer"]}
    _check_prints(nodes, out, partial_prints)
    return out


def _check_prints(nodes: list, jobs: dict[str, dict], partial_prints: int) -> None:
    """The virtual logs' prints are exactly the done jobs' G-code, each once per job."""
    expected: Counter = Counter()
    for entry in jobs.values():
        local = entry["local"]
        if str(local.state) != "done":
            continue
        key = "gcode" if local.kind == "mesh" else "input"
        expected[tuple(gcode_commands(Path(local.outputs[key])))] += 1
    executed: Counter = Counter()
    for node in nodes:
        for log in node.cfg_path.parent.glob("*.log"):
            if log.name != "daemon.log":
                executed.update(print_blocks(log))
    for block, count in expected.items():
        assert executed[block] == count, f"a printed file ran {executed[block]} times, " \
                                         f"{count} expected"
    extra = [b for b in executed if b not in expected and len(b) > 12]
    assert len(extra) <= partial_prints, f"{len(extra)} prints no done job explains"


def report_epsilon(local) -> float:
    return json.loads(Path(local.outputs["report_json"]).read_text())["epsilon"]
