"""mDNS: the daemon announces ``_octoprint._tcp`` with TXT ``path=/``; a failure to
advertise is reported, never raised; loopback-only servers do not advertise."""

from __future__ import annotations

import threading

import pytest

from daemon.web.discovery import (
    SERVICE_TYPE,
    Advertiser,
    advertise_in_background,
    advertised_addresses,
)

zeroconf = pytest.importorskip("zeroconf")


class Seen:
    """A ServiceBrowser listener recording what it hears."""

    def __init__(self) -> None:
        self.added: set[str] = set()
        self.removed: set[str] = set()
        self.changed = threading.Condition()

    def add_service(self, zc, type_, name):
        with self.changed:
            self.added.add(name)
            self.changed.notify_all()

    def remove_service(self, zc, type_, name):
        with self.changed:
            self.removed.add(name)
            self.changed.notify_all()

    def update_service(self, zc, type_, name):
        pass

    def wait(self, pred, timeout=30.0) -> bool:
        with self.changed:
            return self.changed.wait_for(pred, timeout)


def test_loopback_and_unknown_hosts_are_not_advertised():
    assert advertised_addresses("127.0.0.1") is None
    assert advertised_addresses("localhost") is None
    assert advertised_addresses("::1") is None
    assert advertise_in_background("127.0.0.1", 8080) is None
    # a wildcard announces the machine's own addresses, never loopback
    for addr in advertised_addresses("0.0.0.0") or []:
        assert not addr.startswith("127.")


def test_a_browser_finds_the_service_with_its_record_then_sees_it_go():
    adv = Advertiser(["127.0.0.1"], 48123, name="preflight test")
    browser_zc = zeroconf.Zeroconf(interfaces=["127.0.0.1"],
                                   ip_version=zeroconf.IPVersion.V4Only)
    seen = Seen()
    try:
        zeroconf.ServiceBrowser(browser_zc, SERVICE_TYPE, seen)
        assert adv.start(), adv.error
        assert adv.registered and adv.error is None
        assert seen.wait(lambda: adv.name in seen.added), "the browser never saw the service"
        info = browser_zc.get_service_info(SERVICE_TYPE, adv.name, timeout=10000)
        assert info is not None
        assert info.port == 48123
        assert info.parsed_addresses() == ["127.0.0.1"]
        assert info.properties[b"path"] == b"/"
        assert info.properties[b"api"] == b"0.1"
        adv.close()
        assert not adv.registered
        assert seen.wait(lambda: adv.name in seen.removed), "the service was not withdrawn"
    finally:
        adv.close()
        browser_zc.close()


def test_failing_to_advertise_is_reported_not_raised(caplog):
    # 203.0.113.9 (TEST-NET-3) is on no interface of this machine: binding fails
    adv = Advertiser(["203.0.113.9"], 8080)
    assert adv.start() is False
    assert adv.error and adv.error.startswith("cannot advertise over mDNS")
    assert not adv.registered
    assert any("cannot advertise over mDNS" in r.getMessage() for r in caplog.records)
    adv.close()  # closing what never started is harmless
