"""Farm mode: many preflight daemons share one queue through Redis (``[farm] broker``).

- Intake: a file dropped into any node's spool is copied into the shared artefact
  store (by content) and recorded in that node's journal outbox in the transaction that
  takes it out of the spool; it is published to the farm's queue when the broker is
  reachable (:mod:`daemon.farm.ledger`, :mod:`daemon.farm.queue`).
- Dispatch: every node offers each of its free printers the oldest waiting job that
  fits it (pinned nozzle class, build volume). The claim is atomic in Redis, with a
  lease the claiming node renews; a lease that expires before the print started puts
  the job back at the head of the queue (any node's reaper, within ``claim_timeout``).
- Compute: the claiming node sends the repair+slice for its printer's ε to the farm's
  Celery queue; any node with ``[farm] compute = true`` runs it (at-least-once,
  idempotent, results reused: :mod:`daemon.farm.tasks`).
- Printing is at-most-once: the claim is turned into "printing" in Redis, atomically
  and only if the lease still holds, before the first line is sent; from then on the
  job is never re-queued by the farm. A node killed mid-print finds its job
  interrupted at restart (its own journal), re-sent only by ``preflight jobs requeue``.
- A broker outage pauses new dispatch; prints under way go on; outcomes and new jobs
  wait in the journal and are sent when the broker is back.
"""

from __future__ import annotations

import os

from daemon.config import Config, ConfigError


def node_name(cfg: Config) -> str:
    return cfg.farm.node or os.uname().nodename


def check_farm_config(cfg: Config) -> None:
    """ConfigError naming the key when farm mode is asked for but cannot work."""
    farm = cfg.farm
    if not farm.broker:
        return
    if not farm.broker.startswith(("redis://", "rediss://", "unix://")):
        raise ConfigError(f'[farm] broker: expected "redis://host:port/db", got {farm.broker!r}')
    if farm.artefacts is None:
        raise ConfigError("[farm] artefacts: farm mode needs a directory every node mounts "
                          "(inputs and G-code travel through it, not through the broker)")
    if ":" in node_name(cfg) or "/" in node_name(cfg):
        raise ConfigError(f"[farm] node: {node_name(cfg)!r} may not contain ':' or '/'")
