"""Klipper's nozzle and build volume, from its API socket or its ``printer.cfg``.

Klipper's G-code pseudo-tty has no query for either, but when preflight runs beside
Klipper its API server answers on a unix socket (``klippy -a /tmp/klippy_uds``): JSON
requests and responses, each terminated by the byte 0x03. One request,
``objects/query`` on ``configfile`` ``settings``, gives the parsed configuration:
``extruder.nozzle_diameter`` and ``stepper_x|y|z.position_min/position_max``. Without
the socket, the same values are read from ``printer.cfg`` (its ``[include]`` files
followed; the ``#*#`` SAVE_CONFIG block is comments to it).
"""

from __future__ import annotations

import configparser
import glob
import json
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

DEFAULT_SOCKET = "/tmp/klippy_uds"
ETX = b"\x03"
_MAX_REPLY = 4 * 1024 * 1024


class KlipperApiError(Exception):
    """The API socket is missing, refused the query or sent something unreadable."""


@dataclass(frozen=True)
class KlipperCapabilities:
    """What Klipper's configuration says. limits: ((xmin, ymin, zmin), (xmax, ymax, zmax))
    in mm, or None (e.g. a delta). source: ``"Klipper API <socket>"`` or
    ``"Klipper config <printer.cfg>"``."""

    nozzle_diameter: float | None
    limits: tuple[tuple[float, ...], tuple[float, ...]] | None
    source: str


def query_objects(socket_path: str | os.PathLike, objects: dict,
                  timeout: float = 2.0) -> dict:
    """``objects/query`` over the API socket; the ``status`` mapping of the reply."""
    request = {"id": 1, "method": "objects/query", "params": {"objects": objects}}
    reply = _call(os.fspath(socket_path), request, timeout)
    if "error" in reply:
        error = reply["error"]
        message = error.get("message") if isinstance(error, dict) else error
        raise KlipperApiError(f"Klipper refused objects/query: {message}")
    status = (reply.get("result") or {}).get("status")
    if not isinstance(status, dict):
        raise KlipperApiError("Klipper's objects/query reply has no status")
    return status


def _call(path: str, request: dict, timeout: float) -> dict:
    if not os.path.exists(path):
        raise KlipperApiError(f"no Klipper API socket at {path}")
    deadline = time.monotonic() + timeout
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout)
            sock.connect(path)
            sock.sendall(json.dumps(request).encode() + ETX)
            buf = b""
            while True:
                # Klipper may push other messages (subscriptions) first: skip them.
                while ETX in buf:
                    message, buf = buf.split(ETX, 1)
                    reply = json.loads(message.decode("utf-8"))
                    if isinstance(reply, dict) and reply.get("id") == request["id"]:
                        return reply
                if len(buf) > _MAX_REPLY or time.monotonic() > deadline:
                    raise KlipperApiError(f"no reply from the Klipper API socket {path}")
                chunk = sock.recv(65536)
                if not chunk:
                    raise KlipperApiError(f"the Klipper API socket {path} closed the connection")
                buf += chunk
    except (OSError, ValueError) as exc:
        if isinstance(exc, KlipperApiError):
            raise
        raise KlipperApiError(f"the Klipper API socket {path}: {exc}") from None


def from_api(socket_path: str | os.PathLike = DEFAULT_SOCKET,
             timeout: float = 2.0) -> KlipperCapabilities:
    """Nozzle and axis limits from the running Klipper's parsed configuration."""
    status = query_objects(socket_path, {"configfile": ["settings"]}, timeout)
    settings = (status.get("configfile") or {}).get("settings")
    if not isinstance(settings, dict):
        raise KlipperApiError("Klipper's configfile has no settings")
    return _capabilities(settings, f"Klipper API {os.fspath(socket_path)}")


def from_config(path: str | os.PathLike) -> KlipperCapabilities:
    """Nozzle and axis limits from ``printer.cfg`` (and the files it includes)."""
    parser = configparser.ConfigParser(inline_comment_prefixes=("#", ";"), strict=False,
                                       interpolation=None)
    _read_with_includes(parser, Path(path), depth=0)
    settings = {name.lower(): {key.lower(): value for key, value in parser[name].items()}
                for name in parser.sections()}
    return _capabilities(settings, f"Klipper config {os.fspath(path)}")


def _read_with_includes(parser: configparser.ConfigParser, path: Path, depth: int) -> None:
    if depth > 8:
        raise KlipperApiError(f"{path}: [include] nested too deeply")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise KlipperApiError(f"cannot read {path}: {exc.strerror}") from None
    local = configparser.ConfigParser(inline_comment_prefixes=("#", ";"), strict=False,
                                      interpolation=None)
    try:
        local.read_string(text, source=str(path))
    except configparser.Error as exc:
        raise KlipperApiError(f"{path} is not a Klipper config: "
                              f"{' '.join(str(exc).split())[:160]}") from None
    for name in local.sections():
        if name.lower().startswith("include "):
            pattern = name.split(None, 1)[1].strip()
            for included in sorted(glob.glob(str(path.parent / pattern))):
                _read_with_includes(parser, Path(included), depth + 1)
            continue
        if not parser.has_section(name):
            parser.add_section(name)
        for key, value in local[name].items():
            parser[name][key] = value


def _number(value) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if number == number and abs(number) < 1e6 else None


def _capabilities(settings: dict, source: str) -> KlipperCapabilities:
    nozzle = _number((settings.get("extruder") or {}).get("nozzle_diameter"))
    if nozzle is not None and not 0.05 <= nozzle <= 3.0:
        nozzle = None
    low, high = [], []
    for axis in "xyz":
        stepper = settings.get(f"stepper_{axis}") or {}
        top = _number(stepper.get("position_max"))
        bottom = _number(stepper.get("position_min", 0.0))
        if top is None or bottom is None or top <= bottom:
            low = []
            break
        low.append(bottom)
        high.append(top)
    limits = (tuple(low), tuple(high)) if low else None
    return KlipperCapabilities(nozzle, limits, source)


def klipper_capabilities(socket_path: str | os.PathLike | None = DEFAULT_SOCKET,
                         config_path: str | os.PathLike | None = None
                         ) -> tuple[KlipperCapabilities | None, list[str]]:
    """The API socket's answer, else ``printer.cfg``'s; with the reasons a source failed."""
    problems: list[str] = []
    if socket_path:
        try:
            return from_api(socket_path), problems
        except KlipperApiError as exc:
            problems.append(str(exc))
    if config_path:
        try:
            return from_config(config_path), problems
        except KlipperApiError as exc:
            problems.append(str(exc))
    return None, problems
