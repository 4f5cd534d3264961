"""Print control of a running stream: pause, resume, cancel and emergency stop, asked
for by the user (any thread) or by the printer's host actions.

A :class:`PrintControl` is handed to ``PrinterHost.stream``; the streamer calls
:meth:`PrintControl.step` once per turn of its loop and :meth:`PrintControl.on_reply`
with each reply. What each request does:

* **pause**: stop taking new lines; every line already on the wire is delivered
  (resends included), then ``M400`` and ``M114`` give the position and E at the pause
  point, and the head retracts, lifts and parks (Marlin's default park point: X min + 10,
  Y max - 10, 20 mm up, capped by the build volume). Temperatures are left alone. The
  modes the file set (G90/G91, M82/M83, the feed rate) are read from the lines sent.
* **resume**: back over the part, down, un-retract, ``G92 E`` to the paused E, the
  file's modes and feed rate again, then the stream goes on at the next line: the lines
  the printer runs form the file exactly once.
* **cancel**: stop sending, retract and park, heaters off, fan off, motors off
  (``StreamCancelled``); never resumable.
* **stop**: ``M112`` at once (the emergency parser acts on it); ``EmergencyStopped``.

The pause and resume moves are sent unnumbered, as the host's own queries are (a
firmware checks the line numbers of the file's lines only); the file's line numbering
goes on after them unchanged.

Host actions: ``//action:pause`` / ``resume`` / ``cancel`` ask for the above;
``//action:paused`` / ``resumed`` say the firmware paused itself (M600, a filament
runout): the host stops sending until it resumes, and moves nothing.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from printer.errors import EmergencyStopped, PrinterTimeout
from printer.gcode import lex
from printer.replies import Reply, host_action, parse_position, parse_reply, waiting_for_user

if TYPE_CHECKING:
    from printer.stream import Streamer

ACTIONS = ("pause", "resume", "cancel", "stop")
#: How long M400 may take at a pause (the planner's moves finishing).
DRAIN_SECONDS = 120.0


@dataclass(frozen=True)
class ParkSettings:
    """retract: mm of filament pulled back at a pause; lift: mm the nozzle rises (capped
    by the build volume's height); build_volume: (x, y, z) mm or None (then the head is
    lifted but not moved in X/Y)."""

    retract: float = 2.0
    lift: float = 20.0
    build_volume: Sequence[float] | None = None
    travel_feed: float = 6000.0
    z_feed: float = 600.0
    retract_feed: float = 2400.0


@dataclass(frozen=True)
class PausePoint:
    """Where the print stopped: the logical position (None when the printer did not
    report it) and the modes the file had set."""

    position: dict[str, float] | None
    relative: bool
    relative_e: bool
    feed: float | None


def modal_state(commands: Sequence[str], upto: int) -> tuple[bool, bool, float | None,
                                                              dict[str, float]]:
    """(relative XYZ, relative E, last feed rate, tracked position) after
    ``commands[:upto]``, as Marlin keeps them: G90/G91 set every axis including E,
    M82/M83 then set E alone. The tracked position holds the axes the G-code itself fixes
    (an absolute move or G92, then relative moves), exactly; homing forgets them."""
    relative = relative_e = False
    feed = None
    pos: dict[str, float] = {}
    for command in commands[:upto]:
        lexed = lex(command)
        word = lexed.word
        if word in ("G0", "G1", "G2", "G3"):
            for axis, value in lexed.params:
                if axis == "F" and value:
                    feed = value
                elif axis in "XYZE" and value is not None:
                    rel = relative_e if axis == "E" else relative
                    if not rel:
                        pos[axis] = value
                    elif axis in pos:
                        pos[axis] += value
        elif word in ("G90", "G91"):
            relative = relative_e = word == "G91"
        elif word in ("M82", "M83"):
            relative_e = word == "M83"
        elif word == "G92":
            pos.update({a: v for a, v in lexed.params if a in "XYZE" and v is not None})
        elif word in ("G28", "G29"):
            pos = {a: v for a, v in pos.items() if a == "E"}
    return relative, relative_e, feed, pos


def pause_position(reported: dict[str, float] | None,
                   tracked: dict[str, float]) -> dict[str, float] | None:
    """The printer's M114 position, refined by the exactly known one where they agree to
    M114's rounding (it prints 2 decimals: a resumed absolute E must not drift)."""
    if reported is None:
        return None
    return {axis: tracked[axis] if axis in tracked and abs(tracked[axis] - value) <= 0.011
            else value for axis, value in reported.items()}


def pause_moves(point: PausePoint, park: ParkSettings) -> list[str]:
    """Retract, lift and park, leaving the heaters as they are."""
    moves = ["M83", f"G1 E{-park.retract:g} F{park.retract_feed:g}"]
    pos = point.position
    if pos is None:
        return moves  # nowhere known to come back to: do not move the head
    z = pos["Z"] + park.lift
    volume = park.build_volume
    if volume:
        z = max(pos["Z"], min(z, float(volume[2])))
    moves += ["G90", f"G1 Z{z:.3f} F{park.z_feed:g}"]
    if volume:
        moves.append(f"G1 X{10.0:g} Y{float(volume[1]) - 10.0:g} F{park.travel_feed:g}")
    return moves


def resume_moves(point: PausePoint, park: ParkSettings) -> list[str]:
    """Back to the pause point, un-retract, and the file's own modes again."""
    moves = []
    pos = point.position
    if pos is not None:
        moves += ["G90", f"G1 X{pos['X']:.3f} Y{pos['Y']:.3f} F{park.travel_feed:g}",
                  f"G1 Z{pos['Z']:.3f} F{park.z_feed:g}"]
    moves += ["M83", f"G1 E{park.retract:g} F{park.retract_feed:g}"]
    if pos is not None and "E" in pos:
        moves.append(f"G92 E{pos['E']:.5f}")
    moves.append("G91" if point.relative else "G90")
    moves.append("M83" if point.relative_e else "M82")
    if point.feed:
        moves.append(f"G1 F{point.feed:g}")
    return moves


class PrintControl:
    """Requests to one stream, from any thread; see the module docstring.

    on_state(state, why) is called from the streaming thread when the print becomes
    ``paused``, ``printing`` again, or ``waiting`` (M600 waiting for the user).
    """

    def __init__(self, park: ParkSettings | None = None,
                 on_state: Callable[[str, str], None] | None = None) -> None:
        self.park = park or ParkSettings()
        self.on_state = on_state
        self._lock = threading.Lock()
        self._asked: deque[tuple[str, str]] = deque()
        self.wake = threading.Event()
        self.state = "printing"  # printing | pausing | paused | paused_by_printer
        self.paused_by = ""
        self.cancelled_by: str | None = None
        self.point: PausePoint | None = None
        self.waiting = False

    # -- from any thread ------------------------------------------------------------------
    def ask(self, action: str, by: str = "the user") -> None:
        """Queue ``pause``, ``resume``, ``cancel`` or ``stop``; the stream acts on it."""
        if action not in ACTIONS:
            raise ValueError(f"unknown print control {action!r} (known: {', '.join(ACTIONS)})")
        with self._lock:
            self._asked.append((action, by))
        self.wake.set()

    def _take(self) -> tuple[str, str] | None:
        with self._lock:
            return self._asked.popleft() if self._asked else None

    def _tell(self, state: str, why: str) -> None:
        if self.on_state is not None:
            self.on_state(state, why)

    # -- from the streaming thread --------------------------------------------------------
    def on_reply(self, streamer: Streamer, reply: Reply) -> None:
        """A reply during the stream: host actions and M600's wait for the user."""
        if reply.kind == "busy" and waiting_for_user(reply.text):
            if not self.waiting:
                self.waiting = True
                self._tell("waiting", f"the printer waits for the user ({reply.text})")
            return
        if self.waiting and reply.kind == "ok":
            self.waiting = False
            self._tell("printing", "the printer goes on")
        action = host_action(reply.text) if reply.kind == "comment" else None
        if action is None:
            return
        name, detail = action
        by = f"the printer (//action:{name}{' ' + detail if detail else ''})"
        if name == "paused" and self.state == "printing":
            self.state, self.paused_by = "paused_by_printer", by
            streamer.limit = streamer.max_sent  # hold new lines; finish what is on the wire
            self._tell("paused", f"paused by {by}")
        elif name == "resumed" and self.state == "paused_by_printer":
            self.state = "printing"
            streamer.limit = streamer.total
            self._tell("printing", f"resumed by {by}")
        elif name in ("pause", "resume", "cancel"):
            self.ask(name, by)

    def step(self, streamer: Streamer) -> None:
        """Act on the requests asked for since the last turn of the stream loop."""
        if not self._asked and self.state == "printing":
            return  # the common case, once per line: no lock taken
        while (asked := self._take()) is not None:
            action, by = asked
            if action == "stop":
                streamer.host.emergency_stop()
                raise EmergencyStopped(f"emergency stop (M112) by {by}: the printer must be "
                                       "reset before it prints again")
            if action == "cancel":
                self.cancelled_by = by
                streamer.cancelled()
            if action == "pause" and self.state == "printing":
                self.state, self.paused_by = "pausing", by
                streamer.limit = streamer.max_sent
            elif action == "resume" and self.state == "pausing":
                self.state = "printing"  # not parked yet: just go on sending
                streamer.limit = streamer.total
            elif action == "resume" and self.state == "paused_by_printer":
                self.state = "printing"  # the user presses resume on the host: go on
                streamer.limit = streamer.total
                self._tell("printing", f"resumed by {by}")
        if self.state == "paused_by_printer" and not streamer.inflight:
            streamer.last_life = time.monotonic()  # idle on purpose: no lost-ok recovery
        if (self.state == "pausing" and not streamer.inflight and not streamer.tickle_tries
                and streamer.delivered() >= streamer.limit):
            self._pause(streamer)
            self._wait_paused(streamer)

    def _pause(self, streamer: Streamer) -> None:
        host = streamer.host
        host.query("M400", timeout=DRAIN_SECONDS)
        position = None
        for line in host.query("M114"):
            position = position or parse_position(line)
        relative, relative_e, feed, tracked = modal_state(streamer.commands, streamer.limit)
        self.point = PausePoint(pause_position(position, tracked), relative, relative_e, feed)
        for command in pause_moves(self.point, self.park):
            host.query(command)
        self.state = "paused"
        self._tell("paused", f"paused by {self.paused_by} after {streamer.delivered()} of "
                             f"{streamer.total} lines (retracted and parked, heaters on)")

    def _wait_paused(self, streamer: Streamer) -> None:
        """Paused: watch the port and the requests until resume, cancel or stop."""
        host = streamer.host
        while True:
            if streamer.cancel is not None and streamer.cancel.is_set():
                streamer.cancelled()
            with self._lock:
                head = self._asked[0][0] if self._asked else None
            if head in ("cancel", "stop"):
                return self.step(streamer)  # raises
            if head == "resume":
                self._take()
                break
            if head == "pause":
                self._take()
            line = host.next_line(0.1)
            if line is None:
                continue
            reply = parse_reply(line)
            host.raise_if_fatal(reply, "while paused")
            if reply.kind == "comment":
                self.on_reply(streamer, reply)
        self._resume(streamer)

    def _resume(self, streamer: Streamer) -> None:
        host = streamer.host
        for command in resume_moves(self.point, self.park):
            host.query(command)
        self.state = "printing"
        streamer.limit = streamer.total
        streamer.last_life = time.monotonic()
        streamer.nudged = False
        self._tell("printing", f"resumed at line {streamer.delivered() + 1} of {streamer.total}")

    def park_for_cancel(self, streamer: Streamer) -> None:
        """Retract, lift and park before the heaters go off (not when already parked)."""
        if self.state == "paused":
            return
        host = streamer.host
        try:
            host.query("M400", timeout=DRAIN_SECONDS)
            position = None
            for line in host.query("M114"):
                position = position or parse_position(line)
            for command in pause_moves(PausePoint(position, False, False, None), self.park):
                host.query(command)
        except PrinterTimeout:
            pass  # the cooldown that follows matters more than the park
