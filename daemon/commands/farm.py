"""CLI: ``preflight farm status``: the farm's nodes, printers and queue, from its broker."""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

from daemon.commands import fail
from daemon.commands.daemon import CONFIG_HELP, _load


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("farm", help="the print farm this daemon belongs to")
    fsub = p.add_subparsers(dest="farm_command", metavar="ACTION", required=True)
    q = fsub.add_parser("status", help="nodes, printers (class, state, current job) and "
                        "queue depth")
    q.add_argument("--config", "-c", metavar="FILE", help=CONFIG_HELP)
    q.add_argument("--json", action="store_true", help="print the status as JSON")
    q.set_defaults(func=cmd_farm_status)


def farm_status(cfg: Any) -> dict[str, Any]:
    """The farm as its broker sees it (raises redis.RedisError if it is unreachable)."""
    from daemon.farm.queue import FarmQueue, shown_broker
    from daemon.farm.tasks import compute_queue

    queue = FarmQueue(cfg.farm.broker, cfg.farm.name)
    nodes = queue.nodes()
    depth = queue.depth()
    # Celery's Redis transport keeps a queue as a list named after it (with our prefix)
    depth["compute"] = int(queue.redis.llen(f"pf:{cfg.farm.name}:celery:"
                                            f"{compute_queue(cfg)}"))
    states: dict[str, int] = {}
    names: dict[str, str] = {}
    for fid, job in queue.all_jobs().items():
        states[job.get("state", "?")] = states.get(job.get("state", "?"), 0) + 1
        names[fid] = job.get("name", "?")
    return {"farm": cfg.farm.name, "broker": shown_broker(cfg.farm.broker), "nodes": nodes,
            "queue": depth, "jobs": states, "job_names": names}


def _lines(status: dict[str, Any]) -> list[str]:
    queue = status["queue"]
    out = [f"farm {status['farm']} on {status['broker']}: {queue['waiting']} waiting for a "
           f"printer, {queue['claimed']} claimed, {queue['compute']} waiting for compute",
           "jobs: " + (", ".join(f"{n} {s}" for s, n in sorted(status["jobs"].items()))
                       or "none")]
    for name, node in status["nodes"].items():
        if node is None:
            out.append(f"node {name}: no heartbeat (down)")
            continue
        age = time.time() - float(node.get("heartbeat") or 0)
        role = "compute" if node.get("compute") else "no compute"
        outbox = node.get("outbox") or {}
        out.append(f"node {name}: up ({role}, heartbeat {age:.0f} s ago, "
                   f"{outbox.get('unpublished', 0)} not yet published)")
        for p in node.get("printers") or []:
            job = p.get("job")
            doing = (f"job {status['job_names'].get(job, job)} ({p.get('job_state')})"
                     if job else "idle")
            nozzle = p.get("nozzle")
            out.append(f"  printer {p['name']}: nozzle {nozzle if nozzle else '?'} mm, "
                       f"{p.get('state')}, {doing}")
    return out


def cmd_farm_status(args: argparse.Namespace) -> int:
    import redis

    from daemon.config import ConfigError
    from daemon.farm.queue import shown_broker

    try:
        cfg = _load(args)
    except ConfigError as e:
        return fail(str(e), 2)
    if not cfg.farm.broker:
        return fail(f"this node is not in a farm: [farm] broker is not set in {cfg.source}", 2)
    try:
        status = farm_status(cfg)
    except redis.RedisError as e:
        return fail(f"cannot reach the farm's broker {shown_broker(cfg.farm.broker)}: {e}")
    if args.json:
        print(json.dumps(status, indent=2))
    else:
        print("\n".join(_lines(status)))
    return 0
