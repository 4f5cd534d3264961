"""Streaming one job to the printer: the state machine behind ``PrinterHost.stream``.

See :mod:`printer.host` for the delivery guarantee and how it is kept (line numbers
and checksums, one rewind per resend request, lost-``ok`` recovery by an ``M105``
tickle and probing, ping-pong / buffered / auto modes). The streamer talks to the
printer only through its :class:`~printer.host.PrinterHost`, which owns the port.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

from printer.control import PrintControl
from printer.errors import PrinterError, PrinterTimeout, StreamCancelled
from printer.firmware import keepalive_forms
from printer.gcode import command_word, frame
from printer.replies import Reply, parse_reply
from printer.waits import LongWaits

if TYPE_CHECKING:
    from printer.host import PrinterHost

#: Called with ``{"T": (current, target), "B": (...)}`` (°C; target None when unknown)
#: whenever the printer reports temperatures during a stream.
TemperatureCallback = Callable[[dict[str, tuple[float, float | None]]], None]


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


class Streamer(LongWaits):
    """The state machine of one stream (see the module docstring; long-running commands
    and temperature reports: :mod:`printer.waits`)."""

    def __init__(self, host: PrinterHost, commands: list[str],
                 progress: Callable[[int, int], None] | None,
                 cancel: threading.Event | None, control: PrintControl | None = None,
                 temperatures: TemperatureCallback | None = None) -> None:
        self.host = host
        self.temperatures = temperatures
        self.commands = commands
        self.total = len(commands)
        #: Lines up to this one may be sent (held below ``total`` while pausing).
        self.limit = self.total
        self.control = control or PrintControl()
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
        self.keepalives = keepalive_forms(host.flavour)
        self.last_ack = time.monotonic()  # when the oldest unacknowledged line last changed
        self.wait_life = False  # a keep-alive arrived since last_ack
        self.held_probe = False  # a keep-alive arrived while a probe M105 was outstanding
        self.targets: dict[str, float] = {}

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
        self.last_ack = time.monotonic()
        self.wait_life = False

    def drop_inflight_from(self, n: int) -> None:
        """Forget in-flight entries with N >= n (they will be sent again)."""
        while self.inflight and self.inflight[-1][0] >= n:
            entry = self.inflight.pop()
            self.inflight_bytes -= entry[1]

    def ack_through(self, n: int) -> None:
        while self.inflight and self.inflight[0][0] <= n:
            self.pop_inflight()

    def can_send(self) -> bool:
        if self.tickle_tries or self.next_n > self.limit:
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
            len(self.inflight) < self.host.queue_size
            and self.inflight_bytes + size <= self.host.rx_buffer
        )

    def send_next(self) -> None:
        n = self.next_n
        if not self.inflight:
            self.last_ack = time.monotonic()
            self.wait_life = False
        text = self.frame_of(n)
        self.host.write(text)
        self.inflight.append([n, len(text) + 1])
        self.inflight_bytes += len(text) + 1
        self.max_sent = max(self.max_sent, n)
        self.next_n += 1

    # ---------------------------------------------------------------- main loop
    def run(self) -> StreamResult:
        host = self.host
        started = time.monotonic()
        bytes_before = host.bytes_sent
        self.sync_line_numbers()
        self.last_life = time.monotonic()
        try:
            while self.next_n <= self.total or self.inflight:
                if self.cancel is not None and self.cancel.is_set():
                    self.cancelled()
                self.control.step(self)
                while self.can_send():
                    self.send_next()
                now = time.monotonic()
                wait = min(self.host.timeout - (now - self.last_life), 0.25)
                if self.hold_until > now:
                    wait = min(wait, self.hold_until - now)
                if self.inflight and not self.nudged and self.checks_lines:
                    wait = min(wait, self.last_life + host.nudge - now)
                line = host.next_line(max(wait, 0.0))
                if line is None:
                    quiet = time.monotonic() - self.last_life
                    if quiet >= self.host.timeout:
                        self.on_timeout()
                    elif quiet >= host.nudge and self.inflight and not self.nudged:
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
            bytes_sent=host.bytes_sent - bytes_before,
            mode=self.mode,
            resends=self.resends,
            resends_ignored=self.resends_ignored,
            timeouts=self.timeouts,
        )

    def sync_line_numbers(self) -> None:
        """``N0 M110 N0``: the firmware's next expected line number becomes 1."""
        host = self.host
        for _attempt in range(self.host.retries + 1):
            host.write(frame(0, "M110 N0"))
            deadline = time.monotonic() + host.timeout
            while time.monotonic() < deadline:
                line = host.next_line(deadline - time.monotonic())
                if line is None:
                    continue
                reply = parse_reply(line)
                host.raise_if_fatal(reply, "before the stream started")
                if reply.kind in ("resend", "line_error"):
                    # The M110 was refused (noise): the ok that follows the Resend is
                    # not its acknowledgement, and the firmware still expects the old
                    # line numbers. Let that ok go by, then send the M110 again.
                    self.drain_quiet()
                    break
                if reply.kind == "ok" and not reply.temps:
                    self.drain_quiet()
                    return
        raise PrinterTimeout(f"the printer on {host.port} does not acknowledge M110")

    def drain_quiet(self) -> None:
        """Let trailing replies to the M110 (e.g. a Resend + ok pair) arrive and go."""
        while True:
            line = self.host.next_line(0.02)
            if line is None:
                return
            self.host.raise_if_fatal(parse_reply(line), "before the stream started")

    def on_line(self, line: str) -> None:
        reply = parse_reply(line)
        kind = reply.kind
        after_resend, self.after_resend = self.after_resend, False
        if kind in ("start", "fatal"):
            self.host.raise_if_fatal(reply, "during the print")
        if reply.temps:
            self.note_temperatures(reply.temps)
        if kind in ("comment", "busy", "ok"):
            self.control.on_reply(self, reply)  # host actions, M600 waiting for the user
        if kind in ("temperature", "busy") and not self.keeps_alive(reply):
            return  # an auto-report: not a sign that our lines are moving
        if kind == "other" and reply.text == "wait":
            self.on_idle()
            return
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

    def on_ok(self, reply: Reply, after_resend: bool) -> None:
        if reply.temps:
            if self.inflight and command_word(self.commands[self.inflight[0][0] - 1]) == "M105":
                self.pop_inflight()
            elif self.tickle_tries:
                self.resync()
            return
        if self.host.advanced_ok and reply.number is not None:
            self.confirm(reply.number)
            if reply.number < self.next_n:
                self.ack_through(reply.number)
            return
        if after_resend:
            return  # Marlin's ok that follows "Resend:"; it acknowledges nothing
        if self.inflight:
            self.pop_inflight()

    def on_resend(self, wanted: int | None) -> None:
        """Act once on ``Resend: wanted``; swallow the echoes of it from lines already sent.

        Marlin answers every stale line still on the wire with the same request (or
        drops it with its RX buffer). So after acting, the host waits for the stale
        bytes' wire time plus ``resend_settle`` before resending; identical requests
        inside that window are echoes. A request after it is genuine (the resent copy
        was hit again), and acting on it twice is harmless: line numbers are checked.
        """
        if wanted is None or not self.checks_lines:
            return
        if self.tickle_tries and not self.probe_until:
            # Alive, and saying exactly where it stands: no need to wait for the tickle.
            self.tickle_tries = 0
        self.confirm(wanted - 1)
        if self.probe_until:
            # After a resync no ok is pending for earlier lines: wanted - 1 is the truth.
            self.ack_through(wanted - 1)
            if wanted > self.next_n and wanted - 1 <= self.max_sent:
                self.next_n = wanted
        elif wanted >= self.next_n:
            self.resends_ignored += 1  # nothing from wanted on is in flight
            return
        now = time.monotonic()
        if wanted == self.rewind_r and now < self.hold_until:
            self.resends_ignored += 1
            return
        self.resends += 1
        self.noise += 1.0
        stale = sum(size for n, size in self.inflight if n > wanted)
        self.drop_inflight_from(wanted)
        self.next_n = min(self.next_n, wanted)
        self.rewind_r = wanted
        # Nothing else on the wire (ping-pong): no echo can follow, resend at once.
        settle = stale * 10.0 / self.host.baud + self.host.resend_settle
        self.hold_until = now + settle if stale else 0.0

    def on_idle(self) -> None:
        """``wait``: the firmware (Repetier, OctoPrint's virtual printer) is idle with an
        empty queue. It is no sign that our lines move (it came once a second forever
        while an ``ok`` was lost, and the stream hung); with lines in flight it means
        their ``ok`` was lost, so the lost-``ok`` recovery starts now."""
        if self.inflight and not self.tickle_tries:
            self.on_timeout()

    def nudge(self) -> None:
        """Send a bare newline. If noise ate the end of our last line, the firmware is
        still waiting for it; the newline completes it, the checksum fails and a resend
        follows at once instead of after the timeout. An empty line is otherwise
        ignored (Marlin, Prusa, RepRapFirmware skip it without a reply)."""
        self.nudged = True
        self.host.write("")

    def on_timeout(self) -> None:
        host = self.host
        if self.waiting_on_long_command():
            return
        if self.tickle_tries > host.retries:
            raise PrinterTimeout(
                f"the printer on {host.port} stopped answering: no reply to M105 in "
                f"{host.timeout:g} s, {host.retries} retries"
            )
        self.tickle_tries += 1
        self.timeouts += 1
        self.last_life = time.monotonic()
        host.write("M105")

    def resync(self) -> None:
        """The tickle's reply arrived: every earlier line ran or never arrived."""
        self.tickle_tries = 0
        done = self.delivered()
        if done > self.resync_mark:
            self.resync_mark, self.stuck = done, 0
        else:
            self.stuck += 1
            if self.stuck > self.host.retries:
                raise PrinterTimeout(
                    f"the printer on {self.host.port} answers but never accepts line {done + 1} "
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
        host = self.host
        done = self.delivered()
        self.break_heat_wait()
        deadline = time.monotonic() + host.timeout
        while self.inflight and time.monotonic() < deadline:
            line = host.next_line(0.05)
            if line is not None:
                reply = parse_reply(line)
                if reply.kind == "ok" and not reply.temps:
                    self.on_ok(reply, False)
        host.drain(0.05)
        self.control.park_for_cancel(self)
        host.cooldown()
        raise StreamCancelled(
            f"print cancelled after {done} of {self.total} lines; heaters off, motors released"
        )
