"""Helpers for the end-to-end tests: real daemon processes, real files, real ptys."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import tomli_w

from daemon.config import load_config
from daemon.journal import Journal

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "daemon" / "data"

# Small, fast prints: few layers, no infill, a fast virtual printer.
FAST_PROFILE = {"layer_height": 0.3, "first_layer_height": 0.3, "perimeters": 1,
                "top_layers": 1, "bottom_layers": 1, "infill_percent": 0, "skirts": 0}


def write_config(tmp: Path, *, port: str = "virtual", limits: dict | None = None,
                 profile: bool = True, speedup: float = 2000.0, auto_print: bool = True,
                 virtual_log: Path | None = None, web: dict | None = None) -> Path:
    """A config for a test daemon in ``tmp``; ``limits`` overrides the [limits] keys,
    ``web`` the [web] keys. The web API listens on a free loopback port (never 0.0.0.0)."""
    printer = {"port": port, "baud": 250000, "virtual_speedup": speedup,
               "reconnect_min_seconds": 0.2, "reconnect_max_seconds": 1.0}
    if virtual_log:
        printer["virtual_log"] = str(virtual_log)
    config = {
        "spool": {"path": str(tmp / "spool"), "settle_seconds": 1.0, "close_grace_seconds": 0.2},
        "printer": printer,
        "daemon": {"state_dir": str(tmp / "state"), "auto_print": auto_print,
                   "log_level": "DEBUG"},
        "limits": {"repair_timeout": 120, "slice_timeout": 120, **(limits or {})},
        "web": {"listen": "127.0.0.1:0", **(web or {})},
    }
    if profile:
        config["profile"] = FAST_PROFILE
    p = tmp / "preflight.toml"
    p.write_text(tomli_w.dumps(config))
    return p


# --- models -----------------------------------------------------------------------------

def box(size=(5.0, 5.0, 5.0)) -> tuple[np.ndarray, np.ndarray]:
    x, y, z = size
    v = np.array([[0, 0, 0], [x, 0, 0], [x, y, 0], [0, y, 0],
                  [0, 0, z], [x, 0, z], [x, y, z], [0, y, z]], dtype=np.float64)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
                 dtype=np.int64)
    return v, f


def write_binary_stl(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    tri = v[f].astype("<f4")
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    rec = np.zeros(len(f), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"] = n
    rec["v"] = tri
    with open(path, "wb") as fh:
        fh.write(b"preflight test".ljust(80, b" "))
        fh.write(struct.pack("<I", len(f)))
        fh.write(rec.tobytes())


def broken_stl(path: Path, scale: float = 0.2) -> Path:
    """The shipped broken model (open cube stuck to a closed one), scaled down (mm)."""
    import trimesh

    m = trimesh.load(DATA / "open_cube_stuck_to_side.stl", process=False, force="mesh")
    v = np.asarray(m.vertices, dtype=np.float64) * scale
    f = np.asarray(m.faces, dtype=np.int64)
    write_binary_stl(path, v, f)
    return path


def write_3mf(path: Path, v: np.ndarray, f: np.ndarray) -> Path:
    verts = "".join(f'<vertex x="{a:.6f}" y="{b:.6f}" z="{c:.6f}"/>' for a, b, c in v)
    tris = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in f)
    model = ('<?xml version="1.0" encoding="UTF-8"?>'
             '<model unit="millimeter" xmlns="http://schemas.microsoft.com/3dmanufacturing/'
             'core/2015/02"><resources><object id="1" type="model"><mesh>'
             f'<vertices>{verts}</vertices><triangles>{tris}</triangles></mesh></object>'
             '</resources><build><item objectid="1"/></build></model>')
    ctypes = ('<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.openxmlformats'
              '.org/package/2006/content-types"><Default Extension="rels" ContentType='
              '"application/vnd.openxmlformats-package.relationships+xml"/><Default Extension='
              '"model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>'
              '</Types>')
    rels = ('<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
            'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel'
            '.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/'
            '3dmodel"/></Relationships>')
    tmp = path.with_name(path.name + ".part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("[Content_Types].xml", ctypes)
        z.writestr("_rels/.rels", rels)
        z.writestr("3D/3dmodel.model", model)
    os.rename(tmp, path)
    return path


def tiny_gcode(extra: list[str] | None = None, moves: int = 20) -> str:
    lines = ["G28", "G90", "M83", "G1 Z0.3 F600"]
    for i in range(moves):
        lines.append(f"G1 X{10 + (i % 5)} Y{10 + i % 3} E0.1 F1200")
    lines += extra or []
    lines += ["M104 S0", "M84"]
    return "\n".join(lines) + "\n"


def drop(spool: Path, name: str, data: bytes) -> Path:
    """Write a file as a network copy does: a partial name, then a rename."""
    part = spool / (name + ".part")
    part.write_bytes(data)
    os.rename(part, spool / name)
    return spool / name


# --- the daemon -------------------------------------------------------------------------

class DaemonProc:
    """``preflight run --config CFG`` as a subprocess."""

    def __init__(self, cfg_path: Path, env: dict[str, str] | None = None) -> None:
        self.cfg_path = cfg_path
        self.cfg = load_config(cfg_path)
        self.env = dict(os.environ, **(env or {}))
        self.proc: subprocess.Popen | None = None
        self.log = cfg_path.parent / "daemon.log"
        self._journal: Journal | None = None
        self.cfg.spool.path.mkdir(parents=True, exist_ok=True)

    def start(self) -> DaemonProc:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "daemon", "run", "--config", str(self.cfg_path)],
                stdout=log, stderr=log, stdin=subprocess.DEVNULL, env=self.env)
        self.wait_for(lambda: self.status().get("running") and
                      self.status().get("pid") == self.proc.pid, what="daemon start")
        return self

    @property
    def journal(self) -> Journal:
        if self._journal is None:
            self._journal = Journal(self.cfg.journal_path, readonly=True)
        return self._journal

    def status(self) -> dict:
        if not self.cfg.journal_path.exists():
            return {}
        return self.journal.get_meta("status") or {}

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def wait_for(self, pred, *, what: str, timeout: float = 180.0, poll: float = 0.1):
        """Poll ``pred`` until true; fail with the daemon log's tail if it never is.

        The timeout only guards against a hung test; it asserts nothing about speed.
        """
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                v = pred()
            except FileNotFoundError:
                v = None
            if v:
                return v
            if self.proc is not None and self.proc.poll() is not None and what != "exit":
                raise AssertionError(f"daemon exited ({self.proc.returncode}) waiting for "
                                     f"{what}:\n{self.tail()}")
            time.sleep(poll)
        raise AssertionError(f"timed out waiting for {what}:\n{self.tail()}")

    def jobs(self):
        return self.journal.jobs()

    def states(self) -> dict[str, str]:
        return {j.source_name: str(j.state) for j in self.jobs()}

    def cli(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "daemon", *args, "--config",
                               str(self.cfg_path)], capture_output=True, text=True,
                              timeout=120, env=self.env)

    def stop(self) -> int:
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=120)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def kill9(self) -> None:
        assert self.proc is not None
        self.proc.kill()
        self.proc.wait()

    def tail(self, n: int = 40) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


def gcode_commands(path: Path) -> list[str]:
    """The commands of a G-code file as the printer executes them (no comments/blank)."""
    out = []
    for line in path.read_text().splitlines():
        code = line.split(";", 1)[0].strip()
        if code:
            out.append(code)
    return out
