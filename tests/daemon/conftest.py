"""Fixtures shared by the daemon tests."""

from __future__ import annotations

import pytest
from daemon_helpers import DaemonProc, write_config


@pytest.fixture
def web_daemon(tmp_path):
    """``make(**write_config options) -> (daemon, web port, API key)``: the real daemon
    with its web API on a free loopback port and the virtual printer logging to
    ``tmp_path/printer.log``; every daemon made is stopped at the end."""
    from web_helpers import start_web_daemon

    made: list[DaemonProc] = []

    def make(**kw) -> tuple[DaemonProc, int, str]:
        d = DaemonProc(write_config(tmp_path, virtual_log=tmp_path / "printer.log", **kw))
        made.append(d)
        port, key = start_web_daemon(d)
        return d, port, key

    yield make
    for d in made:
        d.stop()
