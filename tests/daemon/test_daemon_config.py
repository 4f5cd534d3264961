"""The TOML config: defaults, every documented key, errors that name the key."""

from pathlib import Path

import pytest
import tomli_w

from daemon.config import (
    SECTIONS,
    ConfigError,
    load_config,
    parse_config,
    rules,
)
from daemon.config_example import example_config

ROOT = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "preflight.toml"
    p.write_text(text)
    return p


def test_defaults_without_a_file():
    cfg = parse_config({})
    assert cfg.printer.port == "auto"  # a printer is searched for; "virtual" only when asked
    assert cfg.printer.scan[0] == "/dev/serial/by-id/*"
    assert cfg.printer.baud == 115200
    assert cfg.daemon.auto_print is True
    assert cfg.spool.path == Path("/var/spool/preflight")
    assert cfg.done_dir == cfg.spool.path / "done"


def test_documented_keys_are_read(tmp_path):
    p = write(tmp_path, """
[spool]
path = "spool"
[printer]
port = "/dev/serial/by-id/usb-foo"
baud = 250000
nozzle_diameter = 0.6
[daemon]
state_dir = "/tmp/x/state"
auto_print = false
log_level = "debug"
[limits]
max_file_mb = 10
max_triangles = 1000
repair_timeout = 5
slice_timeout = 6
repair_memory_mb = 512
[repair]
clean = "scan"
[profile]
infill_percent = 30
""")
    cfg = load_config(p)
    assert cfg.spool.path == tmp_path / "spool"  # relative to the config file
    assert cfg.printer.port == "/dev/serial/by-id/usb-foo"
    assert cfg.printer.baud == 250000
    assert cfg.printer.nozzle_diameter == 0.6
    assert cfg.daemon.state_dir == Path("/tmp/x/state")
    assert cfg.daemon.auto_print is False
    assert cfg.daemon.log_level == "DEBUG"
    assert (cfg.limits.max_file_mb, cfg.limits.max_triangles) == (10, 1000)
    assert (cfg.limits.repair_timeout, cfg.limits.slice_timeout) == (5, 6)
    assert cfg.limits.repair_memory_mb == 512
    assert cfg.repair.clean == "scan"
    assert cfg.profile == {"infill_percent": 30}


@pytest.mark.parametrize("text, key", [
    ("[printer]\nbaud = \"fast\"", "[printer] baud"),
    ("[printer]\nbaud = 12.5", "[printer] baud"),
    ("[printer]\nnozzle_diameter = -0.4", "[printer] nozzle_diameter"),
    ("[daemon]\nauto_print = \"yes\"", "[daemon] auto_print"),
    ("[daemon]\nlog_level = \"loud\"", "[daemon] log_level"),
    ("[limits]\nrepair_timeout = 0", "[limits] repair_timeout"),
    ("[spool]\npath = 3", "[spool] path"),
    ("[spool]\npaht = \"/x\"", "[spool] paht"),
    ("[printr]\nport = \"x\"", "[printr]"),
    ("[safety]\nforbidden_gcodes = \"M502\"", "[safety] forbidden_gcodes"),
    ("[repair]\nclean = \"deep\"", "[repair] clean"),
])
def test_bad_value_names_the_key(tmp_path, text, key):
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, text))
    assert str(e.value).startswith(key)


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[spool\npath ="))


def test_shipped_example_config_is_valid():
    cfg = load_config(ROOT / "systemd" / "preflight.toml")
    assert cfg.spool.path == Path("/var/spool/preflight")
    assert cfg.printer.port == "auto"
    assert cfg.printer.scan == ("/dev/serial/by-id/*", "/dev/ttyACM*", "/dev/ttyUSB*")


def test_run_with_bad_config_prints_one_line(tmp_path):
    import subprocess
    import sys

    p = write(tmp_path, "[printer]\nbaud = \"fast\"\n")
    out = subprocess.run([sys.executable, "-m", "daemon", "run", "--config", str(p)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [out.stderr.strip()]
    assert out.stderr.startswith("preflight: [printer] baud")


def test_unknown_profile_setting_is_named_at_start(tmp_path):
    import subprocess
    import sys

    p = write(tmp_path, tomli_w.dumps({"spool": {"path": str(tmp_path / "s")},
                                       "daemon": {"state_dir": str(tmp_path / "st")},
                                       "profile": {"infill_prcent": 20}}))
    out = subprocess.run([sys.executable, "-m", "daemon", "run", "--config", str(p)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert out.stderr.startswith("preflight: [profile]") and "infill_prcent" in out.stderr


def test_shipped_example_config_is_the_generated_one():
    """systemd/preflight.toml is regenerated with `preflight example-config -o ...`."""
    assert (ROOT / "systemd" / "preflight.toml").read_text() == example_config()


def test_example_config_shows_every_key_with_its_default():
    text = example_config()
    uncommented = "\n".join(line[2:] if line.startswith("# ") and " = " in line
                            or line.startswith("#  ") else line for line in text.splitlines())
    cfg = parse_config(__import__("tomllib").loads(uncommented))
    defaults = parse_config({})
    for name, section in SECTIONS.items():
        for key, default, rule in rules(section):
            assert f"\n{key} = " in text or f"\n# {key} = " in text, key
            if rule.example is None:
                assert getattr(getattr(cfg, name), key) == default, key
                assert getattr(getattr(defaults, name), key) == default, key
    assert cfg.printer.port == "auto"
    examples = {key: rule.example for key, _, rule in rules(SECTIONS["printer"]) if rule.example}
    assert cfg.printer.klipper_config == Path(examples["klipper_config"])
    assert cfg.printer.nozzle_macro == examples["nozzle_macro"]


def test_paths_with_quotes_and_backslashes_round_trip(tmp_path):
    odd = tmp_path / 'a "quoted" \\ dir'
    p = write(tmp_path, tomli_w.dumps({"spool": {"path": str(odd)}}))
    assert load_config(p).spool.path == odd


@pytest.mark.parametrize("text, key", [
    ('[spool]\n"bad\\nkey" = 1', "[spool] bad\\nkey: unknown key"),
    ('["sect\\nion"]\nx = 1', "[sect\\nion]: unknown section"),
    ("[printer]\nport = \"" + "x" * 600 + "\"\nbaud = \"" + "y" * 600 + "\"",
     "[printer] baud: expected a number"),
    ('[spool]\npath = "a\\u0000b"', "[spool] path: a path cannot contain a NUL"),
])
def test_refusals_are_one_short_line(tmp_path, text, key):
    """Found by fuzzing: names and values are shown escaped and cut short."""
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, text))
    message = str(e.value)
    assert message.startswith(key)
    assert "\n" not in message and len(message) <= 500


def test_a_long_profile_value_is_refused_in_one_short_line():
    """Found by fuzzing: the slicer's refusal quotes the whole value."""
    from daemon.config import check_profile

    with pytest.raises(ConfigError) as e:
        check_profile(parse_config({"profile": {"infill_percent": "x" * 700}}))
    assert str(e.value).startswith("[profile] ") and "infill_percent" in str(e.value)
    assert len(str(e.value)) <= 500
