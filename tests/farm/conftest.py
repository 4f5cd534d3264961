"""Fixtures of the farm tests: a real redis-server (skipped, saying why, without one)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from farm_helpers import RedisServer  # noqa: E402


@pytest.fixture
def redis_server(tmp_path):
    if shutil.which("redis-server") is None:
        pytest.skip("redis-server is not installed (Debian: apt-get install redis-server; "
                    ".ci/run installs it)")
    server = RedisServer(tmp_path / "redis").start()
    yield server
    server.stop()
