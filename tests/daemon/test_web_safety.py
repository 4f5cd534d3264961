"""What the web API refuses, over real sockets against the real daemon: bad keys,
traversal, over-size and conflicting uploads, binary G-code, hostile bytes; and an
upload answered 201 survives a kill -9."""

from __future__ import annotations

import json
import os
import shutil
import socket
from pathlib import Path

import pytest
from daemon_helpers import DaemonProc, gcode_commands, tiny_gcode, write_config
from web_helpers import (
    curl_boundary,
    executed_once,
    multipart,
    outside_files,
    request,
    send_raw,
    start_web_daemon,
    upload_head,
)

from daemon.web.auth import key_path

pytest.importorskip("aiohttp")

OCTET = "application/octet-stream"

GUARDED = [("GET", "/api/settings"), ("GET", "/api/printer"), ("GET", "/api/job"),
           ("GET", "/api/printerprofiles"), ("POST", "/api/login"), ("POST", "/api/job"),
           ("POST", "/api/files/local"), ("POST", "/api/files/local/a.gcode"),
           ("GET", "/api/files/local/a.gcode"), ("POST", "/server/files/upload"),
           ("POST", "/printer/print/start"), ("GET", "/printer/info"),
           ("POST", "/api/printer/command"), ("POST", "/printer/print/pause"),
           ("POST", "/printer/print/resume"), ("POST", "/printer/print/cancel"),
           ("GET", "/no/such/endpoint"), ("POST", "/api/version"), ("POST", "/"),
           # the status page's data and actions (the page itself, "/", is public)
           ("GET", "/api/preflight/state"), ("GET", "/api/preflight/events"),
           ("GET", "/api/preflight/jobs/1"), ("GET", "/api/preflight/jobs/1/mesh/input"),
           ("GET", "/api/preflight/jobs/1/layers"), ("POST", "/api/preflight/jobs/1/cancel"),
           ("GET", "/static")]


def upload(port: int, key: str | None, name: str, data: bytes, *, path: str = "",
           print_: bool = True, expect: bool = True):
    boundary = curl_boundary()
    body = multipart([("print", b"true" if print_ else b"false", None, None),
                      ("path", path.encode("utf-8", "surrogateescape"), None, None),
                      ("file", data, name, OCTET)], boundary)
    head = upload_head(port, "/api/files/local", boundary, len(body), key, expect=expect)
    return send_raw(port, head, body, wait_continue=expect)


def spool_names(d: DaemonProc) -> list[str]:
    return sorted(p.name for p in d.cfg.spool.path.iterdir())


def test_key_is_made_once_with_mode_0600_and_printed_by_the_cli(web_daemon):
    d, port, key = web_daemon()
    path = key_path(d.cfg.daemon.state_dir)
    assert oct(os.stat(path).st_mode & 0o777) == "0o600"
    assert len(key) >= 32
    out = d.cli("api-key")
    assert out.returncode == 0 and out.stdout.strip() == key
    status = d.cli("status")
    assert key in status.stdout and f"127.0.0.1:{port}" in status.stdout
    assert json.loads(d.cli("status", "--json").stdout)["api_key"] == key
    d.stop()
    d.start()  # the same key after a restart
    assert key_path(d.cfg.daemon.state_dir).read_text().strip() == key


def test_bad_key_is_401_on_every_endpoint_and_host_does_not_matter(web_daemon):
    d, port, key = web_daemon()
    bad = [{}, {"X-Api-Key": "wrong"}, {"X-Api-Key": key + "x"}, {"X-Api-Key": key[:-1]},
           {"Authorization": "Bearer "}, {"Authorization": f"Basic {key}"},
           {"Authorization": "Bearer nope"}]
    for method, path in GUARDED:
        for headers in bad:
            for host in (None, "localhost", "127.0.0.1"):
                ans = request(port, method, path, headers=headers, host=host)
                assert ans.status == 401, (method, path, headers, host, ans.body)
        ans = request(port, method, path + ("&" if "?" in path else "?") + "apikey=wrong")
        assert ans.status == 401, (method, path)
    # the key in any of its three places, whatever the Host header says
    for headers, query in (({"X-Api-Key": key}, ""), ({"Authorization": f"Bearer {key}"}, ""),
                           ({}, f"?apikey={key}")):
        for host in ("evil.example", "192.168.1.50:8080", "[::1]"):
            ans = request(port, "GET", "/api/settings" + query, headers=headers, host=host)
            assert ans.status == 200, (headers, host, ans.body)
    # HTTP/1.0 without any Host header
    ans = send_raw(port, f"GET /api/job HTTP/1.0\r\nX-Api-Key: {key}\r\n\r\n".encode())
    assert ans.status == 200
    # the two connection-test endpoints are open
    assert request(port, "GET", "/api/version").status == 200
    assert request(port, "GET", "/server/info").status == 200
    # and the status page with its static files: they hold no data (it reads with the key)
    assert request(port, "GET", "/").status == 200
    assert request(port, "GET", "/static/app.js").status == 200
    # a refused upload with Expect: 100-continue never gets to send its body
    ans = upload(port, "wrong", "a.gcode", tiny_gcode().encode())
    assert ans.status == 401 and not ans.continued
    assert d.jobs() == [] and spool_names(d) == [".preflight", "done", "failed"]


TRAVERSAL_NAMES = ["../evil.gcode", "..\\evil.gcode", "/tmp/evil.gcode", "sub/evil.gcode",
                   "..", "evil\x01.gcode", "e" * 300 + ".gcode"]
TRAVERSAL_PATHS = ["../", "../../etc", "/etc", "a/../../b", "..\\..", "C:\\Windows",
                   "x\x00y", "ok/" + "f" * 300]


def test_traversal_in_the_name_or_the_path_is_400_and_nothing_is_written_outside(
        web_daemon, tmp_path):
    d, port, key = web_daemon()
    before = outside_files(tmp_path, d.cfg.spool.path, d.cfg.daemon.state_dir)
    data = tiny_gcode().encode()
    for name in TRAVERSAL_NAMES:
        ans = upload(port, key, name, data)
        assert ans.status == 400, (name, ans.body)
        assert ans.json()["error"].startswith("refused")
    for folder in TRAVERSAL_PATHS:
        ans = upload(port, key, "fine.gcode", data, path=folder)
        assert ans.status == 400, (folder, ans.body)
    # a NUL byte in the file name itself, written raw
    boundary = curl_boundary()
    body = multipart([("file", data, "a\x00/../../b.gcode", OCTET)], boundary)
    ans = send_raw(port, upload_head(port, "/api/files/local", boundary, len(body), key,
                                     expect=False), body)
    assert ans.status == 400
    assert outside_files(tmp_path, d.cfg.spool.path, d.cfg.daemon.state_dir) == before
    assert not (tmp_path.parent / "evil.gcode").exists()
    assert d.jobs() == [] and spool_names(d) == [".preflight", "done", "failed"]
    # an ordinary folder is accepted (the spool is flat: only the name is kept)
    ans = upload(port, key, "fine.gcode", data, path="prints/today", print_=False)
    assert ans.status == 201 and ans.json()["files"]["local"]["name"] == "fine.gcode"


def test_over_size_is_413_declared_or_counted(web_daemon):
    d, port, key = web_daemon(web={"max_upload_mb": 0.05})
    big = tiny_gcode(moves=20000).encode()
    assert len(big) > 4 * 0.05 * 1048576
    ans = upload(port, key, "big.gcode", big)  # Content-Length known: refused before the body
    assert ans.status == 413 and not ans.continued
    assert "max_upload_mb" in ans.json()["error"]
    # chunked, no Content-Length: counted while streaming
    boundary = curl_boundary()
    body = multipart([("print", b"true", None, None), ("file", big, "big.gcode", OCTET)],
                     boundary)
    pieces = [body[i:i + 8192] for i in range(0, len(body), 8192)]
    chunks = [f"{len(p):x}\r\n".encode() + p + b"\r\n" for p in pieces] + [b"0\r\n\r\n"]
    ans = send_raw(port, upload_head(port, "/api/files/local", boundary, None, key,
                                     expect=False), chunks=chunks)
    assert ans.status == 413, ans.body
    assert d.jobs() == [] and spool_names(d) == [".preflight", "done", "failed"]
    small = tiny_gcode(moves=10).encode()
    assert upload(port, key, "small.gcode", small).status == 201


def test_second_upload_over_the_printing_file_is_409_then_pause_resume_cancel(web_daemon):
    d, port, key = web_daemon(speedup=20)
    ans = upload(port, key, "long.gcode", tiny_gcode(moves=3000).encode())
    assert ans.status == 201
    job_id = ans.json()["preflight"]["job"]
    d.wait_for(lambda: str(d.journal.get(job_id).state) == "printing", what="printing")
    again = upload(port, key, "long.gcode", tiny_gcode(moves=5).encode())
    assert again.status == 409 and "printing now" in again.json()["error"]
    assert len(d.jobs()) == 1
    headers = {"X-Api-Key": key, "Content-Type": "application/json"}
    flags = request(port, "GET", "/api/printer", headers=headers).json()["state"]["flags"]
    assert flags["printing"] and not flags["ready"]
    # OctoPrint's pause command: toggle when no action is given, then an explicit resume
    pause = request(port, "POST", "/api/job", headers=headers, body=b'{"command": "pause"}')
    assert pause.status == 204, pause.body
    d.wait_for(lambda: str(d.journal.get(job_id).state) == "paused", what="paused")
    flags = request(port, "GET", "/api/printer", headers=headers).json()["state"]["flags"]
    assert flags["paused"] and not flags["printing"] and not flags["ready"]
    resume = request(port, "POST", "/api/job", headers=headers,
                     body=b'{"command": "pause", "action": "resume"}')
    assert resume.status == 204, resume.body
    d.wait_for(lambda: str(d.journal.get(job_id).state) == "printing", what="printing again")
    cancel = request(port, "POST", "/api/job", headers=headers, body=b'{"command": "cancel"}')
    assert cancel.status == 204, cancel.body
    d.wait_for(lambda: str(d.journal.get(job_id).state) == "cancelled", what="cancelled")
    assert "cancelled by user" in d.journal.get(job_id).reason


def test_binary_gcode_and_other_types_are_refused_with_a_reason(web_daemon):
    d, port, key = web_daemon()
    ans = upload(port, key, "part.bgcode", b"GCDE\x01\x00\x00\x00" + os.urandom(64))
    assert ans.status == 415 and "turn off binary G-code" in ans.json()["error"]
    ans = upload(port, key, "notes.txt", b"hello")
    assert ans.status == 415 and "not a model or G-code" in ans.json()["error"]
    ans = upload(port, key, "empty.gcode", b"")
    assert ans.status == 400 and "empty" in ans.json()["error"]
    assert [str(j.state) for j in d.jobs()] == ["failed"]  # the empty file, like a spool drop


def test_hostile_requests_never_take_the_daemon_down(web_daemon):
    d, port, key = web_daemon()
    for raw in (b"\x00\xff\xfe garbage\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n",
                b"POST /api/files/local HTTP/1.1\r\nContent-Length: -5\r\n\r\n",
                b"GET /" + b"a" * 70000 + b" HTTP/1.1\r\n\r\n"):
        with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
            s.sendall(raw)
            s.recv(65536)
    # a body cut off half-way: the partial file is removed
    boundary = curl_boundary()
    body = multipart([("file", tiny_gcode(moves=3000).encode(), "cut.gcode", OCTET)], boundary)
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(upload_head(port, "/api/files/local", boundary, len(body), key, expect=False))
        s.sendall(body[:len(body) // 2])
    # not multipart, not JSON, wrong JSON types
    headers = {"X-Api-Key": key, "Content-Type": "application/json"}
    for path, body in (("/api/files/local", b"{}"), ("/api/job", b"[1, 2]"),
                       ("/api/job", b"\xff\xfe"), ("/server/files/upload", b"x")):
        assert request(port, "POST", path, headers=headers, body=body).status in (400, 409)
    # found by tests/fuzz/test_fuzz_web.py: a body ending inside a part was a 500, not a 400
    cut = b"--XyZ\n!:\nContent-Transfer-Encoding:base64\n\n/////////////////////////"
    ans = send_raw(port, upload_head(port, "/api/files/local", "XyZ", len(cut), key,
                                     expect=False), cut)
    assert ans.status == 400 and "malformed" in ans.json()["error"], ans.body
    # endless or oversized form fields
    for parts, words in (([(f"f{i}", b"x", None, None) for i in range(100)], "form fields"),
                         ([("path", b"a" * 5000, None, None)], "longer than")):
        boundary = curl_boundary()
        body = multipart(parts, boundary)
        ans = send_raw(port, upload_head(port, "/api/files/local", boundary, len(body), key,
                                         expect=False), body)
        assert ans.status == 400 and words in ans.json()["error"], ans.body
    d.wait_for(lambda: not any(p.name.startswith(".upload-")
                               for p in d.cfg.spool.path.iterdir()), what="temp file removed")
    assert request(port, "GET", "/api/version").status == 200
    assert d.alive() and d.jobs() == []


def test_kill9_right_after_the_201_keeps_the_job(web_daemon):
    d, port, key = web_daemon()
    data = tiny_gcode(moves=100).encode()
    ans = upload(port, key, "keep.gcode", data, print_=False)
    assert ans.status == 201
    d.kill9()  # immediately: no time for repair, checks or printing
    job_id = ans.json()["preflight"]["job"]
    d2 = DaemonProc(d.cfg_path)
    port2, key2 = start_web_daemon(d2)
    try:
        assert key2 == key
        job = d2.journal.get(job_id)
        assert job is not None and job.source_name == "keep.gcode"
        assert Path(job.input_path).read_bytes() == data
        d2.wait_for(lambda: str(d2.journal.get(job_id).state) == "ready", what="ready")
        assert not d2.journal.get(job_id).print_requested  # print=false survived the kill
        ans = request(port2, "POST", "/api/files/local/keep.gcode", headers={
            "X-Api-Key": key, "Content-Type": "application/json"},
            body=b'{"command": "select", "print": true}')
        assert ans.status == 204, ans.body
        done = d2.wait_for(lambda: str(d2.journal.get(job_id).state) == "done"
                           and d2.journal.get(job_id), what="printed after the restart")
        log = d.cfg.printer.virtual_log.read_text().splitlines()
        executed_once(log, gcode_commands(Path(done.outputs["input"])))
    finally:
        d2.stop()


def test_an_upload_the_disk_cannot_hold_is_507_before_its_body(tmp_path):
    cfg_path = write_config(tmp_path, web={"max_upload_mb": 10000000})
    text = cfg_path.read_text().replace("slice_timeout = 120",
                                        "slice_timeout = 120\nmax_file_mb = 1000000")
    cfg_path.write_text(text)
    d = DaemonProc(cfg_path)
    port, key = start_web_daemon(d)
    try:
        declared = 500 * 10**9  # 500 GB: under both limits, over this disk's free space
        if shutil.disk_usage(d.cfg.spool.path).free >= declared:
            pytest.skip("the test disk has more than 500 GB free")
        boundary = curl_boundary()
        ans = send_raw(port, upload_head(port, "/api/files/local", boundary, declared, key),
                       b"", wait_continue=True)
        assert ans.status == 507 and not ans.continued
        assert "free" in ans.json()["error"]
        assert d.alive() and d.jobs() == []
    finally:
        d.stop()


def test_moonraker_upload_outside_the_gcodes_root_is_400(web_daemon):
    d, port, key = web_daemon()
    boundary = curl_boundary()
    body = multipart([("root", b"config", None, None),
                      ("file", tiny_gcode().encode(), "printer.cfg.gcode", OCTET)], boundary)
    ans = send_raw(port, upload_head(port, "/server/files/upload", boundary, len(body), key),
                   body, wait_continue=True)
    assert ans.status == 400 and "gcodes" in ans.json()["error"]
    assert d.jobs() == [] and spool_names(d) == [".preflight", "done", "failed"]
