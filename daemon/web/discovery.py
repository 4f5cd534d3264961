"""mDNS / DNS-SD: the daemon announces itself as an OctoPrint instance
(``_octoprint._tcp``, TXT ``path=/``), so PrusaSlicer's and Cura's "browse" find the Pi.

Advertising is best effort: a failure (no multicast route, the port 5353 refused, no
zeroconf) is logged and shown in the status, never fatal. It is off when the web API is
off or listens on loopback only (nobody else could reach it).
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
from typing import Any

from daemon import __version__
from daemon.web.octoprint import OCTOPRINT_VERSION

log = logging.getLogger("preflight.web")

SERVICE_TYPE = "_octoprint._tcp.local."


def advertised_addresses(host: str) -> list[str] | None:
    """The IPv4 addresses to announce for a listen host: all non-loopback addresses of
    the machine for a wildcard, the address itself for a specific one; None (do not
    advertise) for loopback. IPv6-only listen addresses are not announced."""
    if host in ("", "0.0.0.0", "::"):
        import ifaddr

        found = []
        for adapter in ifaddr.get_adapters():
            for ip in adapter.ips:
                if isinstance(ip.ip, str) and not ipaddress.ip_address(ip.ip).is_loopback:
                    found.append(ip.ip)
        return sorted(set(found)) or None
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:  # a host name: announce what it resolves to
        try:
            addr = ipaddress.ip_address(socket.gethostbyname(host))
        except (OSError, ValueError):
            return None
    if addr.is_loopback or addr.version != 4:
        return None
    return [str(addr)]


def service_properties() -> dict[str, str]:
    """The TXT record OctoPrint publishes (the slicers read ``path``)."""
    return {"path": "/", "version": OCTOPRINT_VERSION, "api": "0.1",
            "model": "preflight", "vendor": f"preflight {__version__}"}


class Advertiser:
    """Announces the web API on ``port`` at ``addresses`` (on those interfaces only)."""

    def __init__(self, addresses: list[str], port: int, name: str | None = None) -> None:
        host = socket.gethostname().split(".")[0] or "preflight"
        self.addresses = addresses
        self.port = port
        self.name = f"{name or f'preflight on {host}'}.{SERVICE_TYPE}"
        self.server = f"{host}.local."
        self.error: str | None = None
        self._zc: Any = None
        self._info: Any = None
        self._lock = threading.Lock()  # start (on its thread) and close (at shutdown)

    @property
    def registered(self) -> bool:
        return self._zc is not None

    def service_info(self) -> Any:
        from zeroconf import ServiceInfo

        return ServiceInfo(SERVICE_TYPE, self.name, port=self.port, server=self.server,
                           addresses=[socket.inet_aton(a) for a in self.addresses],
                           properties=service_properties())

    def start(self) -> bool:
        """Register the service (blocks for the probe, about 2 s); False on failure."""
        with self._lock:
            return self._start()

    def _start(self) -> bool:
        try:
            from zeroconf import IPVersion, Zeroconf

            self._info = self.service_info()
            self._zc = Zeroconf(interfaces=list(self.addresses), ip_version=IPVersion.V4Only)
            self._zc.register_service(self._info, allow_name_change=True)
        except Exception as e:  # ImportError, OSError, zeroconf's own errors
            self.error = f"cannot advertise over mDNS: {type(e).__name__}: {e}"
            log.warning("%s (slicers can still add http://<this machine>:%d by hand)",
                        self.error, self.port)
            self._close()
            return False
        log.info("advertised %s on %s port %d over mDNS", self.name, ", ".join(self.addresses),
                 self.port)
        return True

    def close(self) -> None:
        """Withdraw the service (waits for a registration still in progress)."""
        with self._lock:
            self._close()

    def _close(self) -> None:
        zc, self._zc = self._zc, None
        if zc is None:
            return
        try:
            if self._info is not None:
                zc.unregister_service(self._info)
        except Exception as e:  # shutting down: say so, go on
            log.info("mDNS: could not withdraw the service: %s", e)
        finally:
            zc.close()


def advertise_in_background(host: str, port: int) -> Advertiser | None:
    """Start advertising on a thread (the probe takes seconds); None when it is off."""
    addresses = advertised_addresses(host)
    if not addresses:
        log.info("not advertising over mDNS: the web API listens on %s only", host or "?")
        return None
    adv = Advertiser(addresses, port)
    threading.Thread(target=adv.start, name="mdns", daemon=True).start()
    return adv
