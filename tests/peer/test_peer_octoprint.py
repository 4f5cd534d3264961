"""An independent peer: OctoPrint's own VirtualPrinter (OctoPrint 1.11 from PyPI, in the
test-only venv ``.venv-peer`` that ``.ci/run`` builds), run by a bridge on a real pty
with its default simulated errors on: a resend request at line 100, a resend whose
answer is lost at 105, a missing line number at 110 and a checksum mismatch at 115.
Our host streams 2000 sliced lines to it; the peer's own line counter and command
dispatch, observed by the bridge, show each line taken and run exactly once."""

from __future__ import annotations

import threading
import time

import pytest

from printer.host import PrinterHost

peer_helpers = pytest.importorskip("peer_helpers")

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(peer_helpers.peer_python() is None,
                       reason="the OctoPrint peer venv .venv-peer is absent (bash .ci/run "
                              f"builds it: {peer_helpers.PEER_INSTALL})"),
]


def test_2000_lines_each_executed_once_on_octoprints_virtual_printer(tmp_path):
    commands = peer_helpers.sliced_commands(2000)
    record = tmp_path / "peer.record"
    hung = threading.Event()
    bridge = peer_helpers.start_bridge(tmp_path / "ttyPEER", record)
    try:
        with PrinterHost(str(tmp_path / "ttyPEER"), 115200) as host:
            assert host.flavour == "marlin"  # "Virtual Marlin 1.0"
            # only a guard against a hung stream (it hung before on the peer's "wait"
            # lines); it asserts nothing about speed
            guard = threading.Timer(900, lambda: hung.set())
            guard.start()
            started = time.monotonic()
            result = host.stream(commands, cancel=hung)
            seconds = time.monotonic() - started
            guard.cancel()
    finally:
        peer_helpers.stop(bridge)
    seen = peer_helpers.read_record(record)
    assert result.lines == 2000
    # the peer's counter went through 1..2000 once each, in order, never back
    assert seen.accepted == list(range(1, 2001))
    assert seen.resets == 0
    # each line it ran, it ran once, as the file's command for that number
    wrong = {n: ran for n, ran in seen.executed.items() if ran != [commands[n - 1]]}
    assert not wrong, f"lines run other than once: {dict(list(wrong.items())[:5])}"
    # 105 is the peer's "resend_with_timeout": it marks the line received, drops it and
    # never answers (a lost ok by design); every other line was run
    assert seen.silent == [105]
    # nothing ran outside numbering but the host's own handshake and queries
    assert set(seen.unnumbered) <= {"M115", "M105"}, seen.unnumbered
    assert result.resends >= 3  # its simulated errors did happen
    print(f"\nOctoPrint VirtualPrinter: 2000 lines in {seconds:.1f} s "
          f"({2000 / seconds:.0f} lines/s, {result.resends} resends, "
          f"{result.timeouts} lost-ok recoveries)")
