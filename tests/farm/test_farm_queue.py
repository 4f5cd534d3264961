"""The farm queue's claims, leases and hand-over to printing on a real redis-server."""

from __future__ import annotations

import threading
import time

from daemon.farm.queue import FarmQueue


def _queue(redis_server) -> FarmQueue:
    return FarmQueue(redis_server.url, "t")


def test_publish_is_idempotent_and_fifo(redis_server):
    q = _queue(redis_server)
    assert q.publish("a", {"name": "a.stl", "pin": ""})
    assert q.publish("b", {"name": "b.stl", "pin": "0.6"})
    assert not q.publish("a", {"name": "a.stl", "pin": ""})  # a re-publish after a crash
    assert q.waiting() == ["a", "b"]
    assert q.job("b")["pin"] == "0.6" and q.job("b")["state"] == "queued"


def test_exactly_one_of_many_printers_claims_a_job(redis_server):
    q = _queue(redis_server)
    for i in range(20):
        q.publish(f"j{i}", {"name": f"{i}.stl"})
    wins: dict[str, list[str]] = {}
    barrier = threading.Barrier(8)

    def printer(name: str) -> None:
        mine = FarmQueue(redis_server.url, "t")  # a connection of its own, like a node
        barrier.wait()
        got = wins.setdefault(name, [])
        for fid in [f"j{i}" for i in range(20)]:
            if mine.claim(fid, "node", name, ttl=30):
                got.append(fid)

    threads = [threading.Thread(target=printer, args=(f"p{i}",)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    claimed = [fid for got in wins.values() for fid in got]
    assert sorted(claimed) == sorted(f"j{i}" for i in range(20))  # each once, none twice
    assert q.waiting() == [] and q.depth() == {"waiting": 0, "claimed": 20}


def test_an_expired_lease_goes_back_and_cannot_start_printing(redis_server):
    q = _queue(redis_server)
    q.publish("x", {"name": "x.stl"})
    q.publish("y", {"name": "y.stl"})
    assert q.claim("x", "n1", "p", ttl=0.3)
    assert q.reap() == []  # the lease holds
    time.sleep(0.5)
    assert not q.renew("x", "n1", "p", ttl=0.3)
    assert q.reap() == ["x"]
    assert q.waiting() == ["x", "y"]  # back at the head of the queue
    assert not q.start_print("x", "n1", "p")  # the old holder may not print it now
    assert q.claim("x", "n2", "p", ttl=30)
    assert q.start_print("x", "n2", "p")
    assert q.job("x")["state"] == "printing"
    time.sleep(0.5)
    assert q.reap() == []  # printing: never given back by the farm
    assert not q.finish("x", "n1", "p", "done", "", 0.4)  # not the holder
    assert q.finish("x", "n2", "p", "interrupted", "unplugged", 0.4)
    assert not q.finish("x", "n2", "p", "done", "", 0.4)  # an outcome is recorded once
    job = q.job("x")
    assert job["state"] == "interrupted" and job["ends"] == "1" and job["requeues"] == "1"
    # an explicit requeue on the printer that was interrupted may print it again
    assert not q.start_print("x", "n1", "p")
    assert q.start_print("x", "n2", "p") and q.job("x")["prints"] == "2"


def test_the_brokers_appendonly_setting_is_read(redis_server):
    q = _queue(redis_server)
    assert q.appendonly() == "yes"  # the fixture runs Redis as a farm's broker should
    q.redis.config_set("appendonly", "no")
    assert q.appendonly() == "no"
