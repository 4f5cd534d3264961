"""Uploads through a farm node's HTTP API (OctoPrint-style ``/api/files/local``) go to
the farm's queue exactly as spool files do when they are to print; a real redis-server
and real daemons (which also check that a node warns of a broker without appendonly)."""

from __future__ import annotations

import json

import redis
from daemon_helpers import DaemonProc, box, tiny_gcode, write_binary_stl
from farm_checks import all_ended, check_farm
from farm_helpers import farm_config, free_port
from web_helpers import curl_boundary, multipart, request, send_raw, upload_head

from daemon.farm.queue import FarmQueue
from daemon.web.auth import read_key

OCTET = "application/octet-stream"


def _web(node: DaemonProc) -> tuple[int, str]:
    web = node.wait_for(lambda: (node.status().get("web") or {}).get("port")
                        and node.status()["web"], what="the web server")
    key = read_key(node.cfg.daemon.state_dir)
    assert key
    return int(web["port"]), key


def _upload(port: int, key: str, name: str, data: bytes, *, print_: bool):
    boundary = curl_boundary()
    body = multipart([("print", b"true" if print_ else b"false", None, None),
                      ("path", b"", None, None), ("file", data, name, OCTET)], boundary)
    return send_raw(port, upload_head(port, "/api/files/local", boundary, len(body), key),
                    body, wait_continue=True)


def test_upload_to_a_compute_only_node_prints_once_on_another_node(tmp_path, redis_server):
    art = tmp_path / "artefacts"
    # a: no printer, repairs and slices, takes uploads; b: one printer, computes nothing
    a = DaemonProc(farm_config(tmp_path / "a", node="a", broker=redis_server.url,
                               artefacts=art, printers=None, compute=True,
                               listen=f"127.0.0.1:{free_port()}"))
    b = DaemonProc(farm_config(tmp_path / "b", node="b", broker=redis_server.url,
                               artefacts=art, printers=[{"name": "b04", "nozzle": 0.4}],
                               compute=False, listen=f"127.0.0.1:{free_port()}"))
    queue = FarmQueue(redis_server.url, "test")
    model = tmp_path / "cube.stl"
    write_binary_stl(model, *box((6.0, 4.0, 3.0)))
    try:
        a.start()
        a.wait_for(lambda: (a.status().get("farm") or {}).get("broker_up"),
                   what="node a reached the broker")
        # b joins a broker that would lose the queue on a restart: it says so, once
        redis.Redis.from_url(redis_server.url).config_set("appendonly", "no")
        b.start()
        port_a, key_a = _web(a)
        port_b, key_b = _web(b)
        ans = _upload(port_a, key_a, "up cube.stl", model.read_bytes(), print_=True)
        assert ans.status == 201, ans.body
        answer = ans.json()["preflight"]
        assert answer["farm"] == "test" and answer["farm_job"]
        assert "job" not in answer  # no job of node a: the farm's queue has it
        a.wait_for(lambda: all_ended(queue, 1), what="the uploaded job ended", timeout=300)
        jobs = check_farm(queue, [a, b], 1)  # ended once, in one journal, printed once
        (fid, entry), = jobs.items()
        assert fid == answer["farm_job"] and entry["job"]["origin"] == "a"
        assert entry["node"] is b and entry["printer"] == "b04"
        local = entry["local"]
        assert str(local.state) == "done" and local.source_name == "up cube.stl"
        assert local.kind == "mesh" and local.outputs.get("gcode")
        assert a.jobs() == [] and list(a.cfg.spool.path.glob("*.stl")) == []

        # not to print now: a compute-only node has no printer to keep it for
        ans = _upload(port_a, key_a, "later.gcode", tiny_gcode(moves=5).encode(), print_=False)
        assert ans.status == 409, ans.body
        error = ans.json()["error"]
        assert "compute-only node of farm 'test'" in error and "\n" not in error
        assert sorted(p.name for p in a.cfg.spool.path.iterdir() if p.is_file()) == []
        # a node with printers keeps it as its own job, waiting for the user's "print"
        ans = _upload(port_b, key_b, "later.gcode", tiny_gcode(moves=5).encode(), print_=False)
        assert ans.status == 201, ans.body
        job_id = ans.json()["preflight"]["job"]
        b.wait_for(lambda: str(b.journal.get(job_id).state) == "ready", what="ready")
        assert not b.journal.get(job_id).print_requested
        assert len(queue.all_jobs()) == 1  # nothing more reached the farm

        state = request(port_a, "GET", "/api/preflight/state",
                        headers={"X-Api-Key": key_a}).json()
        assert state["printer"]["state"] == "none" and state["printers"] == []
        assert "compute-only node of farm 'test'" in state["printer"]["message"]
        status = a.cli("status")
        assert status.returncode == 0, status.stderr
        assert "compute-only node of farm 'test'" in status.stdout
        assert "printer" not in status.stdout.replace("(no printer)", "")
        assert json.loads(a.cli("status", "--json").stdout)["printer"] is None
        warning = "runs with appendonly no"
        assert warning not in a.log.read_text() and b.log.read_text().count(warning) == 1
    finally:
        a.stop()
        b.stop()
