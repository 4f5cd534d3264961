"""Printer-link errors: every message is one human-readable line naming the cause."""

from __future__ import annotations


class PrinterError(Exception):
    """Base class for everything that can go wrong on the printer link.

    ``lines_sent`` is set by PrinterHost.stream: how many of the job's numbered lines
    had been written to the port when the error happened (None outside a stream).
    """

    lines_sent: int | None = None


class PortNotFound(PrinterError):
    """The serial port path does not exist (printer unplugged or wrong path)."""


class PortBusy(PrinterError):
    """Another process holds the port (exclusive lock failed)."""


class PortPermission(PrinterError):
    """The user may not open the port (usually: not in the dialout group)."""


class WrongBaud(PrinterError):
    """Bytes arrive but never form a valid reply: almost always a baud-rate mismatch."""


class PrinterReset(PrinterError):
    """The firmware printed ``start`` mid-session: the board reset, the job is lost."""


class PrinterDisconnected(PrinterError):
    """The port vanished or hung up (USB unplugged, power cut)."""


class PrinterHalted(PrinterError):
    """The firmware reported a fatal error (kill(), thermal runaway, Klipper shutdown)."""


class PrinterTimeout(PrinterError):
    """The printer stopped answering and bounded recovery attempts were exhausted."""


class StreamCancelled(PrinterError):
    """The stream was cancelled; cooldown and motors-off have been sent."""


class EmergencyStopped(PrinterError):
    """M112 was sent: the firmware stopped at once and must be reset before printing."""
