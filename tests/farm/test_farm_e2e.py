"""The print farm end to end: a real redis-server, real `preflight run` daemons with
virtual printers, jobs dropped into different nodes' spools."""

from __future__ import annotations

import pytest
from daemon_helpers import DaemonProc, box, broken_stl, drop, tiny_gcode, write_binary_stl
from farm_checks import all_ended, check_farm, report_epsilon
from farm_helpers import farm_config

from daemon.farm.queue import FarmQueue


def _nodes(tmp, redis_server, *, compute_nodes=1, **kw):
    art = tmp / "artefacts"
    a = DaemonProc(farm_config(tmp / "a", node="a", broker=redis_server.url, artefacts=art,
                               printers=[{"name": "a04", "nozzle": 0.4},
                                         {"name": "a06", "nozzle": 0.6}], **kw))
    b = DaemonProc(farm_config(tmp / "b", node="b", broker=redis_server.url, artefacts=art,
                               printers=[{"name": "b04", "nozzle": 0.4,
                                          "volume": [300, 300, 300]},
                                         {"name": "b06", "nozzle": 0.6}], **kw))
    c = DaemonProc(farm_config(tmp / "c", node="c", broker=redis_server.url, artefacts=art,
                               printers=None, compute=True, **kw))
    return a, b, c


def _drop_mix(tmp, spools, count: int) -> dict[str, float | None]:
    """``count`` jobs over ``spools``: boxes of a few sizes (repeats reuse their repair),
    the shipped broken model, G-code files; two in five pinned to 0.6, by a sidecar or
    by the spool subfolder ``nozzle-0.6/``. Returns name -> pinned nozzle."""
    src = tmp / "models"
    src.mkdir(exist_ok=True)
    broken = broken_stl(src / "broken.stl").read_bytes()
    pins: dict[str, float | None] = {}
    for i in range(count):
        spool = spools[i % len(spools)]
        kind = i % 4
        if kind == 3:
            name, data = f"g{i:03d}.gcode", tiny_gcode([f"M117 job {i}"], moves=5).encode()
        elif kind == 2:
            name, data = f"broken{i:03d}.stl", broken
        else:
            path = src / f"box{i:03d}.stl"
            write_binary_stl(path, *box((3.0 + (i % 5), 3.0, 2.0)))
            name, data = path.name, path.read_bytes()
        pin = 0.6 if i % 5 in (0, 3) else None
        if i % 5 == 0:  # a sidecar first, then the model
            drop(spool, name.rsplit(".", 1)[0] + ".toml", b"nozzle = 0.6\n")
        elif i % 5 == 3:  # the spool subfolder the user made for the 0.6 printers
            spool = spool / "nozzle-0.6"
        drop(spool, name, data)
        pins[name] = pin
    return pins


def _run_batch(tmp, redis_server, count: int) -> None:
    a, b, c = _nodes(tmp, redis_server)
    nodes = [a, b, c]
    try:
        for node in nodes:
            (node.cfg.spool.path / "nozzle-0.6").mkdir(parents=True)
            node.start()
        pins = _drop_mix(tmp, [a.cfg.spool.path, b.cfg.spool.path, c.cfg.spool.path],
                         count - 2)
        for i in range(2):  # only b04's bed (300 mm) holds these
            path = tmp / "models" / f"long{i}.stl"
            write_binary_stl(path, *box((270.0, 8.0 + i, 1.0)))
            drop(a.cfg.spool.path, path.name, path.read_bytes())
            pins[path.name] = None
        queue = FarmQueue(redis_server.url, "test")
        a.wait_for(lambda: all_ended(queue, count), what=f"{count} farm jobs ended",
                   timeout=900, poll=0.5)
        jobs = check_farm(queue, nodes, count)
        for entry in jobs.values():
            local = entry["local"]
            assert str(local.state) == "done", (local.name, local.reason)
            pin = pins[local.source_name]
            if pin:
                assert entry["printer"].endswith("06"), (local.name, entry["printer"])
                if local.kind == "mesh":
                    assert local.epsilon == pytest.approx(0.6)
                    assert report_epsilon(local) == pytest.approx(0.6)
            if local.source_name.startswith("long"):
                assert entry["printer"] == "b04"
            if local.kind == "mesh":
                nozzle = 0.6 if entry["printer"].endswith("06") else 0.4
                assert local.epsilon == pytest.approx(nozzle)
        # results reused: one repair+slice per (input, ε), however many copies
        inputs = {e["job"]["input"] for e in jobs.values() if e["local"].kind == "mesh"}
        prepared = list((tmp / "artefacts" / "prepared").glob("*.json"))
        meshes = sum(e["local"].kind == "mesh" for e in jobs.values())
        assert len(prepared) <= 2 * len(inputs) < meshes
        printers = {e["printer"] for e in jobs.values()}
        assert {"a04", "a06", "b04", "b06"} <= printers  # the work was shared
        # Nodes post their status with each heartbeat, so the last job's end shows
        # within a heartbeat or two; a printer stuck "preparing" would never go idle.
        idle = "printer a06: nozzle 0.6 mm, connected, idle"
        a.wait_for(lambda: idle in a.cli("farm", "status").stdout,
                   what="a06 idle in farm status", timeout=60, poll=1.0)
        status = a.cli("farm", "status")
        assert status.returncode == 0, status.stderr
        assert f"{count} done" in status.stdout and "node c: up (compute" in status.stdout
        assert idle in status.stdout
        assert "0 waiting for a printer, 0 claimed" in status.stdout
    finally:
        for node in nodes:
            node.stop()


def test_farm_hundred_mixed_jobs_each_end_once_pinned_on_their_nozzle(tmp_path,
                                                                     redis_server):
    _run_batch(tmp_path, redis_server, 100)
