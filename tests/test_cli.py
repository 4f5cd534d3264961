"""The console script is installed and answers as a user would call it."""

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "daemon", *args], capture_output=True, text=True, timeout=120
    )


def test_version_matches_distribution():
    expected = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    out = run_cli("--version")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"preflight {expected}"


def test_no_command_prints_usage_and_fails():
    out = run_cli()
    assert out.returncode == 2
    assert "usage: preflight" in out.stderr


def test_example_config_prints_and_writes_the_shipped_file(tmp_path):
    shipped = (ROOT / "systemd" / "preflight.toml").read_text()
    out = run_cli("example-config")
    assert out.returncode == 0, out.stderr
    assert out.stdout == shipped
    out = run_cli("example-config", "--output", str(tmp_path / "p.toml"))
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "p.toml").read_text() == shipped


def test_a_sub_command_builds_only_its_own_module():
    """``preflight slice ...`` registers daemon/commands/slice.py alone (start-up cost on a
    small model); a word that names a module but no command still gets the full list."""
    probe = ("import sys\nfrom daemon import cli\ntry:\n    cli.main(sys.argv[1:])\n"
             "except SystemExit:\n    pass\n"
             "print(sorted(m for m in sys.modules if m.startswith('daemon.commands.')))")
    out = subprocess.run([sys.executable, "-c", probe, "slice", "--help"], capture_output=True,
                         text=True, cwd=ROOT, check=True).stdout
    assert "usage: preflight slice" in out and "--workers" in out
    assert out.strip().splitlines()[-1] == "['daemon.commands.slice']"
    bad = subprocess.run([sys.executable, "-m", "daemon.cli", "daemon"], capture_output=True,
                         text=True, cwd=ROOT)
    assert bad.returncode == 2
    assert "'slice'" in bad.stderr and "'run'" in bad.stderr
