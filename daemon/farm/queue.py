"""The farm's shared queue in Redis: published jobs, atomic claims with leases,
the hand-over to printing, the final outcome, node heartbeats.

Every multi-key step is one Lua script, so Redis runs it atomically: two printers
can never both claim a job, a lease that expired can never be taken to printing,
and a final outcome is recorded once.

Keys (``pf:<farm>:`` prefix):

- ``queue``: LIST of job ids waiting for a printer, oldest first;
- ``job:<id>``: HASH, the job: name, kind, input (artefact key), suffix, origin node,
  pin (nozzle class, "" = any), extents (JSON mm), state (queued, claimed, printing,
  done, failed, cancelled, interrupted), node and printer holding it, reason, epsilon;
  kept for ``KEEP_ENDED_SECONDS`` once ended;
- ``claim:<id>``: STRING ``node/printer``, with a TTL while claimed (the lease), made
  persistent when printing starts;
- ``claimed``: SET of job ids claimed but not printing (what the reaper looks at);
- ``node:<name>``: STRING, the node's JSON status, expiring without heartbeats;
- ``nodes``: SET of node names ever seen.
"""

from __future__ import annotations

import json
import time
from typing import Any

import redis

FINAL_STATES = ("done", "failed", "cancelled", "interrupted")
#: An ended job's record stays in the broker this long (each node's journal keeps its own).
KEEP_ENDED_SECONDS = 7 * 86400

_PUBLISH = """
if redis.call('EXISTS', KEYS[1]) == 1 then return 0 end
redis.call('HSET', KEYS[1], unpack(ARGV, 2))
redis.call('HSET', KEYS[1], 'state', 'queued')
redis.call('RPUSH', KEYS[2], ARGV[1])
return 1
"""

# KEYS: job, claim, queue, claimed; ARGV: id, owner, ttl ms, node, printer, now
_CLAIM = """
if redis.call('HGET', KEYS[1], 'state') ~= 'queued' then return 0 end
if not redis.call('SET', KEYS[2], ARGV[2], 'NX', 'PX', ARGV[3]) then return 0 end
redis.call('LREM', KEYS[3], 1, ARGV[1])
redis.call('SADD', KEYS[4], ARGV[1])
redis.call('HSET', KEYS[1], 'state', 'claimed', 'node', ARGV[4], 'printer', ARGV[5],
           'claimed_at', ARGV[6])
redis.call('HINCRBY', KEYS[1], 'claims', 1)
return 1
"""

# KEYS: claim; ARGV: owner, ttl ms
_RENEW = """
if redis.call('GET', KEYS[1]) ~= ARGV[1] then return 0 end
redis.call('PEXPIRE', KEYS[1], ARGV[2])
return 1
"""

# KEYS: job, claim, claimed; ARGV: id, owner, node, printer, now
# 1: go ahead; 0: the claim is someone else's (or lost); a requeued interrupted print
# of this very printer goes ahead too (an explicit requeue by the user).
_START = """
if redis.call('EXISTS', KEYS[1]) == 0 then return 1 end  -- ended long ago: a local requeue
local state = redis.call('HGET', KEYS[1], 'state')
local mine = redis.call('HGET', KEYS[1], 'node') == ARGV[3] and
             redis.call('HGET', KEYS[1], 'printer') == ARGV[4]
if state == 'claimed' and redis.call('GET', KEYS[2]) == ARGV[2] then
  redis.call('PERSIST', KEYS[2])
elseif not (state == 'interrupted' and mine) then
  return 0
else
  redis.call('SET', KEYS[2], ARGV[2])
end
redis.call('SREM', KEYS[3], ARGV[1])
redis.call('HSET', KEYS[1], 'state', 'printing', 'started_at', ARGV[5])
redis.call('HINCRBY', KEYS[1], 'prints', 1)
return 1
"""

# KEYS: job, claim, claimed; ARGV: id, node, printer, state, reason, epsilon, now, keep s
_FINISH = """
if redis.call('HGET', KEYS[1], 'node') ~= ARGV[2] or
   redis.call('HGET', KEYS[1], 'printer') ~= ARGV[3] then return 0 end
local state = redis.call('HGET', KEYS[1], 'state')
if state ~= 'claimed' and state ~= 'printing' then return 0 end
redis.call('DEL', KEYS[2])
redis.call('SREM', KEYS[3], ARGV[1])
redis.call('HSET', KEYS[1], 'state', ARGV[4], 'reason', ARGV[5], 'epsilon', ARGV[6],
           'ended_at', ARGV[7])
redis.call('HINCRBY', KEYS[1], 'ends', 1)
redis.call('EXPIRE', KEYS[1], ARGV[8])
return 1
"""

# KEYS: job, claim, queue, claimed; ARGV: id, owner (or "" for the reaper)
_GIVE_BACK = """
local holder = redis.call('GET', KEYS[2])
if ARGV[2] ~= '' then
  if holder ~= ARGV[2] then return 0 end
elseif holder then return 0 end
if redis.call('HGET', KEYS[1], 'state') ~= 'claimed' then
  redis.call('SREM', KEYS[4], ARGV[1])
  return 0
end
redis.call('DEL', KEYS[2])
redis.call('SREM', KEYS[4], ARGV[1])
redis.call('HSET', KEYS[1], 'state', 'queued', 'node', '', 'printer', '')
redis.call('HINCRBY', KEYS[1], 'requeues', 1)
redis.call('LPUSH', KEYS[3], ARGV[1])
return 1
"""


def shown_broker(url: str) -> str:
    """The broker URL as it may be printed or logged: a password in it becomes ``***``."""
    from urllib.parse import urlsplit, urlunsplit

    try:
        parts = urlsplit(url)
        if parts.password is None:
            return url
        user = parts.username or ""
        host = parts.hostname or ""
        port = f":{parts.port}" if parts.port else ""
        return urlunsplit(parts._replace(netloc=f"{user}:***@{host}{port}"))
    except ValueError:
        return "<broker URL not shown>"


class FarmQueue:
    """The farm's Redis keys, for one farm ``name``; every method may raise
    ``redis.RedisError`` (the broker is down): callers retry later."""

    def __init__(self, url: str, farm: str, *, timeout: float = 2.0) -> None:
        self.redis = redis.Redis.from_url(url, socket_timeout=timeout,
                                          socket_connect_timeout=timeout,
                                          decode_responses=True)
        self.prefix = f"pf:{farm}:"
        self._publish = self.redis.register_script(_PUBLISH)
        self._claim = self.redis.register_script(_CLAIM)
        self._renew = self.redis.register_script(_RENEW)
        self._start = self.redis.register_script(_START)
        self._finish = self.redis.register_script(_FINISH)
        self._give_back = self.redis.register_script(_GIVE_BACK)

    def key(self, *parts: str) -> str:
        return self.prefix + ":".join(parts)

    def _job_keys(self, fid: str) -> tuple[str, str]:
        return self.key("job", fid), self.key("claim", fid)

    # -- jobs -----------------------------------------------------------------------------
    def publish(self, fid: str, fields: dict[str, Any]) -> bool:
        """Put a job on the queue; False if it was already published (idempotent)."""
        flat: list[str] = []
        for k, v in fields.items():
            flat += [k, v if isinstance(v, str) else json.dumps(v)]
        return bool(self._publish(keys=[self.key("job", fid), self.key("queue")],
                                  args=[fid, *flat]))

    def waiting(self, limit: int = 200) -> list[str]:
        return self.redis.lrange(self.key("queue"), 0, limit - 1)

    def job(self, fid: str) -> dict[str, str]:
        return self.redis.hgetall(self.key("job", fid))

    def jobs(self, fids: list[str]) -> list[dict[str, str]]:
        pipe = self.redis.pipeline(transaction=False)
        for fid in fids:
            pipe.hgetall(self.key("job", fid))
        return pipe.execute()

    def all_jobs(self) -> dict[str, dict[str, str]]:
        """Every job of the farm (for status and tests; SCAN, never KEYS)."""
        fids = [k.rsplit(":", 1)[1] for k in self.redis.scan_iter(self.key("job", "*"),
                                                                    count=500)]
        return dict(zip(fids, self.jobs(fids), strict=True))

    @staticmethod
    def owner(node: str, printer: str) -> str:
        return f"{node}/{printer}"

    def claim(self, fid: str, node: str, printer: str, ttl: float) -> bool:
        job, claim = self._job_keys(fid)
        return bool(self._claim(
            keys=[job, claim, self.key("queue"), self.key("claimed")],
            args=[fid, self.owner(node, printer), int(ttl * 1000), node, printer, time.time()]))

    def renew(self, fid: str, node: str, printer: str, ttl: float) -> bool:
        return bool(self._renew(keys=[self.key("claim", fid)],
                                args=[self.owner(node, printer), int(ttl * 1000)]))

    def start_print(self, fid: str, node: str, printer: str) -> bool:
        job, claim = self._job_keys(fid)
        return bool(self._start(keys=[job, claim, self.key("claimed")],
                                args=[fid, self.owner(node, printer), node, printer,
                                      time.time()]))

    def finish(self, fid: str, node: str, printer: str, state: str, reason: str,
               epsilon: float | None) -> bool:
        job, claim = self._job_keys(fid)
        return bool(self._finish(keys=[job, claim, self.key("claimed")],
                                 args=[fid, node, printer, state, reason or "",
                                       "" if epsilon is None else f"{epsilon:g}", time.time(),
                                       KEEP_ENDED_SECONDS]))

    def give_back(self, fid: str, node: str = "", printer: str = "") -> bool:
        """Put a claimed job back at the head of the queue: by its holder (``node``,
        ``printer``), or by the reaper (no owner) once its lease has expired."""
        job, claim = self._job_keys(fid)
        owner = self.owner(node, printer) if node else ""
        return bool(self._give_back(keys=[job, claim, self.key("queue"), self.key("claimed")],
                                    args=[fid, owner]))

    def reap(self) -> list[str]:
        """Give back every claim whose lease expired (its node died or lost the broker
        for longer than the lease): the ids put back on the queue."""
        back = []
        for fid in self.redis.smembers(self.key("claimed")):
            if self.give_back(fid):
                back.append(fid)
        return back

    # -- nodes ----------------------------------------------------------------------------
    def heartbeat(self, node: str, status: dict[str, Any], ttl: float) -> None:
        pipe = self.redis.pipeline(transaction=False)
        pipe.set(self.key("node", node), json.dumps(status), px=int(ttl * 1000))
        pipe.sadd(self.key("nodes"), node)
        pipe.execute()

    def nodes(self) -> dict[str, dict[str, Any] | None]:
        """Every node ever seen: its last status, or None if its heartbeat stopped."""
        names = sorted(self.redis.smembers(self.key("nodes")))
        values = self.redis.mget([self.key("node", n) for n in names]) if names else []
        return {n: (json.loads(v) if v else None) for n, v in zip(names, values, strict=True)}

    def appendonly(self) -> str | None:
        """The broker's ``appendonly`` setting ("yes" or "no"), None when it does not say
        (CONFIG renamed or refused, as on some managed Redis services)."""
        try:
            value = self.redis.config_get("appendonly").get("appendonly")
        except redis.ResponseError:
            return None
        return str(value) if value is not None else None

    def depth(self) -> dict[str, int]:
        pipe = self.redis.pipeline(transaction=False)
        pipe.llen(self.key("queue"))
        pipe.scard(self.key("claimed"))
        waiting, claimed = pipe.execute()
        return {"waiting": int(waiting), "claimed": int(claimed)}
