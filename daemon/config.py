"""The daemon's configuration: one TOML file, validated, with built-in defaults.

Lookup order: the ``--config`` path, else ``/etc/preflight/preflight.toml``, else
the built-in defaults. Every value is checked on load; a bad one raises
:class:`ConfigError` whose message names the key (``[printer] baud: ...``).

Units: sizes in mm, times in seconds, memory in MB, file sizes in MB.
"""

from __future__ import annotations

import logging
import os
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

DEFAULT_CONFIG_PATH = Path("/etc/preflight/preflight.toml")

#: Firmware-altering G-codes refused unless ``[safety] allow_firmware_commands``:
#: EEPROM save/load/reset, firmware update, SD-card file operations (write, delete,
#: select and start a file, log to a file), network / Wi-Fi configuration.
DEFAULT_FORBIDDEN_GCODES = (
    "M500", "M501", "M502", "M504", "M997",
    "M23", "M24", "M28", "M29", "M30", "M32", "M928",
    "M540", "M550", "M551", "M552", "M553", "M554", "M555", "M556",
    "M587", "M588", "M589",
)


class ConfigError(ValueError):
    """A configuration value is wrong; the message names the key."""


# --- the schema ---------------------------------------------------------------------------
# Every key is a dataclass field declared with setting(): its default, a one-line doc, and
# how its value is checked. Parsing, validation and the example config come from these.

BOOL, INT, FLOAT, STR, PATH, CHOICE, GCODES, LISTEN, GLOBS, SIZE = (
    "bool", "int", "float", "str", "path", "choice", "G-code words", "host:port", "globs",
    "x, y, z (mm)")


@dataclass(frozen=True)
class Rule:
    """How one key's value is checked, and how the example config shows it."""

    kind: str
    doc: str
    low: float | None = None          # the smallest value allowed
    high: float | None = None         # the largest value allowed
    above_low: bool = False           # the value must be > low (not >= low)
    low_key: str | None = None        # the smallest value is that key's value
    choices: tuple[str, ...] = ()
    optional: bool = False            # the default is "not set" (None)
    example: Any = None               # shown in the example config instead of the default
    commented: bool = False           # shown commented out in the example config
    upper: bool = False               # the value is taken in capitals ("info" = "INFO")


def setting(default: Any, doc: str, kind: str, **rule: Any) -> Any:
    """A config key: a dataclass field carrying its :class:`Rule`."""
    return field(default=default, metadata={"rule": Rule(kind, doc, **rule)})


@dataclass(frozen=True)
class SpoolConfig:
    path: Path = setting(Path("/var/spool/preflight"),
                         "drop files here; done/ and failed/ live inside", PATH)
    settle_seconds: float = setting(5.0, "no close event seen (network share): stable this "
                                    "long = complete", FLOAT, low=0.05, high=3600)
    close_grace_seconds: float = setting(0.3, "after close-after-write, wait this long for "
                                         "more writes", FLOAT, low=0, high=60)
    poll: bool = setting(False, "true: poll instead of inotify (NFS/SMB mounts)", BOOL)


@dataclass(frozen=True)
class PrinterConfig:
    name: str = setting("printer", "the printer's name in status, reports and the journal "
                        "(required and unique in [[printers]] tables)", STR)
    port: str = setting("auto", '"auto" (find it: see scan), a serial device (best under '
                        '/dev/serial/by-id/), or "virtual" (a simulator)', STR)
    baud: int = setting(115200, "serial speed (port = \"auto\" finds its own)", INT, low=300,
                        high=4_000_000)
    scan: tuple[str, ...] = setting(("/dev/serial/by-id/*", "/dev/ttyACM*", "/dev/ttyUSB*"),
                                    'with port "auto": where to look, in order', GLOBS)
    probe_seconds: float = setting(3.0, 'port = "auto": how long each port and baud rate may '
                                   "take to answer", FLOAT, low=0.2, high=60)
    nozzle_diameter: float = setting(0.4, "mm, used when the printer cannot report its nozzle",
                                     FLOAT, low=0.05, high=3.0, above_low=True)
    mode: str = setting("auto", "how G-code is streamed", CHOICE,
                        choices=("auto", "ping-pong", "buffered"))
    nozzle_macro: str | None = setting(None, "Klipper: a macro that reports the nozzle", STR,
                                       optional=True, example="GET_NOZZLE")
    klipper_api_socket: Path = setting(Path("/tmp/klippy_uds"), "Klipper: its API socket, "
                                       "for the nozzle and build volume", PATH)
    klipper_config: Path | None = setting(None, "Klipper: printer.cfg, read when the API "
                                          "socket is not there", PATH, optional=True,
                                          example="/home/pi/printer_data/config/printer.cfg")
    long_command_timeout: float = setting(900.0, "s a heat-up, homing or levelling command "
                                          "(M109, M190, G28, G29...) may take", FLOAT, low=1,
                                          high=86400)
    reconnect_min_seconds: float = setting(1.0, "first wait before reconnecting", FLOAT,
                                           low=0.01, high=3600)
    reconnect_max_seconds: float = setting(60.0, "longest wait between reconnects", FLOAT,
                                           low_key="reconnect_min_seconds", high=86400)
    virtual_firmware: str = setting("marlin", 'port = "virtual" only: the firmware it plays',
                                    CHOICE, choices=("marlin", "prusa", "buddy", "klipper",
                                                     "rrf"))
    virtual_speedup: float = setting(1.0, 'port = "virtual" only: how much faster than real '
                                     "time it heats and moves (1: real time)", FLOAT, low=0.01,
                                     high=1e6)
    virtual_log: Path | None = setting(None, 'port = "virtual" only: append every executed '
                                       "command here", PATH, optional=True,
                                       example="/var/log/preflight/virtual.gcode")
    virtual_build_volume: tuple[float, float, float] = setting(
        (250.0, 210.0, 220.0), "the virtual printer's bed and height (x, y, z), mm", SIZE)


@dataclass(frozen=True)
class DaemonConfig:
    state_dir: Path = setting(Path("/var/lib/preflight"), "journal.sqlite lives here", PATH)
    auto_print: bool = setting(True, "false: repair and slice, then wait for `preflight jobs "
                               "print ID`", BOOL)
    log_level: str = setting("INFO", "how much the daemon logs", CHOICE,
                             choices=("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"),
                             upper=True)
    workers: int = setting(1, "models repaired/sliced at once", INT, low=1, high=64)


@dataclass(frozen=True)
class LimitsConfig:
    max_file_mb: float = setting(200.0, "MB; a bigger dropped file is refused", FLOAT,
                                 low=0, high=1e6, above_low=True)
    max_triangles: int = setting(2_000_000, "a model with more triangles is refused", INT,
                                 low=1, high=1e9)
    repair_timeout: float = setting(600.0, "s", FLOAT, low=0, high=1e6, above_low=True)
    slice_timeout: float = setting(600.0, "s", FLOAT, low=0, high=1e6, above_low=True)
    repair_memory_mb: int = setting(2048, "address-space cap of the repair child", INT,
                                    low=64, high=1e7)
    slice_memory_mb: int = setting(2048, "address-space cap of the slicing child", INT,
                                   low=64, high=1e7)
    max_attempts: int = setting(3, "a job whose processing died this often fails", INT,
                                low=1, high=100)


@dataclass(frozen=True)
class SafetyConfig:
    allow_firmware_commands: bool = setting(False, "true: allow M500/M502/M997/SD "
                                            "writes/Wi-Fi... in G-code", BOOL)
    forbidden_gcodes: tuple[str, ...] = setting(DEFAULT_FORBIDDEN_GCODES, "G-code words refused "
                                                "unless allow_firmware_commands", GCODES,
                                                commented=True)


@dataclass(frozen=True)
class WebConfig:
    listen: str = setting("0.0.0.0:8080", "host:port of the slicers' OctoPrint/Moonraker API; "
                          '"" turns it off', LISTEN)
    max_upload_mb: float = setting(1024.0, "MB; a bigger upload is refused (413); [limits] "
                                   "max_file_mb also applies", FLOAT,
                                   low=0, high=1e7, above_low=True)


@dataclass(frozen=True)
class RepairConfig:
    clean: str = setting("auto", 'scan cleanup (spikes, specks, ragged holes) before the '
                         'repair: "auto" when the model looks like a scan, "scan" always, '
                         '"none" never', CHOICE, choices=("auto", "scan", "none"))
    surface: str = setting("holes", 'refine curved features of an STL to the design surface '
                           '(chordal error within min(0.01 mm, nozzle/40)) before slicing: '
                           '"holes" cylinders and cones (holes, bosses, countersinks), "all" '
                           'also spheres and tori, "off" never', CHOICE,
                           choices=("off", "holes", "all"))
    # 120 s: the slowest corpus models repair exactly in about 35 s here, about two minutes
    # on a Raspberry Pi 4, so the budget cuts short only what would run for minutes.
    time_budget: float = setting(120.0, "s; past this the exact repair gives way to the "
                                 "fallback approximation (the report says so and gives its "
                                 "D); at most half of [limits] repair_timeout; 0: no budget",
                                 FLOAT, low=0, high=1e6)


@dataclass(frozen=True)
class FarmConfig:
    broker: str | None = setting(None, 'the farm\'s Redis, "redis://host:6379/0"; not set: '
                                 "no farm (this daemon is an island)", STR, optional=True,
                                 example="redis://farm-hub:6379/0")
    name: str = setting("preflight", "the farm's name: nodes with the same broker and name "
                        "share one queue", STR)
    node: str | None = setting(None, "this node's name in the farm; not set: the host name",
                               STR, optional=True, example="pi-rack-3")
    compute: bool = setting(True, "run repair and slicing for the whole farm here", BOOL)
    compute_workers: int = setting(1, "with compute: farm tasks run at once", INT, low=1,
                                   high=64)
    artefacts: Path | None = setting(None, "a directory every node mounts (NFS/SMB): inputs "
                                     "and G-code live here, never in the broker", PATH,
                                     optional=True, example="/srv/preflight-farm")
    claim_timeout: float = setting(60.0, "s a claimed job not yet printing may go without its "
                                   "node's heartbeat before the farm gives it to another "
                                   "printer", FLOAT, low=3, high=3600)
    task_timeout: float = setting(900.0, "s before a repair+slice task whose worker vanished "
                                  "is handed to another compute node", FLOAT, low=5,
                                  high=86400)


#: The sections in the order of the example config; ``[profile]`` is an open table.
SECTIONS: dict[str, type] = {"spool": SpoolConfig, "printer": PrinterConfig,
                             "daemon": DaemonConfig, "limits": LimitsConfig,
                             "safety": SafetyConfig, "web": WebConfig,
                             "repair": RepairConfig, "farm": FarmConfig}
PROFILE = "profile"


@dataclass(frozen=True)
class Config:
    spool: SpoolConfig = field(default_factory=SpoolConfig)
    printer: PrinterConfig = field(default_factory=PrinterConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    daemon: DaemonConfig = field(default_factory=DaemonConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    web: WebConfig = field(default_factory=WebConfig)
    repair: RepairConfig = field(default_factory=RepairConfig)
    farm: FarmConfig = field(default_factory=FarmConfig)
    profile: dict[str, Any] = field(default_factory=dict)  # slicer Profile overrides
    source: str = "built-in defaults"
    #: Every printer: the ``[[printers]]`` tables, else the one ``[printer]``
    #: (``printer`` is always the first of them).
    printers: tuple[PrinterConfig, ...] = ()
    #: Whether the file has a [printer] or [[printers]] table (a farm node without one,
    #: with [farm] compute, is a compute-only node).
    printer_tables: bool = True

    @property
    def all_printers(self) -> tuple[PrinterConfig, ...]:
        return self.printers or (self.printer,)

    @property
    def journal_path(self) -> Path:
        return self.daemon.state_dir / "journal.sqlite"

    @property
    def done_dir(self) -> Path:
        return self.spool.path / "done"

    @property
    def failed_dir(self) -> Path:
        return self.spool.path / "failed"

    @property
    def work_dir(self) -> Path:
        return self.spool.path / ".preflight" / "work"


def rules(section: type) -> list[tuple[str, Any, Rule]]:
    """(key, default, rule) for every key of a section class, in declaration order."""
    return [(f.name, f.default, f.metadata["rule"]) for f in fields(section)]


# --- parsing and validation ----------------------------------------------------------------

def _shown(value: Any, limit: int = 60) -> str:
    """A value as it appears in an error message: one line, never very long."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _name(text: str) -> str:
    """A section or key name as it appears in an error message: escaped, at most 40 chars."""
    shown = repr(str(text))[1:-1]
    return shown if len(shown) <= 40 else shown[:37] + "..."


def _key(section: str, name: str) -> str:
    return f"[{_name(section)}] {_name(name)}"


def _number(where: str, value: Any, rule: Rule, low: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {_shown(value)}")
    if rule.kind == INT and not isinstance(value, int):
        raise ConfigError(f"{where}: expected a whole number, got {_shown(value)}")
    high = float("inf") if rule.high is None else rule.high
    too_low = value <= low if rule.above_low else value < low
    if value != value or too_low or value > high:
        bounds = f"{'>' if rule.above_low else '>='} {low} and <= {high}"
        raise ConfigError(f"{where}: {_shown(value)} is out of range (must be {bounds})")
    return int(value) if rule.kind == INT else float(value)


def _string(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: expected a non-empty string, got {_shown(value)}")
    return value


def check_value(section: str, name: str, value: Any, rule: Rule, *, base: Path | None,
                earlier: dict[str, Any]) -> Any:
    """``value`` checked and converted by ``rule``; ConfigError naming the key if wrong.

    ``earlier``: the values of the section's keys declared before this one.
    """
    where = _key(section, name)
    if rule.kind == BOOL:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {_shown(value)}")
        return value
    if rule.kind in (INT, FLOAT):
        low = earlier[rule.low_key] if rule.low_key else rule.low
        return _number(where, value, rule, float("-inf") if low is None else low)
    if rule.kind == GCODES:
        if not isinstance(value, list) or not all(isinstance(x, str) and x.strip()
                                                  for x in value):
            raise ConfigError(f'{where}: expected a list of G-code words like "M502"')
        return tuple(x.strip().upper() for x in value)
    if rule.kind == GLOBS:
        if not isinstance(value, list) or not all(isinstance(x, str) and x.strip()
                                                  for x in value):
            raise ConfigError(f'{where}: expected a list of paths or globs like "/dev/ttyACM*"')
        return tuple(os.path.expanduser(x.strip()) for x in value)
    if rule.kind == SIZE:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 < x < 1e5
                           for x in value)):
            raise ConfigError(f"{where}: expected three sizes in mm like [250, 210, 220], got "
                              f"{_shown(value)}")
        return tuple(float(x) for x in value)
    if rule.kind == LISTEN:
        if not isinstance(value, str) or (value and split_listen(value) is None):
            raise ConfigError(f'{where}: expected "host:port" or "" (off), got {_shown(value)}')
        return value
    text = _string(where, value)
    if rule.kind == PATH:
        if "\0" in text:
            raise ConfigError(f"{where}: a path cannot contain a NUL character")
        path = Path(os.path.expanduser(text))
        return base / path if not path.is_absolute() and base is not None else path
    if rule.kind == CHOICE:
        text = text.upper() if rule.upper else text
        if text not in rule.choices:
            raise ConfigError(f"{where}: {_shown(text)} is not one of {', '.join(rule.choices)}")
    return text


def _section(name: str, table: dict[str, Any], section: type, base: Path | None) -> Any:
    known = [key for key, _, _ in rules(section)]
    for key in table:
        if key not in known:
            raise ConfigError(f"{_key(name, key)}: unknown key (known: {', '.join(sorted(known))})")
    values: dict[str, Any] = {}
    for key, default, rule in rules(section):
        if key in table:
            values[key] = check_value(name, key, table[key], rule, base=base, earlier=values)
        else:
            values[key] = default
    return section(**values)


def parse_config(data: dict[str, Any], *, base: Path | None = None,
                 source: str = "built-in defaults") -> Config:
    """Validate a parsed TOML mapping into a :class:`Config`.

    Relative paths are taken relative to ``base`` (the config file's folder).
    Unknown sections or keys are errors, so that a typo never passes silently.
    """
    known = [*SECTIONS, PROFILE, PRINTERS]
    printers = _printer_tables(data, base)
    for name, table in data.items():
        if name == PRINTERS:
            continue
        if name not in known:
            raise ConfigError(f"[{_name(name)}]: unknown section "
                              f"(known: {', '.join(sorted(known))})")
        if not isinstance(table, dict):
            raise ConfigError(f"[{name}]: expected a table")
    sections = {name: _section(name, data.get(name, {}), section, base)
                for name, section in SECTIONS.items()}
    if printers:
        sections["printer"] = printers[0]
    return Config(**sections, profile=dict(data.get(PROFILE, {})), source=source,
                  printers=printers, printer_tables=bool(printers) or "printer" in data)


PRINTERS = "printers"


def _printer_tables(data: dict[str, Any], base: Path | None) -> tuple[PrinterConfig, ...]:
    """The ``[[printers]]`` tables, checked: each has the keys of ``[printer]`` and a
    unique ``name``; ``[printer]`` and ``[[printers]]`` together are an error."""
    tables = data.get(PRINTERS)
    if tables is None:
        return ()
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict)
                                                             for t in tables):
        raise ConfigError("[[printers]]: expected one or more [[printers]] tables")
    if "printer" in data:
        raise ConfigError("[printer] and [[printers]] are both set: use [[printers]] tables "
                          "only (one per printer, each with a name), or the one [printer]")
    printers: list[PrinterConfig] = []
    for number, table in enumerate(tables, 1):
        if "name" not in table:
            raise ConfigError(f"[[printers]] table {number}: name is required (e.g. "
                              f'name = "left")')
        where = f"printers {_name(str(table['name']))}"
        printer = _section(where, table, PrinterConfig, base)
        if any(p.name == printer.name for p in printers):
            raise ConfigError(f"[[printers]] table {number}: the name {printer.name!r} is "
                              "used by another printer; names must be unique")
        if printer.port not in ("auto", "virtual") and any(p.port == printer.port
                                                           for p in printers):
            raise ConfigError(f"[[printers]] table {number}: port {printer.port!r} is given "
                              "to another printer too; each printer needs its own port")
        printers.append(printer)
    return tuple(printers)


def split_listen(listen: str) -> tuple[str, int] | None:
    """``"host:port"`` (``"[::]:8080"`` for IPv6) as (host, port), or None if malformed."""
    host, sep, port = listen.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        return None
    return host, int(port)


def load_config(path: str | os.PathLike[str] | None = None) -> Config:
    """Load the configuration: ``path``, else the system file, else the defaults.

    An explicitly given path that does not exist is an error; a missing system file is not.
    """
    if path is None:
        if not DEFAULT_CONFIG_PATH.is_file():
            cfg = parse_config({})
            return cfg
        path = DEFAULT_CONFIG_PATH
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"config file {p} does not exist") from None
    except OSError as e:
        raise ConfigError(f"config file {p} cannot be read: {e.strerror}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"config file {p} is not valid TOML: {e}") from None
    return parse_config(data, base=p.resolve().parent, source=str(p))


def check_profile(cfg: Config, nozzle: float = 0.4,
                  build_volume: tuple[float, float, float] | None = None) -> None:
    """Raise ConfigError if the ``[profile]`` overrides are not accepted by the slicer."""
    if not cfg.profile:
        return
    from slicer.profile import Profile, ProfileError  # heavy-ish; only when needed

    try:
        Profile.for_printer(nozzle_diameter=nozzle, build_volume=build_volume).with_overrides(
            cfg.profile)
    except ProfileError as e:  # its message may quote a long value: keep one short line
        message = " ".join(str(e).split())
        if len(message) > 200:
            message = message[:197] + "..."
        raise ConfigError(f"[profile] {message}") from None


def setup_logging(level: str) -> None:
    logging.basicConfig(level=getattr(logging, level, logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("watchdog").setLevel(max(logging.INFO, logging.getLogger().level))
