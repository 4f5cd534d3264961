"""A virtual FDM printer on a real pseudo-terminal, for tests, the demo and benchmarks.

The printer runs in a background thread of the calling process and serves the slave
side of an ``os.openpty()`` pair, so a host talks to it exactly as to a USB serial
port. It models what matters for a serial host:

* the wire: host bytes reach the firmware at ``baud / 10`` bytes per second;
* a ``rx_buffer``-byte receive buffer (128 by default) that loses bytes on overflow,
  as a UART does; the firmware only drains it while its command queue has room;
* a ``queue_size``-command queue (BUFSIZE, 4 by default) with ``ok`` sent when a
  command has been executed; moves go into a 16-block planner and take
  distance / feedrate / ``speedup`` seconds;
* the line protocol of each firmware profile: Marlin 2.x and Prusa Buddy (line
  number + checksum checked, ``Error:`` + ``Resend:`` + ``ok``), Prusa MK3 (the same
  but ``Resend:`` without ``ok``), Klipper (ignores N and checksum, never resends,
  ``ok`` on every line) and RepRapFirmware (silently drops a bad-checksum line);
* a thermal model for M104/M109/M140/M190, replies to M105, M115, M211, M208,
  M200, M862.1 and a Klipper nozzle macro;
* faults (:class:`Faults`): byte corruption, lost ``ok``, busy keepalives, a board
  reset or a disconnect after N lines (optionally coming back on a new pty, the
  ``link`` symlink updated, as a re-plugged USB device does), and line noise.

Every executed command is recorded (``executed``; ``executed_numbered`` also gives
its line number, None for an unnumbered line) so tests can prove exactly-once,
in-order delivery.
"""

from __future__ import annotations

import math
import os
import random
import re
import select
import termios
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass

from printer.gcode import command_word

FIRMWARES = ("marlin", "prusa", "buddy", "klipper", "rrf")

_PLANNER_BLOCKS = 16
_AMBIENT = 25.0


@dataclass(frozen=True)
class Faults:
    """Fault injection for the virtual printer.

    corrupt: probability that a host->printer byte is replaced by another random
    byte (never by a line terminator: a noise-made newline defeats the Marlin line
    protocol itself, not the host). drop_ok: probability that the ``ok`` of an
    executed command is lost. busy_seconds: G28/G29 block for this many real seconds,
    sending ``echo:busy: processing`` every ``keepalive`` seconds. reset_after /
    disconnect_after: after this many executed numbered lines the board resets
    (prints ``start``) / the port hangs up. reconnect_after: seconds after a
    disconnect the printer comes back on a new pty (the link is re-pointed).
    garbage: every byte sent to the host is noise (what a wrong baud rate looks like).
    """

    corrupt: float = 0.0
    drop_ok: float = 0.0
    busy_seconds: float = 0.0
    reset_after: int | None = None
    disconnect_after: int | None = None
    reconnect_after: float | None = None
    garbage: bool = False
    seed: int = 1


@dataclass(frozen=True)
class _Profile:
    name: str
    banner: tuple[str, ...]
    m115: tuple[str, ...]
    checks: str  # "marlin" (N + checksum, resend), "rrf" (silent drop), "none"
    resend_ok: bool
    advanced_ok: bool


_MARLIN_CAPS = (
    "Cap:SERIAL_XON_XOFF:0",
    "Cap:BINARY_FILE_TRANSFER:0",
    "Cap:EEPROM:1",
    "Cap:VOLUMETRIC:1",
    "Cap:AUTOREPORT_POS:0",
    "Cap:AUTOREPORT_TEMP:1",
    "Cap:PROGRESS:0",
    "Cap:PRINT_JOB:1",
    "Cap:AUTOLEVEL:1",
    "Cap:RUNOUT:0",
    "Cap:Z_PROBE:1",
    "Cap:LEVELING_DATA:1",
    "Cap:SOFTWARE_POWER:0",
    "Cap:EMERGENCY_PARSER:1",
    "Cap:HOST_ACTION_COMMANDS:0",
    "Cap:PROMPT_SUPPORT:0",
    "Cap:SDCARD:1",
    "Cap:THERMAL_PROTECTION:1",
    "Cap:MOTION_MODES:0",
    "Cap:ARCS:1",
    "Cap:CHAMBER_TEMPERATURE:0",
)

_PROFILES = {
    "marlin": _Profile(
        "marlin",
        ("start", "echo:Marlin 2.1.2.1", "echo: Last Updated: 2023-07-23 | Author: (virtual)"),
        (
            "FIRMWARE_NAME:Marlin 2.1.2.1 (Jul 23 2023 10:00:00) "
            "SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:Virtual Marlin EXTRUDER_COUNT:1 "
            "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff",
            *_MARLIN_CAPS,
        ),
        "marlin",
        True,
        False,
    ),
    "prusa": _Profile(
        "prusa",
        ("start", "echo: 3.14.1-8237", "echo:Free Memory: 1987  PlannerBufferBytes: 1392"),
        (
            "FIRMWARE_NAME:Prusa-Firmware 3.14.1 based on Marlin "
            "FIRMWARE_URL:https://github.com/prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:Prusa i3 MK3S EXTRUDER_COUNT:1 UUID:00000000-0000-0000-0000-000000000000",
            "Cap:AUTOREPORT_TEMP:1",
            "Cap:AUTOREPORT_FANS:1",
            "Cap:AUTOREPORT_POSITION:1",
            "Cap:EXTENDED_M20:1",
            "Cap:PRUSA_MMU2:1",
        ),
        "marlin",
        False,
        False,
    ),
    "buddy": _Profile(
        "buddy",
        ("start", "echo:Prusa-Firmware-Buddy 6.1.3"),
        (
            "FIRMWARE_NAME:Prusa-Firmware-Buddy 6.1.3+8542 (Github) "
            "SOURCE_CODE_URL:https://github.com/prusa3d/Prusa-Firmware-Buddy "
            "PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa-MK4 EXTRUDER_COUNT:1 "
            "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff",
            "Cap:SERIAL_XON_XOFF:0",
            "Cap:EEPROM:0",
            "Cap:AUTOREPORT_TEMP:1",
            "Cap:AUTOREPORT_POS:1",
            "Cap:EMERGENCY_PARSER:1",
            "Cap:PRUSA_MMU2:0",
        ),
        "marlin",
        True,
        True,
    ),
    "klipper": _Profile("klipper", (), (), "none", False, False),
    "rrf": _Profile(
        "rrf",
        (),
        (
            "FIRMWARE_NAME: RepRapFirmware for Duet 3 Mini 5+ FIRMWARE_VERSION: 3.5.1 "
            "ELECTRONICS: Duet 3 Mini5plus Ethernet FIRMWARE_DATE: 2024-04-19 14:40:46",
        ),
        "rrf",
        False,
        False,
    ),
}

_PARAM_RE = re.compile(r"([A-Za-z])\s*(-?\d*\.?\d+)")


def _params(command: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for letter, value in _PARAM_RE.findall(command.split(None, 1)[1] if " " in command else ""):
        try:
            out.setdefault(letter.upper(), float(value))
        except ValueError:
            pass
    return out


def _command_part(line: str) -> str:
    """The command of a received line, without N and checksum."""
    star = line.rfind("*")
    body = line[:star] if star >= 0 else line
    return re.sub(r"^N-?\d*\s*", "", body.strip()).strip()


def _xor(text: str) -> int:
    """The firmware's checksum over the bytes exactly as received (latin-1 text)."""
    value = 0
    for byte in text.encode("latin-1"):
        value ^= byte
    return value


def _leading_int(text: str) -> int:
    m = re.match(r"-?\d+", text)
    return int(m.group(0)) if m else 0


class VirtualPrinter:
    """A simulated printer on a pty; see the module docstring for what it models.

    nozzle: mm. baud: bits/s of the simulated wire. speedup: simulated time runs this
    many times faster than real time (moves, heating). build_volume: (x, y, z) mm.
    keepalive: real seconds between busy / heating keepalive lines.
    """

    def __init__(
        self,
        firmware: str = "marlin",
        nozzle: float = 0.4,
        baud: int = 115200,
        speedup: float = 1.0,
        faults: Faults | None = None,
        log_path: str | os.PathLike | None = None,
        link: str | os.PathLike | None = None,
        *,
        rx_buffer: int = 128,
        queue_size: int = 4,
        advanced_ok: bool | None = None,
        build_volume: tuple[float, float, float] = (250.0, 210.0, 220.0),
        filament_diameter: float = 1.75,
        keepalive: float = 2.0,
        nozzle_macro: str = "NOZZLE_DIAMETER",
    ) -> None:
        if firmware not in _PROFILES:
            raise ValueError(f"unknown firmware {firmware!r}; choose one of {', '.join(FIRMWARES)}")
        self.profile = _PROFILES[firmware]
        self.firmware = firmware
        self.nozzle = float(nozzle)
        self.baud = int(baud)
        self.speedup = float(speedup)
        self.faults = faults or Faults()
        self.log_path = os.fspath(log_path) if log_path else None
        self.link = os.fspath(link) if link else None
        self.rx_size = int(rx_buffer)
        self.queue_size = int(queue_size)
        self.advanced_ok = self.profile.advanced_ok if advanced_ok is None else advanced_ok
        self.build_volume = tuple(float(v) for v in build_volume)
        self.filament_diameter = float(filament_diameter)
        self.keepalive = float(keepalive)
        self.nozzle_macro = nozzle_macro.upper()

        self.executed_numbered: list[tuple[int | None, str]] = []
        self.stats = {
            "bytes_received": 0,
            "bytes_corrupted": 0,
            "bytes_overflowed": 0,
            "line_errors": 0,
            "oks_dropped": 0,
            "silent_drops": 0,
            "resets": 0,
            "disconnects": 0,
        }
        #: Line numbers of lines accepted although noise changed their command (an XOR
        #: checksum collision): a limit of the firmware protocol, reported, never hidden.
        self.undetected_corruptions: list[int] = []
        self._rng = random.Random(self.faults.seed)
        self._baud_checked_at = -1.0
        self._baud_wrong = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = -1
        self._slave = -1
        self.port: str | None = None
        #: How many times a pty has been opened (2 after one disconnect + reconnect).
        self.generation = 0
        self._slave_name: str | None = None
        self._log = None
        self._reset_state()

    # ----------------------------------------------------------------- public API
    @property
    def executed(self) -> list[str]:
        """Executed commands (without N/checksum), in execution order."""
        with self._lock:
            return [cmd for _, cmd in self.executed_numbered]

    def start(self) -> str:
        """Open the pty and start the serving thread; return the pty slave path.

        With ``link``, a symlink at that path points to the slave (and is re-pointed
        after a reconnect); ``port`` is the path a host should open (link or slave).
        """
        if self.log_path:
            self._log = open(self.log_path, "a", buffering=1, encoding="utf-8")  # noqa: SIM115
        self._open_pty()
        self._thread = threading.Thread(target=self._run, name="virtual-printer", daemon=True)
        self._thread.start()
        return self._slave_name or ""

    def stop(self) -> None:
        """Stop serving and close the pty (the link is removed)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._close_pty()
        if self.link and os.path.islink(self.link):
            try:
                os.unlink(self.link)
            except OSError:
                pass
        if self._log is not None:
            self._log.close()
            self._log = None

    def __enter__(self) -> VirtualPrinter:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def slave_path(self) -> str | None:
        """The current pty slave path (changes after a disconnect + reconnect)."""
        return self._slave_name

    # ----------------------------------------------------------------- pty plumbing
    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        attrs = termios.tcgetattr(slave)
        attrs[3] &= ~termios.ECHO
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._slave_name = os.ttyname(slave)
        self.generation += 1
        if self.link:
            tmp = f"{self.link}.tmp{os.getpid()}"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self._slave_name, tmp)
            os.replace(tmp, self.link)
            self.port = self.link
        else:
            self.port = self._slave_name

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = -1

    # ----------------------------------------------------------------- state
    def _reset_state(self) -> None:
        self._wire = bytearray()
        self._wire_next = 0.0
        self._wire_last = 0.0
        self._rx: deque[int] = deque()
        self._rx_orig: deque[int] = deque()
        self._line = bytearray()
        self._line_orig = bytearray()
        self._em_line = bytearray()
        self._queue: deque[tuple[int | None, str]] = deque()
        self._planner: deque[float] = deque()
        self._current: dict | None = None
        self._last_n = 0
        self._halted = False
        self._pos = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        self._feed = 1500.0  # mm/min
        self._relative = False
        self._relative_e = False
        self._temp = {"T": _AMBIENT, "B": _AMBIENT}
        self._target = {"T": 0.0, "B": 0.0}
        self._autoreport = 0.0
        self._next_report = 0.0
        self._numbered_done = 0
        self._last_tick = time.monotonic()

    # ----------------------------------------------------------------- output
    def _send(self, text: str) -> None:
        data = (text + "\n").encode("ascii", "replace")
        if self.faults.garbage or self._baud_mismatch():
            data = bytes(self._rng.randrange(128, 256) for _ in range(len(data) + 3))
        if self._master < 0:
            return
        try:
            os.write(self._master, data)
        except BlockingIOError:
            pass  # nobody reading: a UART drops what no one listens to
        except OSError:
            pass

    def _ok(self, extra: str = "", *, executed: bool = True) -> None:
        if executed and self.faults.drop_ok and self._rng.random() < self.faults.drop_ok:
            self.stats["oks_dropped"] += 1
            return
        if self.firmware == "klipper":
            self._send(f"ok {extra}".rstrip())
            return
        text = "ok"
        if self.advanced_ok and not extra:
            planner_free = _PLANNER_BLOCKS - len(self._planner)
            queue_free = self.queue_size - len(self._queue)
            text = f"ok N{self._last_n} P{planner_free} B{queue_free}"
        self._send(f"{text} {extra}".rstrip())

    _BAUD_CONSTANTS = {
        9600: "B9600", 19200: "B19200", 38400: "B38400", 57600: "B57600",
        115200: "B115200", 230400: "B230400", 460800: "B460800", 500000: "B500000",
        921600: "B921600", 1000000: "B1000000",
    }

    def _baud_mismatch(self) -> bool:
        """True when the host set a standard speed on the tty that differs from ours."""
        now = time.monotonic()
        if now < self._baud_checked_at + 0.2:
            return self._baud_wrong
        self._baud_checked_at = now
        self._baud_wrong = self._tty_speed_differs()
        return self._baud_wrong

    def _tty_speed_differs(self) -> bool:
        if self._slave < 0:
            return False
        try:
            speed = termios.tcgetattr(self._slave)[5]
        except termios.error:
            return False
        host = {getattr(termios, n, None): b for b, n in self._BAUD_CONSTANTS.items()}.get(speed)
        return host is not None and host != self.baud and speed != termios.B38400

    # ----------------------------------------------------------------- main loop
    def _run(self) -> None:
        byte_time = 10.0 / self.baud
        while not self._stop.is_set():
            if self._master < 0:
                time.sleep(0.01)
                continue
            now = time.monotonic()
            timeout = self._next_wakeup(now, byte_time)
            try:
                ready, _, _ = select.select([self._master], [], [], timeout)
            except (OSError, ValueError):
                ready = []
            now = time.monotonic()
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:
                    data = b""
                if data:
                    if not self._wire:
                        self._wire_next = max(now, self._wire_last + byte_time)
                    self._wire += data
            with self._lock:
                self._deliver(now, byte_time)
                self._tick(now)

    def _next_wakeup(self, now: float, byte_time: float) -> float:
        wake = 0.05
        if self._wire:
            wake = min(wake, max(0.0, self._wire_next - now) + 4 * byte_time)
        if self._current is not None and "until" in self._current:
            wake = min(wake, max(0.0, self._current["until"] - now))
        if self._queue or self._rx:
            wake = min(wake, 0.002)
        return max(wake, 0.0)

    def _deliver(self, now: float, byte_time: float) -> None:
        if not self._wire or now < self._wire_next:
            return
        n = min(len(self._wire), int((now - self._wire_next) / byte_time) + 1)
        chunk = bytes(self._wire[:n])
        del self._wire[:n]
        self._wire_next += n * byte_time
        self._wire_last = self._wire_next - byte_time
        self.stats["bytes_received"] += n
        if self._halted:
            return
        if self.faults.garbage or self._baud_mismatch():
            # At the wrong speed our bytes are noise to it and its replies noise to us.
            if b"\n" in chunk:
                self._send("echo:Unknown command: \"\"")
            return
        p = self.faults.corrupt
        rng = self._rng
        for orig in chunk:
            byte = orig
            if p and rng.random() < p:
                byte = rng.randrange(1, 256)
                while byte in (orig, 10, 13):
                    byte = rng.randrange(1, 256)
                self.stats["bytes_corrupted"] += 1
            if len(self._rx) >= self.rx_size:
                self.stats["bytes_overflowed"] += 1
                continue
            self._rx.append(byte)
            self._rx_orig.append(orig)
            self._emergency_scan(byte)

    def _emergency_scan(self, byte: int) -> None:
        if byte in (10, 13):
            line = self._em_line.decode("ascii", "replace")
            self._em_line.clear()
            if re.search(r"(^|\s)M112(\s|\*|$)", line):
                self._halt("M112")
        elif len(self._em_line) < 200:
            self._em_line.append(byte)

    def _halt(self, why: str) -> None:
        self._record(None, "M112")
        self._halted = True
        self._queue.clear()
        self._rx.clear()
        self._rx_orig.clear()
        self._current = None
        self._target = {"T": 0.0, "B": 0.0}
        if self.firmware == "klipper":
            self._send(f"!! Shutdown due to {why} command")
        else:
            self._send("Error:Printer halted. kill() called!")

    # ----------------------------------------------------------------- receiving
    def _tick(self, now: float) -> None:
        self._thermal(now)
        if self._halted:
            return
        while self._rx and len(self._queue) < self.queue_size:
            byte = self._rx.popleft()
            orig = self._rx_orig.popleft()
            if byte in (10, 13):
                if self._line:
                    raw = self._line.decode("latin-1")  # byte for byte: noise stays noise
                    sent = self._line_orig.decode("latin-1")
                    changed = _command_part(raw) != _command_part(sent)
                    self._line.clear()
                    self._line_orig.clear()
                    self._receive_line(raw.strip(), changed)
            elif len(self._line) < 200:
                self._line.append(byte)
                self._line_orig.append(orig)
        self._execute(now)
        if self._autoreport and now >= self._next_report:
            self._next_report = now + self._autoreport
            self._send(self._temps_text())

    def _line_error(self, reason: str) -> None:
        self.stats["line_errors"] += 1
        self._send(f"Error:{reason}, Last Line: {self._last_n}")
        self._rx.clear()  # Marlin drains its RX buffer after a line error
        self._rx_orig.clear()
        self._send(f"Resend: {self._last_n + 1}")
        if self.profile.resend_ok:
            self._ok(executed=False)

    def _receive_line(self, raw: str, changed: bool) -> None:
        number: int | None = None
        command = raw
        checks = self.profile.checks
        if raw.startswith("N") and (checks != "none" or re.match(r"N-?\d", raw)):
            number = _leading_int(raw[1:])
            star = raw.rfind("*")
            body = raw[:star] if star >= 0 else raw
            command = re.sub(r"^N-?\d*\s*", "", body).strip()
            if checks == "marlin":
                if "M110" in raw:
                    m = re.search(r"M110\s*N(-?\d+)", raw)
                    number = int(m.group(1)) if m else number
                elif number != self._last_n + 1:
                    self._line_error("Line Number is not Last Line Number+1")
                    return
                if star < 0:
                    self._line_error("No Checksum with line number")
                    return
                if _leading_int(raw[star + 1:]) != _xor(raw[:star]):
                    self._line_error("checksum mismatch")
                    return
                self._last_n = number
            elif checks == "rrf":
                if star < 0 or _leading_int(raw[star + 1:]) != _xor(raw[:star]):
                    self.stats["silent_drops"] += 1
                    return
                if "M110" in raw:
                    m = re.search(r"M110\s*N(-?\d+)", raw)
                    number = int(m.group(1)) if m else number
                elif number <= self._last_n:
                    self._ok(executed=False)  # a line it already has: acknowledged, not re-run
                    return
                elif number != self._last_n + 1:
                    self.stats["silent_drops"] += 1
                    return
                self._last_n = number
        else:
            star = raw.rfind("*")
            if star >= 0:
                # A checksum without a line number: noise ate the "N".
                if checks == "marlin":
                    self._line_error("No Line Number with checksum")
                    return
                if checks == "rrf" and _leading_int(raw[star + 1:]) != _xor(raw[:star]):
                    self.stats["silent_drops"] += 1
                    return
                command = raw[:star].strip()
        if not command:
            return
        if changed and checks != "none" and number is not None:
            self.undetected_corruptions.append(number)
        self._queue.append((number, command))

    # ----------------------------------------------------------------- executing
    def _record(self, number: int | None, command: str) -> None:
        self.executed_numbered.append((number, command))
        if self._log is not None:
            self._log.write(command + "\n")

    def _execute(self, now: float) -> None:
        while self._queue:
            if self._current is None:
                self._current = self._begin(self._queue[0], now)
            if not self._progress(self._current, now):
                return
            number, command = self._queue.popleft()
            current = self._current
            self._current = None
            self._record(number, command)
            for line in current.get("replies", ()):
                self._send(line)
            if current.get("ok", True):
                self._ok(current.get("ok_extra", ""))
            if number is not None and not command.upper().startswith("M110"):
                self._numbered_done += 1
                if self._fault_after_line():
                    return

    def _fault_after_line(self) -> bool:
        f = self.faults
        if f.reset_after is not None and self._numbered_done == f.reset_after:
            self.stats["resets"] += 1
            if self.firmware == "klipper":
                # The MCU went away: Klipper shuts down and refuses further commands.
                self._numbered_done = -10**9
                self._halted = True
                self._queue.clear()
                self._send("!! Lost communication with MCU 'mcu'")
            else:
                self._reset_state()
                self._numbered_done = -10**9  # one reset per printer
                for line in self.profile.banner or ("start",):
                    self._send(line)
            return True
        if f.disconnect_after is not None and self._numbered_done == f.disconnect_after:
            self.stats["disconnects"] += 1
            self._numbered_done = -10**9
            self._close_pty()
            if f.reconnect_after is not None:
                threading.Timer(f.reconnect_after, self._reconnect).start()
            return True
        return False

    def _reconnect(self) -> None:
        if self._stop.is_set():
            return
        with self._lock:
            self._reset_state()
            self._numbered_done = -10**9
            self._open_pty()

    def _begin(self, item: tuple[int | None, str], now: float) -> dict:
        """Work out what executing a command means: replies, and what it waits for."""
        _, command = item
        word = command_word(command)
        p = _params(command)
        fw = self.firmware
        state: dict = {"replies": []}
        replies = state["replies"]
        if word in ("G0", "G1", "G2", "G3"):
            state["move"] = self._move_time(p)
        elif word == "G4":
            seconds = p.get("P", 0.0) / 1000.0 + p.get("S", 0.0)
            state["until"] = now + seconds / self.speedup
            state["drain"] = True
        elif word in ("G28", "G29"):
            state["drain"] = True
            if self.faults.busy_seconds:
                state["until"] = None
                state["busy_for"] = self.faults.busy_seconds
            else:
                state["until"] = None
                state["busy_for"] = 5.0 / self.speedup
            if word == "G28":
                for axis in "XYZ":
                    self._pos[axis] = 0.0
        elif word == "G90":
            self._relative = False
            self._relative_e = False
        elif word == "G91":
            self._relative = True
            self._relative_e = True
        elif word == "M82":
            self._relative_e = False
        elif word == "M83":
            self._relative_e = True
        elif word == "G92":
            for axis in "XYZE":
                if axis in p:
                    self._pos[axis] = p[axis]
        elif word in ("M104", "M109"):
            self._target["T"] = p.get("S", p.get("R", 0.0))
            if word == "M109":
                state["heat"] = "T"
        elif word in ("M140", "M190"):
            self._target["B"] = p.get("S", p.get("R", 0.0))
            if word == "M190":
                state["heat"] = "B"
        elif word == "M400":
            state["drain"] = True
        elif word == "M105":
            state["ok_extra"] = self._temps_text().strip()
            if fw != "klipper":
                state["ok_extra"] = state["ok_extra"]
        elif word == "M155":
            self._autoreport = p.get("S", 0.0)
            self._next_report = now + self._autoreport
        elif word == "M114":
            pos = self._pos
            replies.append(
                f"X:{pos['X']:.2f} Y:{pos['Y']:.2f} Z:{pos['Z']:.2f} E:{pos['E']:.2f}"
                " Count X:0 Y:0 Z:0"
            )
        elif word == "M115":
            if fw == "klipper":
                state["ok_extra"] = "FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.12.0-virtual"
            else:
                replies.extend(self.profile.m115)
                if fw in ("marlin", "buddy"):
                    replies.append(self._area())
        elif word == "M211" and fw in ("marlin", "buddy") and not p:
            x, y, z = self.build_volume
            replies.extend(
                (
                    "echo:; Soft Endstops:",
                    "echo:  M211 S1 ; ON",
                    f"echo:    Min:  X0.00 Y0.00 Z0.00   Max:  X{x:.2f} Y{y:.2f} Z{z:.2f}",
                )
            )
        elif word == "M208" and fw == "rrf" and not p:
            x, y, z = self.build_volume
            replies.append(f"Axis limits (mm) X0.0:{x:.1f}, Y0.0:{y:.1f}, Z0.0:{z:.1f}")
        elif word == "M200" and fw in ("marlin", "buddy"):
            if "D" in p:
                self.filament_diameter = p["D"]
            else:
                replies.extend(
                    ("echo:; Filament settings (Disabled):",
                     f"echo:  M200 S0 D{self.filament_diameter:.2f}")
                )
        elif word == "M862.1" and fw == "prusa":
            if "Q" in command.upper().split()[1:] or command.upper().endswith("Q"):
                replies.append(f"{self.nozzle:.2f}")
        elif word == "M862.1" and fw == "buddy":
            if "Q" in command.upper():
                replies.append(f"echo:  M862.1 T0 P{self.nozzle:.2f} A0 F0")
        elif fw == "klipper" and word == self.nozzle_macro:
            replies.append(f"// nozzle_diameter: {self.nozzle:.3f}")
        elif self._is_known(word):
            pass
        else:
            replies.append(self._unknown(command, word))
        return state

    _KNOWN = frozenset(
        "M84 M18 M17 M106 M107 M110 M220 M221 M204 M205 M201 M203 M92 M117 M73 M300 M420 "
        "M500 M501 M502 M503 M851 M900 M104 M140 M21 M75 M76 M77 M80 M81 G21 G20 T0 M601 "
        "M602 M201 M907 M862.3 M862.5 M862.6 M115 M486".split()
    )

    def _is_known(self, word: str) -> bool:
        if word in self._KNOWN:
            return True
        if self.firmware == "klipper":
            return word in ("M110", "M112") or word.startswith("SET_") or word in (
                "PRINT_START", "PRINT_END", "BED_MESH_CALIBRATE", "TURN_OFF_HEATERS"
            )
        if word in ("M862.1", "M211", "M200", "M208"):
            return False
        return bool(re.fullmatch(r"[GMT]\d+(\.\d+)?", word))

    def _unknown(self, command: str, word: str) -> str:
        if self.firmware == "klipper":
            return f'// Unknown command:"{word}"'
        if self.firmware == "rrf":
            return f"Error: {word}: Command is not supported"
        return f'echo:Unknown command: "{command}"'

    def _area(self) -> str:
        x, y, z = self.build_volume
        box = f"min:{{x:0.00,y:0.00,z:0.00}},max:{{x:{x:.2f},y:{y:.2f},z:{z:.2f}}}"
        return f"area:{{full:{{{box}}},work:{{{box}}}}}"

    def _move_time(self, p: dict[str, float]) -> float:
        if "F" in p and p["F"] > 0:
            self._feed = p["F"]
        dist2 = 0.0
        for axis in "XYZE":
            if axis not in p:
                continue
            rel = self._relative_e if axis == "E" else self._relative
            target = self._pos[axis] + p[axis] if rel else p[axis]
            delta = target - self._pos[axis]
            self._pos[axis] = target
            if axis != "E" or dist2 == 0.0:
                dist2 += delta * delta
        return math.sqrt(dist2) / (self._feed / 60.0) / self.speedup

    def _progress(self, state: dict, now: float) -> bool:
        """Advance the head command; True once it has finished."""
        while self._planner and self._planner[0] <= now:
            self._planner.popleft()
        if "move" in state:
            if len(self._planner) >= _PLANNER_BLOCKS:
                return False
            start = self._planner[-1] if self._planner else now
            self._planner.append(max(start, now) + state.pop("move"))
            return True
        if state.get("drain") and self._planner:
            return False
        if "busy_for" in state:
            state["until"] = now + state.pop("busy_for")
            state["next_keepalive"] = now + self.keepalive
        if "heat" in state:
            heater = state["heat"]
            if abs(self._temp[heater] - self._target[heater]) <= 1.0:
                return True
            if now >= state.get("next_keepalive", 0.0):
                state["next_keepalive"] = now + min(self.keepalive, 1.0)
                self._send(self._temps_text() + " W:?")
            return False
        until = state.get("until")
        if until is not None and now < until:
            if "next_keepalive" in state and now >= state["next_keepalive"]:
                state["next_keepalive"] = now + self.keepalive
                if self.firmware in ("marlin", "prusa", "buddy"):
                    self._send("echo:busy: processing")
            return False
        return True

    def _thermal(self, now: float) -> None:
        dt = (now - self._last_tick) * self.speedup
        self._last_tick = now
        for heater, rate in (("T", 4.0), ("B", 1.5)):
            target = self._target[heater]
            goal = max(target, _AMBIENT)
            current = self._temp[heater]
            step = rate * dt if goal > current else 0.05 * (current - goal) * dt + 0.5 * dt
            if goal > current:
                self._temp[heater] = min(goal, current + step)
            else:
                self._temp[heater] = max(goal, current - step)

    def _temps_text(self) -> str:
        t, b = self._temp["T"], self._temp["B"]
        tt, bt = self._target["T"], self._target["B"]
        if self.firmware == "klipper":
            return f"B:{b:.1f} /{bt:.1f} T0:{t:.1f} /{tt:.1f}"
        if self.firmware == "prusa":
            return (
                f"T:{t:.1f} /{tt:.1f} B:{b:.1f} /{bt:.1f} T0:{t:.1f} /{tt:.1f}"
                " @:0 B@:0 P:0.0 A:26.4"
            )
        if self.firmware == "rrf":
            return f"T:{t:.1f} /{tt:.1f} B:{b:.1f} /{bt:.1f}"
        return f"T:{t:.2f} /{tt:.2f} B:{b:.2f} /{bt:.2f} @:0 B@:0"
