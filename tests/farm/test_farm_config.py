"""Farm configuration and CLI errors: one clear line, no traceback."""

from __future__ import annotations

import subprocess
import sys

import tomli_w
from farm_helpers import free_port


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon", *args], capture_output=True,
                          text=True, timeout=120)


def _config(tmp_path, farm: dict):
    path = tmp_path / "preflight.toml"
    path.write_text(tomli_w.dumps({
        "spool": {"path": str(tmp_path / "spool")},
        "daemon": {"state_dir": str(tmp_path / "state")}, "web": {"listen": ""},
        "farm": farm}))
    return path


def test_farm_without_artefacts_refuses_to_start(tmp_path):
    path = _config(tmp_path, {"broker": "redis://127.0.0.1:6379/0"})
    result = _run("run", "--config", str(path))
    assert result.returncode == 2
    assert result.stderr.strip().startswith("preflight: [farm] artefacts:")
    assert "Traceback" not in result.stderr


def test_farm_broker_must_be_a_redis_url(tmp_path):
    path = _config(tmp_path, {"broker": "amqp://hub", "artefacts": str(tmp_path / "a")})
    result = _run("run", "--config", str(path))
    assert result.returncode == 2 and "[farm] broker:" in result.stderr


def test_farm_status_without_a_farm_or_a_broker(tmp_path):
    path = _config(tmp_path, {"name": "x"})
    result = _run("farm", "status", "--config", str(path))
    assert result.returncode == 2 and "not in a farm" in result.stderr
    port = free_port()  # nothing listens there
    path = _config(tmp_path, {"broker": f"redis://127.0.0.1:{port}/0",
                              "artefacts": str(tmp_path / "a")})
    result = _run("farm", "status", "--config", str(path))
    assert result.returncode == 1
    assert result.stderr.startswith("preflight: cannot reach the farm's broker")
    assert len(result.stderr.strip().splitlines()) == 1


def test_farm_status_never_prints_the_brokers_password(tmp_path):
    port = free_port()  # nothing listens there: the error names the broker
    path = _config(tmp_path, {"broker": f"redis://farm:s3cret@127.0.0.1:{port}/0",
                              "artefacts": str(tmp_path / "a")})
    result = _run("farm", "status", "--config", str(path))
    assert result.returncode == 1
    assert f"redis://farm:***@127.0.0.1:{port}/0" in result.stderr
    assert "s3cret" not in result.stderr + result.stdout
