"""The slicers' own request sequences, replayed as raw HTTP against the real daemon
(``preflight run``) on 127.0.0.1, each ending in a job printed on the virtual printer
with every line executed exactly once."""

from __future__ import annotations

import base64
import json
import secrets
import time
from pathlib import Path

import pytest
from daemon_helpers import (
    DaemonProc,
    box,
    gcode_commands,
    tiny_gcode,
    write_binary_stl,
)
from web_helpers import (
    curl_boundary,
    executed_once,
    multipart,
    request,
    send_raw,
    upload_head,
)

pytest.importorskip("aiohttp")

OCTET = "application/octet-stream"


def printer_log(d: DaemonProc) -> list[str]:
    path = d.cfg.printer.virtual_log
    return path.read_text().splitlines() if path and path.exists() else []


def wait_state(d: DaemonProc, job_id: int, state: str):
    """The job once it is in ``state``; for a final state, once its files are archived
    too (the daemon records the state first, then moves the files and writes reports)."""
    final = state in ("done", "failed", "cancelled", "interrupted")

    def reached():
        job = d.journal.get(job_id)
        if str(job.state) != state:
            return None
        if final and "report_json" not in (job.outputs or {}):
            return None
        return job

    return d.wait_for(reached, what=f"job {job_id} {state}")


def test_prusaslicer_connection_test_and_upload_and_print(web_daemon):
    d, port, key = web_daemon()
    agent = "PrusaSlicer/2.8.1+linux-x64-GTK3"
    # "Test" in the physical printer dialog: GET /api/version with the key
    ans = send_raw(port, (f"GET /api/version HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                          f"User-Agent: {agent}\r\nAccept: */*\r\nX-Api-Key: {key}\r\n"
                          "Connection: close\r\n\r\n").encode())
    assert ans.status == 200
    version = ans.json()
    assert version["text"].startswith("OctoPrint") and version["api"] == "0.1"
    assert version["server"] == "1.10.0" and "preflight" in version["text"]

    # "Upload and print": fields print, path, then the file (libcurl's mime, Expect: 100)
    data = tiny_gcode(moves=200).encode()
    boundary = curl_boundary()
    body = multipart([("print", b"true", None, None), ("path", b"", None, None),
                      ("file", data, "cube_0.2mm_PLA.gcode", OCTET)], boundary)
    ans = send_raw(port, upload_head(port, "/api/files/local", boundary, len(body), key,
                                     agent=agent), body, wait_continue=True)
    assert ans.status == 201, ans.body
    assert ans.continued  # the body was sent only after 100 Continue
    # journalled before the answer: the job is there the moment the 201 arrives
    reply = ans.json()
    job_id = reply["preflight"]["job"]
    job = d.journal.get(job_id)
    assert job is not None and job.print_requested and job.source_name == "cube_0.2mm_PLA.gcode"
    assert ans.headers["location"] == f"http://127.0.0.1:{port}/api/files/local/" \
                                      "cube_0.2mm_PLA.gcode"
    local = reply["files"]["local"]
    assert reply["done"] is True and reply["effectivePrint"] is True
    assert reply["effectiveSelect"] is True
    assert (local["name"], local["path"], local["origin"]) == ("cube_0.2mm_PLA.gcode",) * 2 + (
        "local",)
    assert local["refs"]["resource"] == ans.headers["location"]
    assert local["refs"]["download"].endswith("/cube_0.2mm_PLA.gcode")

    done = wait_state(d, job_id, "done")
    cmds = gcode_commands(Path(done.outputs["input"]))
    assert Path(done.outputs["input"]).read_bytes() == data
    executed_once(printer_log(d), cmds)
    assert done.print_result["acked_lines"] == len(cmds)
    # nothing of the upload is left in the spool
    assert sorted(p.name for p in d.cfg.spool.path.iterdir()) == [".preflight", "done", "failed"]


@pytest.mark.slow
def test_orcaslicer_moonraker_upload_of_a_mesh_is_repaired_sliced_and_printed(web_daemon,
                                                                               tmp_path):
    d, port, key = web_daemon()
    agent = "OrcaSlicer/2.1.1"
    info = send_raw(port, (f"GET /server/info HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                           f"User-Agent: {agent}\r\nAccept: */*\r\nConnection: close\r\n\r\n"
                           ).encode())
    assert info.status == 200
    result = info.json()["result"]
    assert result["klippy_state"] == "ready" and result["moonraker_version"]

    v, f = box((12.0, 10.0, 4.0))
    stl = tmp_path / "bracket.stl"
    write_binary_stl(stl, v, f)
    boundary = curl_boundary()
    body = multipart([("root", b"gcodes", None, None), ("path", b"", None, None),
                      ("print", b"true", None, None),
                      ("file", stl.read_bytes(), "bracket.stl", OCTET)], boundary)
    ans = send_raw(port, upload_head(port, "/server/files/upload", boundary, len(body), key,
                                     agent=agent), body, wait_continue=True)
    assert ans.status == 201, ans.body
    res = ans.json()["result"]
    assert res["item"] == {"path": "bracket.stl", "root": "gcodes"}
    assert res["action"] == "create_file" and res["print_started"] is True
    assert res["print_queued"] is False
    job_id = res["preflight"]["job"]
    assert d.journal.get(job_id).kind == "mesh"

    # idempotent start while it is being processed or printed
    for _ in range(2):
        again = request(port, "POST", "/printer/print/start?filename=bracket.stl",
                        headers={"X-Api-Key": key})
        assert again.status == 200 and again.json() == {"result": "ok"}

    done = wait_state(d, job_id, "done")
    assert done.repair_report and done.slice_summary
    cmds = gcode_commands(Path(done.outputs["gcode"]))
    assert len(cmds) > 50
    executed_once(printer_log(d), cmds)


def qt_multipart(parts: list[tuple[str, bytes, str | None]], boundary: str) -> bytes:
    """Qt's QHttpMultiPart as Cura's OctoPrint plugin fills it (no per-part type on fields)."""
    return multipart([(n, data, fn, OCTET if fn else None) for n, data, fn in parts], boundary)


def test_cura_octoprint_plugin_connect_poll_upload_select_print(web_daemon):
    d, port, key = web_daemon(speedup=20)  # slow enough to poll progress mid-print
    headers = {"X-Api-Key": key, "User-Agent": "Cura/5.7.1 (OctoPrintPlugin)"}
    # the plugin polls /api/printer; OctoPrint answers 409 until the printer is connected
    d.wait_for(lambda: request(port, "GET", "/api/printer", headers=headers).status == 200,
               what="the printer operational over the API")
    for path in ("/api/version", "/api/settings", "/api/printerprofiles", "/api/printer",
                 "/api/job"):
        ans = request(port, "GET", path, headers=headers)
        assert ans.status == 200, (path, ans.body)
    assert request(port, "GET", "/api/settings", headers=headers).json()["feature"][
        "sdSupport"] is False
    profiles = request(port, "GET", "/api/printerprofiles", headers=headers).json()["profiles"]
    assert profiles["_default"]["volume"]["width"] == 250
    flags = request(port, "GET", "/api/printer", headers=headers).json()["state"]["flags"]
    assert flags["operational"] and flags["ready"] and not flags["printing"]
    assert set(flags) >= {"paused", "pausing", "cancelling", "error", "closedOrError"}
    login = request(port, "POST", "/api/login", headers={**headers, "Content-Type":
                    "application/json"}, body=b'{"passive": true}')
    assert login.status == 200

    # upload: select, no print (Qt quotes the boundary), then select+print by command
    data = tiny_gcode(moves=600).encode()
    boundary = "boundary_.oOo._" + base64.b64encode(secrets.token_bytes(24)).decode()
    body = qt_multipart([("select", b"true", None), ("print", b"false", None),
                         ("file", data, "CFFFP_cura part.gcode")], boundary)
    head = upload_head(port, "/api/files/local", boundary, len(body), key, expect=False,
                       quote_boundary=True, agent=headers["User-Agent"])
    ans = send_raw(port, head, body)
    assert ans.status == 201, ans.body
    assert ans.json()["effectivePrint"] is False and ans.json()["effectiveSelect"] is True
    location = ans.headers["location"].split("api/", 1)[1]  # what the plugin does
    assert location == "files/local/CFFFP_cura%20part.gcode"
    job_id = ans.json()["preflight"]["job"]
    wait_state(d, job_id, "ready")
    time.sleep(1.0)  # print=false: it must stay ready
    assert str(d.journal.get(job_id).state) == "ready"

    ans = request(port, "POST", "/api/" + location, headers={
        **headers, "Content-Type": "application/json"},
        body=json.dumps({"command": "select", "print": True}).encode())
    assert ans.status == 204, ans.body

    seen_progress = []

    def polled_done():
        job = request(port, "GET", "/api/job", headers=headers).json()
        if job["state"] == "Printing":
            assert job["job"]["file"]["name"] == "CFFFP_cura part.gcode"
            seen_progress.append(job["progress"]["completion"])
            assert job["progress"]["printTime"] is not None
        return job["preflight"]["state"] == "done"

    d.wait_for(polled_done, what="done, polled as Cura does", poll=0.2)
    assert any(p is not None and 0 <= p <= 100 for p in seen_progress), seen_progress
    done = d.journal.get(job_id)
    executed_once(printer_log(d), gcode_commands(Path(done.outputs["input"])))
