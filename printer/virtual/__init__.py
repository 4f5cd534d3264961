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
* a first-order thermal model in real time (a bed to 60 °C in about 35 s, a
  hotend to 210 °C in about 45 s, times ``speedup``) for M104/M109/M140/M190/M116,
  and each firmware's way of waiting: Marlin's ``W:`` temperature lines and
  ``echo:busy: processing`` while any command blocks, Prusa MK3's ``T:… E:0 W:…``,
  Klipper's bare temperature lines, RepRapFirmware's silence;
* replies to M105, M115, M211, M208, M200, M862.1 and a Klipper nozzle macro;
* faults (:class:`Faults`): byte corruption, lost ``ok``, busy keepalives, a board
  reset or a disconnect after N lines (optionally coming back on a new pty, the
  ``link`` symlink updated, as a re-plugged USB device does), and line noise.

Every executed command is recorded (``executed``; ``executed_numbered`` also gives
its line number, None for an unnumbered line) so tests can prove exactly-once,
in-order delivery.

The package keeps the firmware apart from the wire: :mod:`.profiles` (what each
firmware reports), :mod:`.firmware` (line protocol, queue, execution, faults),
:mod:`.commands` (what each command does), :mod:`.physics` (heaters and motion
timing) and :mod:`.link` (the pty, byte pacing, noise, baud mismatch, hang-ups).
"""

from printer.virtual.faults import Faults
from printer.virtual.link import VirtualPrinter
from printer.virtual.profiles import FIRMWARES

__all__ = ["FIRMWARES", "Faults", "VirtualPrinter"]
