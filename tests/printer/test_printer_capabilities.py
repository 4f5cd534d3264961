"""Capabilities beyond Marlin: Klipper's nozzle and volume from its API socket (a test
double speaking Klipper's documented JSON protocol on a real unix socket) or from
printer.cfg; RepRapFirmware's axis limits from its object model (M409)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading

import pytest
from printer_helpers import FAST, HOST

from printer.host import PrinterHost
from printer.identify import parse_object_model_axes, query_info
from printer.klipper_api import KlipperApiError, from_api, from_config
from printer.virtual import VirtualPrinter

SETTINGS = {
    "printer": {"kinematics": "cartesian", "max_velocity": 300.0, "max_accel": 3000.0},
    "extruder": {"nozzle_diameter": 0.6, "filament_diameter": 1.75, "step_pin": "PB3"},
    "stepper_x": {"position_min": 0.0, "position_endstop": 0.0, "position_max": 235.0},
    "stepper_y": {"position_min": -3.0, "position_endstop": -3.0, "position_max": 230.0},
    "stepper_z": {"position_min": -2.0, "position_endstop": 0.5, "position_max": 250.0},
    "heater_bed": {"max_temp": 120.0},
}


class KlipperApiDouble(threading.Thread):
    """Klipper's API server as documented (docs/API_Server.md): a unix stream socket,
    JSON messages each ended by 0x03; ``objects/query`` answers
    ``{"id", "result": {"eventtime", "status": {object: {field: value}}}}``, an unknown
    method or object an ``{"id", "error": {"error", "message"}}``."""

    def __init__(self, path, settings: dict | None) -> None:
        super().__init__(daemon=True)
        self.path = str(path)
        self.settings = settings
        self.requests: list[dict] = []
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.server.bind(self.path)
        self.server.listen(4)

    def run(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            with conn:
                buf = b""
                while True:
                    data = conn.recv(4096)
                    if not data:
                        break
                    buf += data
                    while b"\x03" in buf:
                        raw, buf = buf.split(b"\x03", 1)
                        conn.sendall(json.dumps(self.answer(json.loads(raw))).encode() + b"\x03")

    def answer(self, request: dict) -> dict:
        self.requests.append(request)
        rid = request.get("id")
        if request.get("method") != "objects/query":
            return {"id": rid, "error": {"error": "WebRequestError",
                                         "message": f"Invalid path {request.get('method')}"}}
        objects = request["params"]["objects"]
        if "configfile" in objects and self.settings is None:
            return {"id": rid, "error": {"error": "WebRequestError",
                                         "message": "Klipper not ready"}}
        status = {}
        for name, wanted in objects.items():
            if name == "configfile":
                fields = {"settings": self.settings, "config": {}, "warnings": []}
                status[name] = {k: v for k, v in fields.items() if not wanted or k in wanted}
        return {"id": rid, "result": {"eventtime": 12345.678, "status": status}}

    def close(self) -> None:
        self.server.close()


@pytest.fixture
def klipper_api():
    """Start API doubles; their sockets live in a short folder (a unix socket path is
    limited to 107 bytes, pytest's tmp_path can be longer)."""
    folder = tempfile.mkdtemp(prefix="klippy")
    servers = []

    def start(settings: dict | None = SETTINGS):
        server = KlipperApiDouble(os.path.join(folder, f"uds{len(servers)}"), settings)
        server.start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.close()
    shutil.rmtree(folder, ignore_errors=True)


def test_klipper_nozzle_and_volume_come_from_its_api_socket(klipper_api):
    api = klipper_api()
    with VirtualPrinter("klipper", nozzle=0.4, **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, nozzle_fallback=0.8, **HOST) as host:
        info = query_info(host, klipper_socket=api.path)
    assert api.requests == [{"id": 1, "method": "objects/query",
                             "params": {"objects": {"configfile": ["settings"]}}}]
    assert info.nozzle_diameter == 0.6  # Klipper's, not the 0.8 fallback
    assert info.nozzle_source == f"Klipper API {api.path}"
    assert info.build_volume == [235.0, 233.0, 252.0]
    assert info.build_volume_source == f"Klipper API {api.path}"


PRINTER_CFG = """\
# printer.cfg of a Klipper machine
[include mainsail.cfg]
[include hardware/*.cfg]

[printer]
kinematics: cartesian
max_velocity: 300

[extruder]
step_pin: PB3
nozzle_diameter: 0.500   ; a 0.5 mm nozzle
filament_diameter: 1.750

#*# <---------------------- SAVE_CONFIG ---------------------->
#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.
#*#
#*# [extruder]
#*# control = pid
"""


def write_printer_cfg(folder):
    (folder / "hardware").mkdir()
    (folder / "mainsail.cfg").write_text("[gcode_macro PAUSE]\ngcode:\n  M25\n")
    (folder / "hardware" / "steppers.cfg").write_text(
        "[stepper_x]\nposition_max: 220\n\n[stepper_y]\nposition_min: -5\nposition_max: 215\n"
        "[stepper_z]\nposition_max: 240 # tall\n")
    path = folder / "printer.cfg"
    path.write_text(PRINTER_CFG)
    return path


def test_klipper_without_its_socket_reads_printer_cfg(tmp_path, klipper_api):
    cfg = write_printer_cfg(tmp_path)
    caps = from_config(cfg)
    assert caps.nozzle_diameter == 0.5
    assert caps.limits == ((0.0, -5.0, 0.0), (220.0, 215.0, 240.0))
    not_ready = klipper_api(settings=None)  # the socket answers, but with an error
    with pytest.raises(KlipperApiError, match="Klipper not ready"):
        from_api(not_ready.path)
    with VirtualPrinter("klipper", **FAST) as vp, \
            PrinterHost(vp.port, vp.baud, **HOST) as host:
        info = query_info(host, klipper_socket=not_ready.path, klipper_config=cfg)
        missing = query_info(host, klipper_socket=tmp_path / "no_socket")
    assert info.nozzle_diameter == 0.5 and info.nozzle_source == f"Klipper config {cfg}"
    assert info.build_volume == [220.0, 220.0, 240.0]
    assert info.build_volume_source == f"Klipper config {cfg}"
    # neither source: the configured/default nozzle and no volume, as before
    assert missing.nozzle_source == "default" and missing.build_volume is None


def test_a_broken_printer_cfg_is_one_line(tmp_path):
    bad = tmp_path / "printer.cfg"
    bad.write_text("nozzle_diameter: 0.4\n[extruder\n")
    with pytest.raises(KlipperApiError) as err:
        from_config(bad)
    assert "is not a Klipper config" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(("text", "limits"), [
    ('{"key":"move.axes","flags":"","result":[{"letter":"X","min":0,"max":235},'
     '{"letter":"Y","min":-5,"max":230.5},{"letter":"Z","min":0,"max":250},'
     '{"letter":"U","min":0,"max":10}]}', ((0.0, -5.0, 0.0), (235.0, 230.5, 250.0))),
    ('{"key":"move.axes","flags":"","result":null}', None),
    ('{"key":"move.axes","flags":"","result":[{"letter":"X","min":0,"max":235}]}', None),
    ("Error: M409: Command is not supported", None),
    ('{"key":"move.axes", truncated', None),
])
def test_rrf_object_model_replies(text, limits):
    assert parse_object_model_axes([text, "ok"]) == limits


def test_rrf_build_volume_from_the_object_model_over_the_cli(tmp_path):
    link = tmp_path / "ttyRRF"
    proc = subprocess.Popen(
        [sys.executable, "-m", "daemon", "virtual-printer", "--firmware", "rrf",
         "--build-volume", "300", "310", "320", "--link", str(link), "--speedup", "1000"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("/dev/")
        out = subprocess.run([sys.executable, "-m", "daemon", "printer", "info", "--port",
                              str(link)], capture_output=True, text=True, timeout=120)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert out.returncode == 0, out.stderr
    assert 'build_volume:      300 x 310 x 320 mm (from M409 K"move.axes")' in out.stdout
    assert "RepRapFirmware" in out.stdout
