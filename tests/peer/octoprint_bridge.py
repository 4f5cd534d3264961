"""Put OctoPrint's own VirtualPrinter on a real pseudo-terminal (test-only; run it with
the peer venv's python: ``.venv-peer/bin/python tests/peer/octoprint_bridge.py``).

OctoPrint's virtual printer (``octoprint.plugins.virtual_printer.virtual.VirtualPrinter``,
AGPL, installed from PyPI into a separate venv, nothing copied) is a serial-like object
(``write``/``readline``). This bridge serves it on the slave side of an ``os.openpty()``
pair, so our host talks to it exactly as to a USB printer: host bytes are handed over a
line at a time, each byte as soon as its 64-byte RX buffer has room (USB-CDC flow
control), and its replies are written back. It runs with the plugin's default
settings, simulated errors included (resend at line 100, resend with a lost answer at
105, missing line number at 110, checksum mismatch at 115), unless ``--settings``
gives overrides as JSON.

What the peer did is recorded in ``--record``, one event per line:

* ``A <n>``: it accepted line number n (its last-line counter advanced to n);
* ``R <n>``: its counter went back to n (an ``M110``);
* ``X <n> <command>``: it executed a G/M/T command received as line number n
  (``-`` for a line sent without a number).

The slave path is printed on stdout once it is ready; SIGTERM stops it.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time
import tty

from octoprint.plugins.virtual_printer import VirtualPrinterPlugin
from octoprint.plugins.virtual_printer import virtual as peer


class PluginSettings:
    """The part of OctoPrint's plugin settings API the VirtualPrinter reads."""

    def __init__(self, values: dict, folder: str) -> None:
        self.values = values
        self.folder = folder

    def get(self, path, merged=False):
        value = self.values
        for key in path:
            if not isinstance(value, dict):
                return None
            value = value.get(key)
        return value

    def get_int(self, path):
        value = self.get(path)
        return None if value is None else int(value)

    def get_float(self, path):
        value = self.get(path)
        return None if value is None else float(value)

    def get_boolean(self, path):
        return bool(self.get(path))

    def global_get_basefolder(self, name):
        path = os.path.join(self.folder, name)
        os.makedirs(path, exist_ok=True)
        return path


class NoPlugins:
    """Stands in for OctoPrint's plugin manager: no other plugin adds hooks."""

    def get_hooks(self, name):
        return {}


class Profiles:
    """The printer profile manager, as far as the VirtualPrinter asks it (M115 area)."""

    def get_current_or_default(self):
        return {"volume": {"width": 200.0, "depth": 200.0, "height": 200.0,
                           "origin": "lowerleft", "formFactor": "rectangular",
                           "custom_box": False}}


class RecordingPrinter(peer.VirtualPrinter):
    """The peer, unchanged, with its line counter and its G/M/T dispatch observed."""

    record = None
    _record_lock = threading.Lock()

    def _note(self, text: str) -> None:
        if self.record is not None:
            with self._record_lock:
                self.record.write(text + "\n")

    @property
    def lastN(self):  # noqa: N802 - the peer's attribute name
        return self.__dict__.get("_observed_last_n", 0)

    @lastN.setter
    def lastN(self, value):  # noqa: N802
        before = self.__dict__.get("_observed_last_n", 0)
        self.__dict__["_observed_last_n"] = value
        if value == before + 1:
            self._note(f"A {value}")
        elif value < before:
            self._note(f"R {value}")

    def watch_input(self) -> None:
        """Keep the raw line the peer is working on (its input queue's last full line):
        the command hooks below then know the number it arrived with."""
        queue_get = self.incoming.get
        self._raw_line = b""
        pending = [b""]

        def get(*args, **kwargs):
            data = queue_get(*args, **kwargs)
            pending[0] += data if isinstance(data, bytes) else str(data).encode()
            if b"\n" in pending[0]:
                self._raw_line, _, pending[0] = pending[0].partition(b"\n")
            return data

        self.incoming.get = get

    def _executed(self, data: str) -> None:
        raw = getattr(self, "_raw_line", b"").strip()
        number = "-"
        if raw.startswith(b"N"):
            digits = raw[1:].split(None, 1)[0]
            number = digits.decode() if digits.isdigit() else "-"
        self._note(f"X {number} {data.strip()}")

    def _gcode_G(self, code, data):  # noqa: N802 - dispatch hook for every G command
        self._executed(data)

    def _gcode_M(self, code, data):  # noqa: N802
        self._executed(data)

    def _gcode_T(self, code, data):  # noqa: N802
        self._executed(data)
        return super()._gcode_T(code, data)


def serve(link: str, record: str | None, overrides: dict) -> None:
    values = VirtualPrinterPlugin().get_settings_defaults()
    values.update(overrides)
    folder = tempfile.mkdtemp(prefix="octoprint-peer-")
    peer.plugin_manager = NoPlugins  # the module looks its plugin manager up when built
    master, slave = os.openpty()
    tty.setraw(slave)
    if os.path.lexists(link):
        os.unlink(link)
    os.symlink(os.ttyname(slave), link)
    RecordingPrinter.record = open(record, "a", buffering=1) if record else None  # noqa: SIM115
    printer = RecordingPrinter(PluginSettings(values, folder), Profiles(), folder,
                               read_timeout=0.5)
    printer.watch_input()
    stop = threading.Event()

    def to_printer() -> None:
        pending = b""
        while not stop.is_set():
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            pending += data
            while b"\n" in pending:  # one line at a time, as the peer's own host writes
                line, pending = pending.split(b"\n", 1)
                line += b"\n"
                while line and not stop.is_set():
                    # USB-CDC flow control: bytes wait until the RX buffer has room. (The
                    # peer's write() would wait too, but holding the lock its resend
                    # request needs: a deadlock its own host never provokes.)
                    room = printer.incoming.maxsize - printer.incoming.qsize()
                    if room <= 0:
                        time.sleep(0.001)
                        continue
                    line = line[printer.write(line[:room]):]

    def to_host() -> None:
        while not stop.is_set():
            line = printer.readline()
            if line:
                os.write(master, line if line.endswith(b"\n") else line + b"\n")

    for target in (to_printer, to_host):
        threading.Thread(target=target, daemon=True).start()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(os.ttyname(slave), flush=True)
    while not stop.wait(0.2):
        pass
    printer.close()
    os.unlink(link)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--link", required=True, help="symlink to the pty to create")
    parser.add_argument("--record", help="append what the peer accepted and executed here")
    parser.add_argument("--settings", default="{}",
                        help="JSON overrides of the plugin's default settings")
    args = parser.parse_args()
    serve(args.link, args.record, json.loads(args.settings))
    return 0


if __name__ == "__main__":
    sys.exit(main())
