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
  a timeout that busy keepalives extend; the host then sends an unnumbered ``M105``
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
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

from printer import replies as R
from printer.errors import (
    PortBusy,
    PortNotFound,
    PortPermission,
    PrinterDisconnected,
    PrinterError,
    PrinterHalted,
    PrinterReset,
    PrinterTimeout,
    StreamCancelled,
    WrongBaud,
)
from printer.gcode import clean_lines, command_word, frame
from printer.info import PrinterInfo

MODES = ("auto", "ping-pong", "buffered")
DEFAULT_NOZZLE = 0.4
DEFAULT_FILAMENT = 1.75
COOLDOWN = ("M104 S0", "M140 S0", "M107", "M84")

# Prusa printers that do not answer M211: nominal build volumes (mm) by MACHINE_TYPE.
_PRUSA_VOLUMES = {
    "prusa i3 mk3s": [250.0, 210.0, 210.0],
    "prusa i3 mk3": [250.0, 210.0, 210.0],
    "prusa i3 mk2.5s": [250.0, 210.0, 210.0],
    "prusa-mini": [180.0, 180.0, 180.0],
    "prusa-mk4": [250.0, 210.0, 220.0],
    "prusa-xl": [360.0, 360.0, 360.0],
}


@dataclass(frozen=True)
class StreamResult:
    """How a stream went. lines: commands delivered (all of them, on success);
    bytes_sent includes resends and tickles; seconds: wall time."""

    lines: int
    seconds: float
    bytes_sent: int
    mode: str
    resends: int
    resends_ignored: int
    timeouts: int

    def to_dict(self) -> dict:
        return asdict(self)


class _Hangup:
    def __init__(self, reason: str) -> None:
        self.reason = reason


_EOL = (9, 10, 13)


def flavour_of(firmware_name: str) -> str:
    """marlin / prusa / buddy / klipper / rrf / unknown from a FIRMWARE_NAME value."""
    low = firmware_name.lower()
    if "klipper" in low:
        return "klipper"
    if "reprapfirmware" in low:
        return "rrf"
    if "prusa-firmware-buddy" in low:
        return "buddy"
    if "prusa-firmware" in low:
        return "prusa"
    if "marlin" in low:
        return "marlin"
    return "unknown"


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
    def _write(self, text: str) -> None:
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

    def _next_line(self, timeout: float) -> str | None:
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

    def _fatal(self, reply: R.Reply, context: str) -> None:
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
                self._write(frame(0, "M110 N0"))
                sent_at = now
            line = self._next_line(min(0.2, deadline - now))
            if line is None:
                continue
            received += 1
            if _printable_ratio(line) < 0.9:
                garbage += 1
                continue
            reply = R.parse_reply(line)
            if reply.kind == "fatal":
                self._fatal(reply, "during the handshake")
            if reply.kind == "ok":
                if reply.number is not None or reply.queue_free is not None:
                    self.advanced_ok = True
                    if reply.queue_free:
                        self.queue_size = max(self.queue_size, reply.queue_free)
                break
            if reply.kind == "start":
                sent_at = 0.0  # the board just booted: say hello again
        self._drain(0.05)
        self._identify()

    def _drain(self, quiet: float) -> None:
        while self._next_line(quiet) is not None:
            pass

    def query(self, command: str, timeout: float | None = None) -> list[str]:
        """Send one unnumbered, read-only command; return every line up to and including
        its ``ok``. Line noise can eat the command: it is re-sent up to ``retries``
        times, then PrinterTimeout. Not for use while streaming.
        """
        wait = self.timeout if timeout is None else timeout
        for attempt in range(self.retries + 1):
            # A leading newline ends whatever half line noise may have left behind.
            self._write(command if attempt == 0 else "\n" + command)
            out: list[str] = []
            deadline = time.monotonic() + wait
            while True:
                line = self._next_line(deadline - time.monotonic())
                if line is None:
                    if time.monotonic() >= deadline:
                        break
                    continue
                reply = R.parse_reply(line)
                self._fatal(reply, f"answering {command}")
                if reply.kind == "busy" or (reply.kind == "temperature" and reply.waiting):
                    deadline = time.monotonic() + wait
                out.append(line)
                if reply.kind == "ok":
                    return out
        raise PrinterTimeout(f"no answer to {command} from {self.port} in {wait:g} s")

    def _identify(self) -> None:
        lines = self.query("M115")
        for line in lines:
            cap = R.parse_capability(line)
            if cap:
                self.capabilities[cap[0]] = cap[1]
                continue
            if "area:" in line:
                self.area = R.parse_area(line)
                continue
            fields = R.parse_firmware_fields(line)
            if "FIRMWARE_NAME" in fields:
                self.fields = fields
        self.firmware = self.fields.get("FIRMWARE_NAME", "")
        self.flavour = flavour_of(self.firmware)
        if self.capabilities.get("ADVANCED_OK"):
            self.advanced_ok = True

    # ------------------------------------------------------------------ capabilities
    def query_info(self) -> PrinterInfo:
        """Ask the printer what it is (read-only queries; never ``M862.1 P``)."""
        nozzle, nozzle_source = None, None
        if self.flavour in ("prusa", "buddy", "marlin"):
            for line in self.query("M862.1 Q"):
                value = R.parse_nozzle_reply(line)
                if value is not None:
                    nozzle, nozzle_source = value, "M862.1"
                    break
        if nozzle is None and self.nozzle_macro:
            for line in self.query(self.nozzle_macro):
                value = R.parse_nozzle_reply(line)
                if value is not None:
                    nozzle, nozzle_source = value, f"macro:{self.nozzle_macro}"
                    break
        if nozzle is None:
            if self.nozzle_fallback is not None:
                nozzle, nozzle_source = float(self.nozzle_fallback), "config"
            else:
                nozzle, nozzle_source = DEFAULT_NOZZLE, "default"

        volume, volume_source = None, None
        if self.flavour == "rrf":
            for line in self.query("M208"):
                limits = R.parse_axis_limits(line)
                if limits:
                    volume, volume_source = _extent(limits), "M208"
        elif self.flavour != "klipper":
            for line in self.query("M211"):
                limits = R.parse_soft_endstops(line)
                if limits:
                    volume, volume_source = _extent(limits), "M211"
        if volume is None and self.area:
            box = self.area.get("work") or self.area.get("full")
            volume, volume_source = _extent(box), "M115 area"
        if volume is None:
            machine = self.fields.get("MACHINE_TYPE", "").lower()
            if machine in _PRUSA_VOLUMES:
                volume, volume_source = list(_PRUSA_VOLUMES[machine]), "machine type"

        filament, filament_source = None, None
        if self.flavour in ("marlin", "buddy", "prusa", "unknown"):
            for line in self.query("M200"):
                value = R.parse_filament_diameter(line)
                if value is not None:
                    filament, filament_source = value, "M200"
        if filament is None:
            filament, filament_source = self.filament_fallback, "default"

        temps: dict[str, list[float | None]] = {}
        for line in self.query("M105"):
            for key, (cur, target) in R.parse_temperatures(line).items():
                temps[key] = [cur, target]

        return PrinterInfo(
            firmware=self.firmware or "unknown",
            flavour=self.flavour,
            nozzle_diameter=round(float(nozzle), 3),
            nozzle_source=nozzle_source,
            build_volume=volume,
            build_volume_source=volume_source,
            filament_diameter=round(float(filament), 3),
            filament_source=filament_source,
            capabilities=dict(self.capabilities),
            fields=dict(self.fields),
            temperatures=temps,
        )

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
        self._write("M112")

    def stream(
        self,
        lines: Sequence[str],
        *,
        progress: Callable[[int, int], None] | None = None,
        cancel: threading.Event | None = None,
    ) -> StreamResult:
        """Deliver the commands of ``lines`` (comments/blank lines dropped) exactly once,
        in order. Returns when the firmware has acknowledged every one; raises a
        PrinterError subclass otherwise (StreamCancelled after cooldown + motors off),
        whose ``lines_sent`` attribute counts the job's lines written to the port.
        """
        commands = clean_lines(lines)
        streamer = _Streamer(self, commands, progress, cancel)
        try:
            return streamer.run()
        except PrinterError as exc:
            # How many numbered lines went out on the wire before the failure: a caller
            # must treat a job with any line sent as possibly started (the firmware may
            # have run it even if no ``ok`` came back).
            exc.lines_sent = streamer.max_sent
            raise

    def _cooldown(self) -> None:
        for command in COOLDOWN:
            try:
                self.query(command)
            except PrinterTimeout:
                pass


def _extent(limits) -> list[float]:
    lo, hi = limits
    return [round(float(h) - float(l_), 3) for l_, h in zip(lo, hi, strict=True)]


class _Streamer:
    """The state machine of one stream (see the module docstring)."""

    def __init__(self, host: PrinterHost, commands: list[str], progress, cancel) -> None:
        self.h = host
        self.commands = commands
        self.total = len(commands)
        self.progress = progress
        self.cancel = cancel
        self.mode = host.chosen_mode()
        self.adaptive = host.mode == "auto" and self.mode == "buffered"
        self.noise = 0.0  # decaying count of recent resends
        self.checks_lines = host.flavour != "klipper"
        self.resend_has_ok = host.flavour not in ("prusa", "rrf", "klipper")
        self.frames: dict[int, str] = {}
        self.next_n = 1  # next line number to send; command i has N = i + 1
        self.inflight: deque[list[int]] = deque()  # [N, bytes]
        self.inflight_bytes = 0
        self.confirmed = 0  # firmware said it holds every line <= this
        self.tickle_tries = 0
        self.probe_until = 0
        self.rewind_r = 0
        self.hold_until = 0.0
        self.max_sent = 0
        self.resync_mark = 0
        self.nudged = False
        self.stuck = 0
        self.after_resend = False
        self.resends = 0
        self.resends_ignored = 0
        self.timeouts = 0
        self.last_life = time.monotonic()
        self.last_progress = 0.0
        self.reported = -1

    # ---------------------------------------------------------------- helpers
    def frame_of(self, n: int) -> str:
        text = self.frames.get(n)
        if text is None:
            text = frame(n, self.commands[n - 1])
            self.frames[n] = text
            if len(self.frames) > 4096:
                for old in [k for k in self.frames if k < n - 512]:
                    del self.frames[old]
        return text

    def delivered(self) -> int:
        return self.inflight[0][0] - 1 if self.inflight else self.next_n - 1

    def report(self, force: bool = False) -> None:
        if self.progress is None:
            return
        done = self.delivered()
        now = time.monotonic()
        if done != self.reported and (force or now - self.last_progress >= 0.05):
            self.reported = done
            self.last_progress = now
            self.progress(done, self.total)

    def noisy(self) -> bool:
        """In auto mode, fall back to one line in flight while resends are frequent:
        on a noisy line every error throws away the whole buffered window."""
        return self.adaptive and self.noise > 1.5

    def pop_inflight(self) -> None:
        n, size = self.inflight.popleft()
        self.inflight_bytes -= size
        self.noise *= 0.97

    def drop_inflight_from(self, n: int) -> None:
        """Forget in-flight entries with N >= n (they will be sent again)."""
        while self.inflight and self.inflight[-1][0] >= n:
            entry = self.inflight.pop()
            self.inflight_bytes -= entry[1]

    def ack_through(self, n: int) -> None:
        while self.inflight and self.inflight[0][0] <= n:
            self.pop_inflight()

    def can_send(self) -> bool:
        if self.tickle_tries or self.next_n > self.total:
            return False
        if self.probe_until and self.delivered() >= self.probe_until:
            self.probe_until = 0
        if self.hold_until and time.monotonic() < self.hold_until:
            return False
        if self.next_n <= self.probe_until or self.mode == "ping-pong" or self.noisy():
            return not self.inflight
        if not self.inflight:
            return True
        size = len(self.frame_of(self.next_n)) + 1
        return (
            len(self.inflight) < self.h.queue_size
            and self.inflight_bytes + size <= self.h.rx_buffer
        )

    def send_next(self) -> None:
        n = self.next_n
        text = self.frame_of(n)
        self.h._write(text)
        self.inflight.append([n, len(text) + 1])
        self.inflight_bytes += len(text) + 1
        self.max_sent = max(self.max_sent, n)
        self.next_n += 1

    # ---------------------------------------------------------------- main loop
    def run(self) -> StreamResult:
        h = self.h
        started = time.monotonic()
        bytes_before = h.bytes_sent
        self.sync_line_numbers()
        self.last_life = time.monotonic()
        try:
            while self.next_n <= self.total or self.inflight:
                if self.cancel is not None and self.cancel.is_set():
                    self.cancelled()
                while self.can_send():
                    self.send_next()
                now = time.monotonic()
                wait = min(self.h.timeout - (now - self.last_life), 0.25)
                if self.hold_until > now:
                    wait = min(wait, self.hold_until - now)
                if self.inflight and not self.nudged and self.checks_lines:
                    wait = min(wait, self.last_life + h.nudge - now)
                line = h._next_line(max(wait, 0.0))
                if line is None:
                    quiet = time.monotonic() - self.last_life
                    if quiet >= self.h.timeout:
                        self.on_timeout()
                    elif quiet >= h.nudge and self.inflight and not self.nudged:
                        self.nudge()
                    continue
                self.on_line(line)
                self.report()
        except PrinterError as exc:
            if isinstance(exc, StreamCancelled):
                raise
            raise type(exc)(f"{exc} (after {self.delivered()} of {self.total} lines)") from None
        self.report(force=True)
        return StreamResult(
            lines=self.total,
            seconds=time.monotonic() - started,
            bytes_sent=h.bytes_sent - bytes_before,
            mode=self.mode,
            resends=self.resends,
            resends_ignored=self.resends_ignored,
            timeouts=self.timeouts,
        )

    def sync_line_numbers(self) -> None:
        """``N0 M110 N0``: the firmware's next expected line number becomes 1."""
        h = self.h
        for _attempt in range(self.h.retries + 1):
            h._write(frame(0, "M110 N0"))
            deadline = time.monotonic() + h.timeout
            while time.monotonic() < deadline:
                line = h._next_line(deadline - time.monotonic())
                if line is None:
                    continue
                reply = R.parse_reply(line)
                h._fatal(reply, "before the stream started")
                if reply.kind in ("resend", "line_error"):
                    # The M110 was refused (noise): the ok that follows the Resend is
                    # not its acknowledgement, and the firmware still expects the old
                    # line numbers. Let that ok go by, then send the M110 again.
                    self.drain_quiet()
                    break
                if reply.kind == "ok" and not reply.temps:
                    self.drain_quiet()
                    return
        raise PrinterTimeout(f"the printer on {h.port} does not acknowledge M110")

    def drain_quiet(self) -> None:
        """Let trailing replies to the M110 (e.g. a Resend + ok pair) arrive and go."""
        while True:
            line = self.h._next_line(0.02)
            if line is None:
                return
            self.h._fatal(R.parse_reply(line), "before the stream started")

    def on_line(self, line: str) -> None:
        reply = R.parse_reply(line)
        kind = reply.kind
        after_resend, self.after_resend = self.after_resend, False
        if kind in ("start", "fatal"):
            self.h._fatal(reply, "during the print")
        if kind == "temperature" and not reply.waiting:
            return  # auto-report: not a sign that our lines are moving
        self.last_life = time.monotonic()
        self.nudged = False
        if kind == "ok":
            self.on_ok(reply, after_resend)
        elif kind == "resend":
            self.after_resend = self.resend_has_ok
            self.on_resend(reply.number)
        elif kind == "line_error" and reply.number is not None:
            self.confirm(reply.number)

    def confirm(self, n: int) -> None:
        """The firmware holds every line up to n (line numbers are checked)."""
        if self.checks_lines and n < self.next_n:
            self.confirmed = max(self.confirmed, n)

    def on_ok(self, reply: R.Reply, after_resend: bool) -> None:
        if reply.temps:
            if self.inflight and command_word(self.commands[self.inflight[0][0] - 1]) == "M105":
                self.pop_inflight()
            elif self.tickle_tries:
                self.resync()
            return
        if self.h.advanced_ok and reply.number is not None:
            self.confirm(reply.number)
            if reply.number < self.next_n:
                self.ack_through(reply.number)
            return
        if after_resend:
            return  # Marlin's ok that follows "Resend:"; it acknowledges nothing
        if self.inflight:
            self.pop_inflight()

    def on_resend(self, r: int | None) -> None:
        """Act once on ``Resend: r``; swallow the echoes of it from lines already sent.

        Marlin answers every stale line still on the wire with the same request (or
        drops it with its RX buffer). So after acting, the host waits for the stale
        bytes' wire time plus ``resend_settle`` before resending; identical requests
        inside that window are echoes. A request after it is genuine (the resent copy
        was hit again), and acting on it twice is harmless: line numbers are checked.
        """
        if r is None or not self.checks_lines:
            return
        if self.tickle_tries and not self.probe_until:
            # Alive, and saying exactly where it stands: no need to wait for the tickle.
            self.tickle_tries = 0
        self.confirm(r - 1)
        if self.probe_until:
            # After a resync no ok is pending for earlier lines: r - 1 is the truth.
            self.ack_through(r - 1)
            if r > self.next_n and r - 1 <= self.max_sent:
                self.next_n = r
        elif r >= self.next_n:
            self.resends_ignored += 1  # nothing from r on is in flight
            return
        now = time.monotonic()
        if r == self.rewind_r and now < self.hold_until:
            self.resends_ignored += 1
            return
        self.resends += 1
        self.noise += 1.0
        stale = sum(size for n, size in self.inflight if n > r)
        self.drop_inflight_from(r)
        self.next_n = min(self.next_n, r)
        self.rewind_r = r
        # Nothing else on the wire (ping-pong): no echo can follow, resend at once.
        self.hold_until = now + stale * 10.0 / self.h.baud + self.h.resend_settle if stale else 0.0

    def nudge(self) -> None:
        """Send a bare newline. If noise ate the end of our last line, the firmware is
        still waiting for it; the newline completes it, the checksum fails and a resend
        follows at once instead of after the timeout. An empty line is otherwise
        ignored (Marlin, Prusa, RepRapFirmware skip it without a reply)."""
        self.nudged = True
        self.h._write("")

    def on_timeout(self) -> None:
        h = self.h
        if self.tickle_tries > h.retries:
            raise PrinterTimeout(
                f"the printer on {h.port} stopped answering: no reply to M105 in "
                f"{h.timeout:g} s, {h.retries} retries"
            )
        self.tickle_tries += 1
        self.timeouts += 1
        self.last_life = time.monotonic()
        h._write("M105")

    def resync(self) -> None:
        """The tickle's reply arrived: every earlier line ran or never arrived."""
        self.tickle_tries = 0
        done = self.delivered()
        if done > self.resync_mark:
            self.resync_mark, self.stuck = done, 0
        else:
            self.stuck += 1
            if self.stuck > self.h.retries:
                raise PrinterTimeout(
                    f"the printer on {self.h.port} answers but never accepts line {done + 1} "
                    f"after {self.stuck} recoveries"
                )
        if not self.checks_lines:
            self.ack_through(self.next_n)
            return
        self.ack_through(self.confirmed)
        if self.inflight:
            first = self.inflight[0][0]
            last = self.inflight[-1][0]
            self.drop_inflight_from(first)
            self.next_n = first
            self.probe_until = last
            self.rewind_r = 0
            self.hold_until = 0.0

    def cancelled(self) -> None:
        h = self.h
        done = self.delivered()
        deadline = time.monotonic() + h.timeout
        while self.inflight and time.monotonic() < deadline:
            line = h._next_line(0.05)
            if line is not None:
                reply = R.parse_reply(line)
                if reply.kind == "ok" and not reply.temps:
                    self.on_ok(reply, False)
        h._drain(0.05)
        h._cooldown()
        raise StreamCancelled(
            f"print cancelled after {done} of {self.total} lines; heaters off, motors released"
        )
