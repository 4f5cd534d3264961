"""How a printer link opens its port: the configured device, the virtual printer, or
(``port = "auto"``) the printer a scan finds, skipping ports another printer of the
same daemon already uses."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

log = logging.getLogger("preflight.printer")


class _TakenPort:
    """Stands in for a host on a port another printer of this daemon uses: its connect
    fails with a port error (discovery passes the port by and shows the reason)."""

    def __init__(self, path: str, owner: str) -> None:
        self.path = path
        self.owner = owner

    def connect(self) -> None:
        from printer.errors import PrinterDisconnected

        # a port error whose own words discovery shows (PortBusy's would blame another
        # program); the port is never opened
        raise PrinterDisconnected(f"used by printer {self.owner!r} of this daemon")

    def close(self) -> None:
        pass


class PortOpener:
    """Mixin of :class:`~daemon.printlink.PrinterLink`: opening its printer's port.

    Needs ``printer`` (PrinterConfig), ``name``, ``pool`` (or None), ``cfg``, ``virtual``
    and ``_set_status``."""

    printer: Any
    name: str
    pool: Any
    cfg: Any
    virtual: Any

    def _set_status(self, **kw: Any) -> None:  # pragma: no cover - the link's
        raise NotImplementedError

    def _port(self) -> str:
        port = self.printer.port
        if port != "virtual":
            return port
        if self.virtual is None:
            from printer.virtual import VirtualPrinter

            printer_config = self.printer
            self.virtual = VirtualPrinter(
                firmware=printer_config.virtual_firmware, nozzle=printer_config.nozzle_diameter,
                baud=printer_config.baud, speedup=printer_config.virtual_speedup,
                log_path=str(printer_config.virtual_log) if printer_config.virtual_log else None,
                build_volume=printer_config.virtual_build_volume)
            self.virtual_port = self.virtual.start()
            log.info("printer %s: virtual printer on %s", self.name, self.virtual_port)
        return self.virtual_port

    def _make_host(self, port: str, baud: int):
        from printer.host import PrinterHost

        printer_config = self.printer
        return PrinterHost(port, baud, mode=printer_config.mode,
                           nozzle_fallback=printer_config.nozzle_diameter,
                           nozzle_macro=printer_config.nozzle_macro,
                           long_command_timeout=printer_config.long_command_timeout,
                           handshake_timeout=max(printer_config.probe_seconds, 5.0))

    def _claim(self, path: str) -> str | None:
        """Reserve ``path`` for this printer; the name of the printer that has it, if any."""
        return None if self.pool is None else self.pool.claim_port(path, self.name)

    def _remember_dir(self) -> Path:
        """Where ``port = "auto"`` remembers its choice: one folder per named printer."""
        state_dir = self.cfg.daemon.state_dir
        return state_dir if self.name == "printer" else state_dir / "printers" / self.name

    def _open_host(self):
        """A connected host and its port: the configured port, the virtual printer, or
        (``port = "auto"``) the printer a scan finds, the remembered one first."""
        printer_config = self.printer
        if printer_config.port != "auto":
            port = self._port()
            owner = self._claim(port)
            if owner is not None:
                from printer.errors import PortBusy

                raise PortBusy(f"{port} is used by printer {owner!r} of this daemon")
            host = self._make_host(port, printer_config.baud)
            try:
                host.connect()
            except BaseException:
                host.close()
                raise
            return host, port
        return self._discover()

    def _discover(self):
        from printer.discovery import discover, remember, remembered_choice
        from printer.errors import PortNotFound

        printer_config = self.printer
        remember_dir = self._remember_dir()
        self._set_status(state="searching", port="auto", message="looking for a printer on "
                         + ", ".join(printer_config.scan))

        def make_probe_host(path: str, baud: int):
            owner = self._claim(path)
            if owner is not None:
                return _TakenPort(path, owner)
            host = self._make_host(path, baud)
            host.handshake_timeout = printer_config.probe_seconds
            return host

        found = discover(printer_config.scan, remembered=remembered_choice(remember_dir),
                         make_host=make_probe_host, keep_open=True)
        if self.pool is not None:
            self.pool.release_ports(self.name, keep=found.chosen.path if found.host else None)
        self._set_status(discovery=[c.line() for c in found.candidates])
        if found.host is None:
            raise PortNotFound(found.summary())
        remember(remember_dir, found.chosen)
        log.info("printer %s: %s", self.name, found.summary())
        self._set_status(port=found.chosen.path)
        return found.host, found.chosen.path
