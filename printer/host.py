"""The serial host: one class owns the port and the Marlin line-protocol state.

Delivery guarantee: every command of a stream reaches the firmware exactly once and
in order, or ``stream`` raises. The mechanism:

* every line carries ``N<n>`` and an XOR checksum; firmware that checks them
  (Marlin, Prusa, Buddy, RepRapFirmware) accepts only ``N == last + 1``, so a copy
  of a line it already has is rejected, never re-executed;
* ``Resend: R`` / ``rs R`` rewinds to R once; the identical requests that every line
  already in flight triggers are swallowed (no resend storm); Marlin's
  ``ok`` after ``Resend:`` is consumed, Prusa MK3's missing one is not expected;
* a lost ``ok`` (or a silently dropped line, as RepRapFirmware does) is detected by
  a timeout that busy keepalives extend (while a long-running command such as a
  heat-up is in flight, silence is expected and bounded by ``long_command_timeout``
  instead: :mod:`printer.waits`); the host then sends an unnumbered ``M105``
  tickle. Its ``ok T:`` reply is a resynchronisation point: the firmware processes
  in order, so every line sent before it has either been executed or never arrived.
  The unresolved lines are then probed one at a time with their original line
  numbers, and the firmware's line-number check tells which is which. Retries are
  bounded; then :class:`PrinterTimeout`;
* Klipper ignores N and checksums and never resends: the tickle's reply alone
  proves everything before it was executed;
* ``start`` mid-job -> :class:`PrinterReset`; ``!!`` / ``kill()`` ->
  :class:`PrinterHalted`; a vanished port -> :class:`PrinterDisconnected`.

Two streaming modes: ``ping-pong`` (one line in flight) and ``buffered`` (at most
``rx_buffer`` unacknowledged bytes and ``queue_size`` lines in flight; with
ADVANCED_OK, ``ok N<n>`` tells exactly which lines have left the RX buffer).
``auto`` picks buffered for a recognised firmware and drops to one line in flight
while resends are frequent (a noisy line), returning to buffered when it is clean.
"""

from __future__ import annotations

import errno
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence

from printer.control import PrintControl
from printer.errors import (
    PortBusy,
    PortNotFound,
    PortPermission,
    PrinterDisconnected,
    PrinterError,
    PrinterHalted,
    PrinterReset,
    PrinterTimeout,
    WrongBaud,
)
from printer.gcode import clean_lines, frame
from printer.identify import query_info, read_identity
from printer.info import PrinterInfo
from printer.replies import Reply, parse_reply
from printer.stream import Streamer, StreamResult, TemperatureCallback

MODES = ("auto", "ping-pong", "buffered")
DEFAULT_FILAMENT = 1.75
COOLDOWN = ("M104 S0", "M140 S0", "M107", "M84")
#: Seconds a long-running command (a heat-up, homing, levelling) may take.
LONG_COMMAND_TIMEOUT = 900.0

class _Hangup:
    def __init__(self, reason: str) -> None:
        self.reason = reason


_EOL = (9, 10, 13)


def _printable_ratio(line: str) -> float:
    if not line:
        return 1.0
    good = sum(1 for ch in line if 32 <= ord(ch) < 127 or ch == "\t")
    return good / len(line)


class PrinterHost:
    """Owns one serial port and the line-protocol state of one printer.

    port: device path (e.g. ``/dev/ttyACM0`` or a ``/dev/serial/by-id`` link).
    mode: ``auto`` (buffered for a recognised firmware, else ping-pong),
    ``ping-pong`` or ``buffered``. nozzle_fallback: nozzle diameter (mm) used when
    the printer cannot tell (None: 0.4 mm, reported as ``default``). nozzle_macro:
    Klipper macro that prints the nozzle diameter. timeout: seconds without any
    sign of life before the lost-``ok`` recovery starts; retries: tickles before
    giving up. resend_settle: extra seconds to let echoes of a resend request
    arrive before resending (USB-serial latency). nudge: seconds of silence after
    which a bare newline is sent once, to finish a line whose newline noise ate.
    rx_buffer / queue_size: the
    firmware's RX buffer bytes and command queue length (Marlin defaults 128 and 4).
    long_command_timeout: seconds a long-running command (M109, M190, G28, G29, M400...)
    may take before the host gives up; while one runs, silence is not a lost ``ok``
    (see :mod:`printer.waits`).
    """

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        *,
        mode: str = "auto",
        nozzle_fallback: float | None = None,
        nozzle_macro: str | None = None,
        timeout: float = 4.0,
        retries: int = 4,
        handshake_timeout: float = 5.0,
        resend_settle: float = 0.01,
        nudge: float = 0.1,
        rx_buffer: int = 128,
        queue_size: int = 4,
        filament_fallback: float = DEFAULT_FILAMENT,
        long_command_timeout: float = LONG_COMMAND_TIMEOUT,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
        self.port = os.fspath(port)
        self.baud = int(baud)
        self.mode = mode
        self.nozzle_fallback = nozzle_fallback
        self.nozzle_macro = nozzle_macro
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.resend_settle = float(resend_settle)
        self.nudge = float(nudge)
        self.handshake_timeout = float(handshake_timeout)
        self.rx_buffer = int(rx_buffer)
        self.queue_size = int(queue_size)
        self.filament_fallback = float(filament_fallback)
        self.long_command_timeout = float(long_command_timeout)

        self.firmware = ""
        self.flavour = "unknown"
        self.fields: dict[str, str] = {}
        self.capabilities: dict[str, bool] = {}
        self.area: dict = {}
        self.advanced_ok = False
        self.bytes_sent = 0
        self._serial = None
        self._lines: queue.Queue = queue.Queue()
        self._reader: threading.Thread | None = None
        self._closing = threading.Event()
        self._write_lock = threading.Lock()
        self._last_port_check = 0.0
        #: Bytes received that no printer sends (8-bit or control): wrong baud rate.
        self.noise_bytes = 0

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> PrinterHost:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def connect(self) -> None:
        """Open the port exclusively and handshake (``M110 N0``, then ``M115``)."""
        self._open()
        try:
            self._handshake()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Release the port (idempotent)."""
        self._closing.set()
        ser, self._serial = self._serial, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port must not raise
                pass
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=2)
        self._reader = None

    def _open(self) -> None:
        import serial

        if not os.path.exists(self.port):
            raise PortNotFound(
                f"no serial port at {self.port} (is the printer plugged in and switched on?)"
            )
        try:
            ser = serial.Serial(self.port, self.baud, timeout=0.05, exclusive=True)
        except serial.SerialException as exc:
            code = getattr(exc, "errno", None)
            text = str(exc)
            if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
                raise PortPermission(
                    f"permission denied on {self.port}; add your user to the 'dialout' group "
                    "(sudo usermod -aG dialout $USER) and log in again"
                ) from None
            if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY) or "lock" in text:
                raise PortBusy(
                    f"{self.port} is busy: another program (OctoPrint, a second preflight?) "
                    "has it open"
                ) from None
            if code == errno.ENOENT:
                raise PortNotFound(f"no serial port at {self.port}") from None
            raise PrinterDisconnected(f"cannot open {self.port}: {text}") from None
        except OSError as exc:
            raise PrinterDisconnected(f"cannot open {self.port}: {exc.strerror}") from None
        self._serial = ser
        try:
            ser.reset_input_buffer()
        except Exception:  # noqa: BLE001
            pass
        self._closing.clear()
        self._lines = queue.Queue()
        self._reader = threading.Thread(target=self._read_loop, name="printer-reader", daemon=True)
        self._reader.start()

    def _read_loop(self) -> None:
        ser = self._serial
        buf = bytearray()
        while not self._closing.is_set() and ser is not None:
            try:
                data = ser.read(max(1, ser.in_waiting))
            except Exception as exc:  # noqa: BLE001 - any read failure means the port is gone
                if not self._closing.is_set():
                    self._lines.put(_Hangup(str(exc)))
                return
            if not data:
                continue
            self.noise_bytes += sum(1 for b in data if b >= 128 or (b < 32 and b not in _EOL))
            buf += data
            while True:
                cut = buf.find(b"\n")
                if cut < 0:
                    break
                raw = bytes(buf[:cut])
                del buf[: cut + 1]
                self._lines.put(raw.decode("ascii", "replace").strip("\r\x00"))
            if len(buf) > 4096:  # no newline in 4 kB: noise; hand it over as one "line"
                self._lines.put(bytes(buf).decode("ascii", "replace"))
                buf.clear()

    # ------------------------------------------------------------------ I/O helpers
    def write(self, text: str) -> None:
        ser = self._serial
        if ser is None:
            raise PrinterDisconnected(f"not connected to {self.port}")
        data = (text + "\n").encode("ascii", "replace")
        try:
            with self._write_lock:
                ser.write(data)
        except Exception as exc:  # noqa: BLE001
            raise PrinterDisconnected(
                f"lost the printer on {self.port} while writing (unplugged? {exc})"
            ) from None
        self.bytes_sent += len(data)

    def next_line(self, timeout: float) -> str | None:
        """The next received line, or None after ``timeout`` s; raises on hang-up."""
        try:
            item = self._lines.get(timeout=max(0.0, timeout))
        except queue.Empty:
            self._check_port_present()
            return None
        if isinstance(item, _Hangup):
            raise PrinterDisconnected(
                f"lost the printer on {self.port} (unplugged or powered off?)"
            )
        return item

    def _check_port_present(self) -> None:
        now = time.monotonic()
        if now - self._last_port_check < 0.5:
            return
        self._last_port_check = now
        if not os.path.exists(self.port):
            raise PrinterDisconnected(f"{self.port} disappeared (printer unplugged?)")

    def raise_if_fatal(self, reply: Reply, context: str) -> None:
        if reply.kind == "start":
            raise PrinterReset(f"the printer reset itself {context}; the job cannot continue")
        if reply.kind == "fatal":
            raise PrinterHalted(f"the printer halted {context}: {reply.text}")

    # ------------------------------------------------------------------ handshake
    def _handshake(self) -> None:
        deadline = time.monotonic() + self.handshake_timeout
        garbage = 0
        received = 0
        sent_at = 0.0
        while True:
            now = time.monotonic()
            if now >= deadline:
                if garbage or self.noise_bytes:
                    raise WrongBaud(
                        f"only garbage from {self.port} at {self.baud} baud; the baud rate is "
                        "probably wrong (try 115200 or 250000)"
                    )
                raise PrinterTimeout(
                    f"no reply from {self.port} at {self.baud} baud in "
                    f"{self.handshake_timeout:g} s (is it a printer, and is the baud rate right?)"
                )
            if now - sent_at > 1.0:
                self.write(frame(0, "M110 N0"))
                sent_at = now
            line = self.next_line(min(0.2, deadline - now))
            if line is None:
                continue
            received += 1
            if _printable_ratio(line) < 0.9:
                garbage += 1
                continue
            reply = parse_reply(line)
            if reply.kind == "fatal":
                self.raise_if_fatal(reply, "during the handshake")
            if reply.kind == "ok":
                if reply.number is not None or reply.queue_free is not None:
                    self.advanced_ok = True
                    if reply.queue_free:
                        self.queue_size = max(self.queue_size, reply.queue_free)
                break
            if reply.kind == "start":
                sent_at = 0.0  # the board just booted: say hello again
        self.drain(0.05)
        self._identify()

    def drain(self, quiet: float) -> None:
        while self.next_line(quiet) is not None:
            pass

    def query(self, command: str, timeout: float | None = None) -> list[str]:
        """Send one unnumbered, read-only command; return every line up to and including
        its ``ok``. Line noise can eat the command: it is re-sent up to ``retries``
        times, then PrinterTimeout. Not for use while streaming.
        """
        wait = self.timeout if timeout is None else timeout
        for attempt in range(self.retries + 1):
            # A leading newline ends whatever half line noise may have left behind.
            self.write(command if attempt == 0 else "\n" + command)
            out: list[str] = []
            deadline = time.monotonic() + wait
            while True:
                line = self.next_line(deadline - time.monotonic())
                if line is None:
                    if time.monotonic() >= deadline:
                        break
                    continue
                reply = parse_reply(line)
                self.raise_if_fatal(reply, f"answering {command}")
                if reply.kind == "busy" or (reply.kind == "temperature" and reply.waiting):
                    deadline = time.monotonic() + wait
                out.append(line)
                if reply.kind == "ok":
                    return out
        raise PrinterTimeout(f"no answer to {command} from {self.port} in {wait:g} s")

    def _identify(self) -> None:
        identity = read_identity(self.query("M115"))
        self.fields = identity.fields
        self.capabilities = identity.capabilities
        self.area = identity.area
        self.firmware = identity.firmware
        self.flavour = identity.family
        if self.capabilities.get("ADVANCED_OK"):
            self.advanced_ok = True

    def query_info(self) -> PrinterInfo:
        """Ask the printer what it is (read-only queries; never ``M862.1 P``)."""
        return query_info(self)

    # ------------------------------------------------------------------ streaming
    def chosen_mode(self) -> str:
        """The streaming mode ``auto`` resolves to for this printer."""
        if self.mode != "auto":
            return self.mode
        # RepRapFirmware drops a bad line without a word; with one line in flight the
        # timeout that follows can only mean that line, so ping-pong is the safe choice.
        return "buffered" if self.flavour not in ("unknown", "rrf") else "ping-pong"

    def emergency_stop(self) -> None:
        """Send ``M112`` now (Marlin's emergency parser acts on it immediately)."""
        self.write("M112")

    def stream(
        self,
        lines: Sequence[str],
        *,
        progress: Callable[[int, int], None] | None = None,
        cancel: threading.Event | None = None,
        control: PrintControl | None = None,
        temperatures: TemperatureCallback | None = None,
    ) -> StreamResult:
        """Deliver the commands of ``lines`` (comments/blank lines dropped) exactly once,
        in order. Returns when the firmware has acknowledged every one; raises a
        PrinterError subclass otherwise (StreamCancelled after cooldown + motors off),
        whose ``lines_sent`` attribute counts the job's lines written to the port.
        ``control``: pause / resume / cancel / emergency stop while it runs (see
        :mod:`printer.control`); the printer's host actions are obeyed either way.
        ``temperatures`` is called with ``{"T": (current, target), "B": ...}`` (°C)
        whenever the printer reports temperatures (while heating, about once a second).
        """
        commands = clean_lines(lines)
        streamer = Streamer(self, commands, progress, cancel, control, temperatures)
        try:
            return streamer.run()
        except PrinterError as exc:
            # How many numbered lines went out on the wire before the failure: a caller
            # must treat a job with any line sent as possibly started (the firmware may
            # have run it even if no ``ok`` came back).
            exc.lines_sent = streamer.max_sent
            raise

    def cooldown(self) -> None:
        for command in COOLDOWN:
            try:
                self.query(command)
            except PrinterTimeout:
                pass
