"""The virtual printer's serial side: a real pseudo-terminal, paced like a UART.

Host bytes reach the firmware at ``baud / 10`` bytes per second through a
``rx_buffer``-byte receive buffer that loses bytes on overflow; the firmware only
drains it while its command queue has room. Here too: byte corruption (noise), a
baud-rate mismatch (what the host set on the tty differs from ours: both sides see
garbage), Marlin's emergency parser (M112 acts on arrival), and hang-ups with an
optional come-back on a new pty whose ``link`` symlink is re-pointed.
"""

from __future__ import annotations

import os
import random
import select
import termios
import threading
import time
import tty
from collections import deque

from printer.gcode import lex
from printer.virtual.faults import Faults
from printer.virtual.firmware import FirmwareModel, MachineSettings
from printer.virtual.profiles import FIRMWARES, PROFILES

_BAUD_CONSTANTS = {
    9600: "B9600", 19200: "B19200", 38400: "B38400", 57600: "B57600",
    115200: "B115200", 230400: "B230400", 460800: "B460800", 500000: "B500000",
    921600: "B921600", 1000000: "B1000000",
}
_MAX_LINE = 200


class VirtualPrinter:
    """A simulated printer on a pty; see the package docstring for what it models.

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
        if firmware not in PROFILES:
            raise ValueError(f"unknown firmware {firmware!r}; choose one of {', '.join(FIRMWARES)}")
        profile = PROFILES[firmware]
        self.firmware = firmware
        self.baud = int(baud)
        self.log_path = os.fspath(log_path) if log_path else None
        self.link = os.fspath(link) if link else None
        self.rx_size = int(rx_buffer)
        faults = faults or Faults()
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
        self._rng = random.Random(faults.seed)
        settings = MachineSettings(
            nozzle=float(nozzle), speedup=float(speedup), queue_size=int(queue_size),
            advanced_ok=profile.advanced_ok if advanced_ok is None else advanced_ok,
            build_volume=tuple(float(v) for v in build_volume), keepalive=float(keepalive),
            nozzle_macro=nozzle_macro.upper())
        self.machine = FirmwareModel(profile, self, self._rng, self.stats, settings, faults,
                                     float(filament_diameter))
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
        self.reset_wire()

    # ----------------------------------------------------------------- public API
    @property
    def faults(self) -> Faults:
        """The faults in force; may be replaced while running."""
        return self.machine.faults

    @faults.setter
    def faults(self, faults: Faults) -> None:
        self.machine.faults = faults

    @property
    def executed_numbered(self) -> list[tuple[int | None, str]]:
        """Executed commands with their line number (None for an unnumbered line)."""
        return self.machine.executed_numbered

    @property
    def executed(self) -> list[str]:
        """Executed commands (without N/checksum), in execution order."""
        with self._lock:
            return [cmd for _, cmd in self.machine.executed_numbered]

    @property
    def undetected_corruptions(self) -> list[int]:
        """Line numbers accepted although noise changed the command (checksum collisions)."""
        return self.machine.undetected_corruptions

    @property
    def nozzle(self) -> float:
        return self.machine.settings.nozzle

    @property
    def build_volume(self) -> tuple[float, float, float]:
        return self.machine.settings.build_volume

    def start(self) -> str:
        """Open the pty and start the serving thread; return the pty slave path.

        With ``link``, a symlink at that path points to the slave (and is re-pointed
        after a reconnect); ``port`` is the path a host should open (link or slave).
        """
        if self.log_path:
            self.machine.log = open(self.log_path, "a", buffering=1, encoding="utf-8")  # noqa: SIM115
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
        if self.machine.log is not None:
            self.machine.log.close()
            self.machine.log = None

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

    # ----------------------------------------------------------------- the firmware's wire
    def reset_wire(self) -> None:
        """Nothing in flight, nothing buffered (power-on or a board reset)."""
        self._wire = bytearray()
        self._wire_next = 0.0
        self._wire_last = 0.0
        self._rx: deque[int] = deque()
        self._rx_orig: deque[int] = deque()
        self._line = bytearray()
        self._line_orig = bytearray()
        self._em_line = bytearray()

    def clear_receive_buffer(self) -> None:
        self._rx.clear()
        self._rx_orig.clear()

    def hang_up(self) -> None:
        """The port goes away; it comes back after ``reconnect_after`` s if set."""
        self._close_pty()
        if self.faults.reconnect_after is not None:
            threading.Timer(self.faults.reconnect_after, self._reconnect).start()

    def _reconnect(self) -> None:
        if self._stop.is_set():
            return
        with self._lock:
            self.reset_wire()
            self.machine.reset(time.monotonic())
            self.machine.numbered_done = -10**9
            self._open_pty()

    def send(self, text: str) -> None:
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
        host = {getattr(termios, n, None): b for b, n in _BAUD_CONSTANTS.items()}.get(speed)
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
                except OSError:
                    data = b""
                if data:
                    if not self._wire:
                        self._wire_next = max(now, self._wire_last + byte_time)
                    self._wire += data
            with self._lock:
                self._deliver(now, byte_time)
                self._receive()
                self.machine.tick(now)

    def _next_wakeup(self, now: float, byte_time: float) -> float:
        wake = 0.05
        if self._wire:
            wake = min(wake, max(0.0, self._wire_next - now) + 4 * byte_time)
        current = self.machine.current
        if current is not None and "until" in current:
            wake = min(wake, max(0.0, current["until"] - now))
        if self.machine.queue or self._rx:
            wake = min(wake, 0.002)
        return max(wake, 0.0)

    def _deliver(self, now: float, byte_time: float) -> None:
        """Move the bytes whose wire time has come into the receive buffer."""
        if not self._wire or now < self._wire_next:
            return
        n = min(len(self._wire), int((now - self._wire_next) / byte_time) + 1)
        chunk = bytes(self._wire[:n])
        del self._wire[:n]
        self._wire_next += n * byte_time
        self._wire_last = self._wire_next - byte_time
        self.stats["bytes_received"] += n
        if self.machine.halted:
            return
        if self.faults.garbage or self._baud_mismatch():
            # At the wrong speed our bytes are noise to it and its replies noise to us.
            if b"\n" in chunk:
                self.send("echo:Unknown command: \"\"")
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
        """Marlin's emergency parser: M112 and M108 act as soon as their line arrives."""
        if byte in (10, 13):
            line = self._em_line.decode("ascii", "replace")
            self._em_line.clear()
            if "112" in line and lex(line).word == "M112":
                self.machine.halt("M112")
            elif "108" in line and lex(line).word == "M108":
                self.machine.break_heat_wait()
        elif len(self._em_line) < _MAX_LINE:
            self._em_line.append(byte)

    def _receive(self) -> None:
        """Hand complete lines from the receive buffer to the firmware while it has room."""
        machine = self.machine
        if machine.halted:
            return
        while self._rx and machine.has_room():
            byte = self._rx.popleft()
            orig = self._rx_orig.popleft()
            if byte in (10, 13):
                if self._line:
                    raw = self._line.decode("latin-1")  # byte for byte: noise stays noise
                    sent = self._line_orig.decode("latin-1")
                    changed = raw != sent and lex(raw).command != lex(sent).command
                    self._line.clear()
                    self._line_orig.clear()
                    machine.receive_line(raw.strip(), changed)
            elif len(self._line) < _MAX_LINE:
                self._line.append(byte)
                self._line_orig.append(orig)
