"""The status page's server side, over raw HTTP against the real daemon on 127.0.0.1:
the public page, the keyed JSON/binary/event-stream endpoints, and job actions going
through the daemon's request path."""

from __future__ import annotations

import gzip
import json
import socket
import struct
from pathlib import Path

import numpy as np
import pytest
from daemon_helpers import broken_stl, drop
from web_helpers import request

from repair.changes import LABELS
from repair.io import load_mesh

pytest.importorskip("aiohttp")


def get(port, path, key=None):
    return request(port, "GET", path, headers={"X-Api-Key": key} if key else None)


def post(port, path, key):
    return request(port, "POST", path, headers={"X-Api-Key": key})


def parse_mesh(body: bytes):
    assert body[:4] == b"PFM1"
    n = struct.unpack("<I", body[4:8])[0]
    tris = np.frombuffer(body, "<f4", n * 9, 8).reshape(n, 3, 3)
    labels = np.frombuffer(body, np.uint8, n, 8 + 36 * n)
    counts = json.loads(body[8 + 37 * n:])
    return tris, labels, counts


class EventStream:
    """``GET /api/preflight/events`` on a raw socket, read event by event."""

    def __init__(self, port: int, key: str) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=60)
        self.sock.sendall(f"GET /api/preflight/events?apikey={key} HTTP/1.1\r\n"
                          f"Host: 127.0.0.1:{port}\r\nAccept: text/event-stream\r\n\r\n".encode())
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            self.buf += self.sock.recv(65536)
        head, _, self.buf = self.buf.partition(b"\r\n\r\n")
        self.head = head.decode("latin-1").lower()

    def next_state(self) -> dict:
        """The next ``state`` event's data (chunked transfer framing is skipped over)."""
        while True:
            text = self.buf.decode("utf-8", "replace")
            for block in text.split("\n\n")[:-1]:
                if "event: state" in block:
                    data = block.split("data: ", 1)[1].split("\r\n", 1)[0]
                    self.buf = text.split(block, 1)[1].encode()
                    return json.loads(data)
            chunk = self.sock.recv(65536)
            assert chunk, "the event stream closed"
            self.buf += chunk

    def close(self) -> None:
        self.sock.close()


def test_the_page_is_public_and_its_data_needs_the_key(web_daemon):
    d, port, key = web_daemon()
    page = get(port, "/")
    assert page.status == 200 and page.headers["content-type"].startswith("text/html")
    assert b"/static/app.js" in page.body
    for asset in ("/static/app.js", "/static/style.css", "/static/vendor/three/three.module.js",
                  "/static/vendor/three/addons/OrbitControls.js"):
        ans = get(port, asset)
        assert ans.status == 200, asset
        assert len(ans.body) > 1000
    assert get(port, "/static/../auth.py").status in (403, 404)
    # three.js goes gzipped to a browser that takes it; the .gz holds exactly the file
    for name in ("three.module.js", "three.core.js"):
        path = f"/static/vendor/three/{name}"
        plain = get(port, path).body
        packed = request(port, "GET", path, headers={"Accept-Encoding": "gzip, deflate"})
        assert packed.headers.get("content-encoding") == "gzip"
        assert gzip.decompress(packed.body) == plain and len(packed.body) < len(plain) / 3
    for path in ("/api/preflight/state", "/api/preflight/events", "/api/preflight/jobs/1",
                 "/api/preflight/jobs/1/mesh/input", "/api/preflight/jobs/1/layers"):
        assert get(port, path).status == 401, path
        assert get(port, path, "wrong-key").status == 401, path
    assert post(port, "/api/preflight/jobs/1/cancel", "wrong-key").status == 401
    state = get(port, "/api/preflight/state", key).json()
    assert state["printer"]["state"] == "connected"
    assert state["printer"]["build_volume"] and state["printer"]["firmware"]
    assert state["queue"] == [] and state["history"] == []
    # a loopback-only server does not advertise itself over mDNS
    assert d.status()["web"]["mdns"] is None

    # an open event stream ends when the daemon stops (it does not hold the stop up),
    # and the key it carries in its URL is not written to the log
    events = EventStream(port, key)
    events.next_state()
    assert d.stop() == 0
    events.sock.settimeout(30)
    with pytest.raises(AssertionError, match="closed"):
        while True:
            events.next_state()
    events.close()
    log = d.log.read_text()
    assert "/api/preflight/events" in log and key not in log


def test_a_job_report_its_pictures_and_actions(web_daemon, tmp_path):
    d, port, key = web_daemon(auto_print=False)
    events = EventStream(port, key)
    try:
        assert "text/event-stream" in events.head
        first = events.next_state()
        assert first["queue"] == []
        drop(d.cfg.spool.path, "cube.stl", broken_stl(tmp_path / "cube.stl").read_bytes())
        seen = set()
        while "ready" not in seen:  # the stream follows the job through its states
            state = events.next_state()
            seen |= {j["state"] for j in state["queue"] if j["name"] == "cube.stl"}
        assert "ready" in seen
    finally:
        events.close()
    job = d.jobs()[0]
    detail = get(port, f"/api/preflight/jobs/{job.id}", key).json()
    assert detail["views"] == {"mesh": True, "layers": True}
    assert "intersecting pairs resolved" in detail["text"]
    assert detail["repair_report"]["after"]["triangles"] > 0

    # the meshes: the very triangles of the input and the repaired STL, labelled
    tris_in, labels_in, counts_in = parse_mesh(
        get(port, f"/api/preflight/jobs/{job.id}/mesh/input", key).body)
    tris_out, labels_out, counts_out = parse_mesh(
        get(port, f"/api/preflight/jobs/{job.id}/mesh/repaired", key).body)
    src, rep = load_mesh(job.input_path), load_mesh(job.repaired_path)
    assert np.allclose(tris_in, src.vertices[src.faces], atol=1e-6)
    assert np.allclose(tris_out, rep.vertices[rep.faces], atol=1e-6)
    assert labels_in.max() < len(LABELS) and labels_out.max() < len(LABELS)
    assert counts_in.get("dropped", 0) >= 1 and counts_out["kept"] > 0
    assert sum(counts_out.values()) == len(labels_out)
    assert get(port, f"/api/preflight/jobs/{job.id}/mesh/other", key).status == 404
    assert get(port, "/api/preflight/jobs/999/mesh/input", key).status == 404

    # the layers: as many as the slicer made, each a list of typed polylines
    layers = get(port, f"/api/preflight/jobs/{job.id}/layers?from=0&count=5", key).json()
    assert layers["count"] == detail["slice_summary"]["layers"]
    assert layers["z"] == sorted(layers["z"])
    assert len(layers["layers"]) == 5
    for layer in layers["layers"]:
        assert layer["paths"]
        for path in layer["paths"]:
            assert path[0] < len(layers["types"]) and len(path) >= 5 and len(path) % 2 == 1
    x0, y0, x1, y1 = layers["bounds"]
    assert 0 <= x0 < x1 <= 250 and 0 <= y0 < y1 <= 210

    # actions: the daemon's own answers
    ans = post(port, f"/api/preflight/jobs/{job.id}/requeue", key)
    assert ans.status == 409 and "only failed, cancelled or interrupted" in ans.json()["message"]
    assert post(port, f"/api/preflight/jobs/{job.id}/explode", key).status == 404
    ans = post(port, f"/api/preflight/jobs/{job.id}/print", key)
    assert ans.status == 200 and ans.json()["ok"], ans.body
    d.wait_for(lambda: str(d.journal.get(job.id).state) == "done", what="the job printed")
    history = get(port, "/api/preflight/state", key).json()["history"]
    assert [j["state"] for j in history if j["id"] == job.id] == ["done"]
    # archived: the pictures still come from done/
    assert get(port, f"/api/preflight/jobs/{job.id}/mesh/repaired", key).status == 200
    assert Path(d.journal.get(job.id).outputs["repaired"]).is_file()
