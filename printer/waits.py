"""Long-running commands in a stream: heat-ups, homing, levelling, waits.

M109/M190/M191/M116, G28/G29/G32/G34, M400, M600 and a long G4 (the table is
:func:`printer.firmware.long_command_wait`) may hold the firmware for minutes before
it answers ``ok``. While one is in flight the host must neither give up nor mistake
the wait for a lost ``ok``. What the firmware says meanwhile depends on the family
(:func:`printer.firmware.keepalive_forms`): Marlin sends ``echo:busy`` and ``W:``
temperature lines, Prusa MK3 ``T:… E:0 W:…``, Klipper bare ``B:… /… T0:… /…`` lines
once a second, RepRapFirmware nothing at all.

The rules, with ``last_ack`` the time the oldest unacknowledged line last changed:

* a keep-alive of the family's forms is a sign of life (while a long command is in
  flight, for Klipper's bare lines, which look like any temperature report);
* silence while a long command is in flight, no keep-alive came since ``last_ack``
  and the family may stay silent through it (RRF heating, Klipper homing): one
  unnumbered ``M105`` probe is sent and then the host waits. The firmware queues
  the probe behind the command, so it costs nothing while the command runs; if the
  command has in fact finished and its ``ok`` was lost (or the ``ok`` of a line
  before it), the probe's reply resynchronises within seconds, as for any lost ``ok``;
* silence after keep-alives, or where the family always sends them
  (:func:`printer.firmware.keepalives_promised`): the command ended (its ``ok``
  lost?) or the firmware died, so the ordinary lost-``ok`` recovery runs and still
  gives up after its retries. A keep-alive arriving meanwhile proves the firmware is
  still at work (e.g. Marlin with ``M113 S10``): the outstanding tickle is kept and
  no retry is counted;
* the whole wait is bounded by ``long_command_timeout`` (or a G4's dwell plus the
  ordinary timeout, when longer): then :class:`PrinterTimeout`. A firmware that
  dies during a silent wait (RRF heating) is only noticed then: nothing tells the
  two apart sooner.

Temperatures in any reply (keep-alives, auto-reports, ``ok T:``) go to the stream's
``temperatures`` callback, with a missing target filled in from the last report or
from the heat command in flight (Prusa's wait lines carry none).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from printer.errors import PrinterTimeout
from printer.firmware import HEAT_WAITS, heat_wait_break, keepalives_promised, long_command_wait
from printer.gcode import lex
from printer.replies import Reply, heater_readings, keepalive_form

if TYPE_CHECKING:
    from collections import deque
    from collections.abc import Callable

    from printer.host import PrinterHost

#: Which heater a heat command sets (and, for the M1xx waits, waits for).
_HEATER_OF = {"M104": "T", "M109": "T", "M140": "B", "M190": "B", "M141": "C", "M191": "C"}


class LongWaits:
    """The long-command half of :class:`printer.stream.Streamer` (a mixin: it works on
    the streamer's in-flight window, clocks and tickle state)."""

    host: PrinterHost
    commands: list[str]
    inflight: deque[list[int]]
    keepalives: frozenset[str]
    last_ack: float
    last_life: float
    wait_life: bool
    held_probe: bool
    tickle_tries: int
    timeouts: int
    targets: dict[str, float]
    temperatures: Callable[[dict[str, tuple[float, float | None]]], None] | None

    def long_in_flight(self) -> tuple[int, float] | None:
        """(line number, least seconds it takes) of the first long command in flight."""
        for n, _size in self.inflight:
            least = long_command_wait(self.commands[n - 1])
            if least is not None:
                return n, least
        return None

    def break_heat_wait(self) -> None:
        """On cancel: a heat-up wait in flight would hold the cool-down behind it for
        minutes, so end it first where the firmware can (:func:`heat_wait_break`)."""
        found = self.long_in_flight()
        if found is None or lex(self.commands[found[0] - 1]).word not in HEAT_WAITS:
            return
        command = heat_wait_break(self.host.flavour)
        if command is not None:
            self.host.write(command)

    def keeps_alive(self, reply: Reply) -> bool:
        """True when ``reply`` (a busy or temperature line) shows the firmware at work on
        our lines; notes it for the long-command rules."""
        form = keepalive_form(reply)
        if form is None or form not in self.keepalives:
            return False
        found = self.long_in_flight()
        if form == "bare" and found is None:
            return False  # Klipper prints bare temperatures only while it waits
        if found is not None:
            self.wait_life = True
            if self.tickle_tries:
                self.held_probe = True
            self.check_long_bound(*found)
        return True

    def long_limit(self, least: float) -> float:
        return max(self.host.long_command_timeout, least + self.host.timeout)

    def check_long_bound(self, n: int, least: float) -> None:
        waited = time.monotonic() - self.last_ack
        limit = self.long_limit(least)
        if waited >= limit:
            raise PrinterTimeout(
                f"the printer on {self.host.port} has not finished {self.commands[n - 1]!r} "
                f"in {waited:.0f} s (the limit is [printer] long_command_timeout = {limit:g} s)"
            )

    def waiting_on_long_command(self) -> bool:
        """On silence: True when a long command may still be running (so wait, having sent
        at most one probe); False to run the ordinary lost-``ok`` recovery."""
        found = self.long_in_flight()
        if found is None:
            return False
        self.check_long_bound(*found)
        now = time.monotonic()
        if self.held_probe:
            self.held_probe = False  # still at work since the probe: keep waiting
            self.last_life = now
            return True
        if self.wait_life or keepalives_promised(self.host.flavour, self.commands[found[0] - 1]):
            return False  # no keep-alive when one was due: finished (ok lost?) or dead
        if not self.tickle_tries:
            self.tickle_tries = 1
            self.timeouts += 1
            self.host.write("M105")
        self.last_life = now
        return True

    def note_temperatures(self, temps: dict[str, tuple[float, float | None]]) -> None:
        """Pass a temperature report to the caller, with known targets filled in."""
        if self.temperatures is None:
            return
        readings = heater_readings(temps)
        if not readings:
            return
        out: dict[str, tuple[float, float | None]] = {}
        for heater, (current, target) in readings.items():
            if target is None:
                target = self.heat_target_in_flight(heater)
                if target is None:
                    target = self.targets.get(heater)
            else:
                self.targets[heater] = target
            out[heater] = (current, target)
        self.temperatures(out)

    def heat_target_in_flight(self, heater: str) -> float | None:
        """The S (or R) of a heat command in flight for ``heater``, if any."""
        for n, _size in self.inflight:
            lexed = lex(self.commands[n - 1])
            if _HEATER_OF.get(lexed.word or "") == heater:
                value = lexed.value("S", lexed.value("R"))
                if value is not None:
                    return value
        return None
