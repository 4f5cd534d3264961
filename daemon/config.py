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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

DEFAULT_CONFIG_PATH = Path("/etc/preflight/preflight.toml")

#: Firmware-altering G-codes refused unless ``[safety] allow_firmware_commands``:
#: EEPROM save/load/reset, firmware update, network / Wi-Fi configuration.
DEFAULT_FORBIDDEN_GCODES = (
    "M500", "M501", "M502", "M504", "M997",
    "M540", "M550", "M551", "M552", "M553", "M554", "M555", "M556",
    "M587", "M588", "M589",
)


class ConfigError(ValueError):
    """A configuration value is wrong; the message names the key."""


@dataclass(frozen=True)
class SpoolConfig:
    path: Path = Path("/var/spool/preflight")
    settle_seconds: float = 5.0       # size/mtime stable this long => complete (no close event)
    close_grace_seconds: float = 0.3  # after close-after-write, wait this long for more writes
    poll: bool = False                # use a polling observer (network shares without inotify)


@dataclass(frozen=True)
class PrinterConfig:
    port: str = "virtual"             # device path, /dev/serial/by-id/..., or "virtual"
    baud: int = 115200
    nozzle_diameter: float = 0.4      # mm; used when the printer cannot report its nozzle
    mode: str = "auto"                # streaming mode passed to PrinterHost
    nozzle_macro: str | None = None   # Klipper macro reporting the nozzle
    reconnect_min_seconds: float = 1.0
    reconnect_max_seconds: float = 60.0
    # Only for port = "virtual":
    virtual_firmware: str = "marlin"
    virtual_speedup: float = 50.0
    virtual_log: Path | None = None   # append every executed command here


@dataclass(frozen=True)
class LimitsConfig:
    max_file_mb: float = 200.0
    max_triangles: int = 2_000_000
    repair_timeout: float = 600.0
    slice_timeout: float = 600.0
    repair_memory_mb: int = 2048
    slice_memory_mb: int = 2048
    max_attempts: int = 3             # a job whose processing died this often fails


@dataclass(frozen=True)
class DaemonConfig:
    state_dir: Path = Path("/var/lib/preflight")
    auto_print: bool = True
    log_level: str = "INFO"
    workers: int = 1                  # repair/slice jobs processed at once


@dataclass(frozen=True)
class SafetyConfig:
    allow_firmware_commands: bool = False
    forbidden_gcodes: tuple[str, ...] = DEFAULT_FORBIDDEN_GCODES


@dataclass(frozen=True)
class WebConfig:
    listen: str = "0.0.0.0:8080"      # host:port of the slicer-facing HTTP API; "" turns it off
    max_upload_mb: float = 1024.0


@dataclass(frozen=True)
class Config:
    spool: SpoolConfig = field(default_factory=SpoolConfig)
    printer: PrinterConfig = field(default_factory=PrinterConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    daemon: DaemonConfig = field(default_factory=DaemonConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    web: WebConfig = field(default_factory=WebConfig)
    profile: dict[str, Any] = field(default_factory=dict)  # slicer Profile overrides
    source: str = "built-in defaults"

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


# --- validation helpers ------------------------------------------------------------------

def _key(section: str, name: str) -> str:
    return f"[{section}] {name}"


def _bool(section: str, name: str, v: Any) -> bool:
    if isinstance(v, bool):
        return v
    raise ConfigError(f"{_key(section, name)}: expected true or false, got {v!r}")


def _num(section: str, name: str, v: Any, *, lo: float, hi: float, integer: bool = False,
         open_lo: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(f"{_key(section, name)}: expected a number, got {v!r}")
    if integer and not isinstance(v, int):
        raise ConfigError(f"{_key(section, name)}: expected a whole number, got {v!r}")
    if v != v or (v <= lo if open_lo else v < lo) or v > hi:
        rng = f"{'>' if open_lo else '>='} {lo} and <= {hi}"
        raise ConfigError(f"{_key(section, name)}: {v!r} is out of range (must be {rng})")
    return int(v) if integer else float(v)


def _str(section: str, name: str, v: Any) -> str:
    if not isinstance(v, str) or not v.strip():
        raise ConfigError(f"{_key(section, name)}: expected a non-empty string, got {v!r}")
    return v


def _path(section: str, name: str, v: Any, base: Path | None) -> Path:
    p = Path(os.path.expanduser(_str(section, name, v)))
    if not p.is_absolute() and base is not None:
        p = base / p
    return p


_SECTIONS = {"spool", "printer", "limits", "daemon", "safety", "web", "profile"}


def parse_config(data: dict[str, Any], *, base: Path | None = None,
                 source: str = "built-in defaults") -> Config:
    """Validate a parsed TOML mapping into a :class:`Config`.

    Relative paths are taken relative to ``base`` (the config file's folder).
    Unknown sections or keys are errors, so that a typo never passes silently.
    """
    for sect in data:
        if sect not in _SECTIONS:
            raise ConfigError(f"[{sect}]: unknown section (known: {', '.join(sorted(_SECTIONS))})")
        if not isinstance(data[sect], dict):
            raise ConfigError(f"[{sect}]: expected a table")

    def take(sect: str, known: set[str]) -> dict[str, Any]:
        d = dict(data.get(sect, {}))
        for k in d:
            if k not in known:
                raise ConfigError(f"{_key(sect, k)}: unknown key "
                                  f"(known: {', '.join(sorted(known))})")
        return d

    s = take("spool", {"path", "settle_seconds", "close_grace_seconds", "poll"})
    spool = SpoolConfig()
    spool = SpoolConfig(
        path=_path("spool", "path", s["path"], base) if "path" in s else spool.path,
        settle_seconds=_num("spool", "settle_seconds",
                            s.get("settle_seconds", spool.settle_seconds), lo=0.05, hi=3600),
        close_grace_seconds=_num("spool", "close_grace_seconds",
                                 s.get("close_grace_seconds", spool.close_grace_seconds),
                                 lo=0, hi=60),
        poll=_bool("spool", "poll", s.get("poll", spool.poll)),
    )

    p = take("printer", {"port", "baud", "nozzle_diameter", "mode", "nozzle_macro",
                         "reconnect_min_seconds", "reconnect_max_seconds", "virtual_firmware",
                         "virtual_speedup", "virtual_log"})
    d = PrinterConfig()
    baud = _num("printer", "baud", p.get("baud", d.baud), lo=300, hi=4_000_000, integer=True)
    mode = _str("printer", "mode", p.get("mode", d.mode))
    if mode not in ("auto", "ping-pong", "buffered"):
        raise ConfigError(f"[printer] mode: {mode!r} is not one of auto, ping-pong, buffered")
    fw = _str("printer", "virtual_firmware", p.get("virtual_firmware", d.virtual_firmware))
    if fw not in ("marlin", "prusa", "buddy", "klipper", "rrf"):
        raise ConfigError(f"[printer] virtual_firmware: {fw!r} is not one of "
                          "marlin, prusa, buddy, klipper, rrf")
    rmin = _num("printer", "reconnect_min_seconds",
                p.get("reconnect_min_seconds", d.reconnect_min_seconds), lo=0.01, hi=3600)
    rmax = _num("printer", "reconnect_max_seconds",
                p.get("reconnect_max_seconds", d.reconnect_max_seconds), lo=rmin, hi=86400)
    printer = PrinterConfig(
        port=_str("printer", "port", p.get("port", d.port)),
        baud=int(baud),
        nozzle_diameter=_num("printer", "nozzle_diameter",
                             p.get("nozzle_diameter", d.nozzle_diameter), lo=0.05, hi=3.0,
                             open_lo=True),
        mode=mode,
        nozzle_macro=_str("printer", "nozzle_macro", p["nozzle_macro"]) if "nozzle_macro" in p
        else None,
        reconnect_min_seconds=rmin,
        reconnect_max_seconds=rmax,
        virtual_firmware=fw,
        virtual_speedup=_num("printer", "virtual_speedup", p.get("virtual_speedup",
                             d.virtual_speedup), lo=0.01, hi=1e6),
        virtual_log=_path("printer", "virtual_log", p["virtual_log"], base)
        if "virtual_log" in p else None,
    )

    lim = take("limits", {"max_file_mb", "max_triangles", "repair_timeout", "slice_timeout",
                          "repair_memory_mb", "slice_memory_mb", "max_attempts"})
    dl = LimitsConfig()
    limits = LimitsConfig(
        max_file_mb=_num("limits", "max_file_mb", lim.get("max_file_mb", dl.max_file_mb),
                         lo=0, hi=1e6, open_lo=True),
        max_triangles=int(_num("limits", "max_triangles", lim.get("max_triangles",
                               dl.max_triangles), lo=1, hi=1e9, integer=True)),
        repair_timeout=_num("limits", "repair_timeout", lim.get("repair_timeout",
                            dl.repair_timeout), lo=0, hi=1e6, open_lo=True),
        slice_timeout=_num("limits", "slice_timeout", lim.get("slice_timeout", dl.slice_timeout),
                           lo=0, hi=1e6, open_lo=True),
        repair_memory_mb=int(_num("limits", "repair_memory_mb", lim.get("repair_memory_mb",
                                  dl.repair_memory_mb), lo=64, hi=1e7, integer=True)),
        slice_memory_mb=int(_num("limits", "slice_memory_mb", lim.get("slice_memory_mb",
                                 dl.slice_memory_mb), lo=64, hi=1e7, integer=True)),
        max_attempts=int(_num("limits", "max_attempts", lim.get("max_attempts",
                              dl.max_attempts), lo=1, hi=100, integer=True)),
    )

    dm = take("daemon", {"state_dir", "auto_print", "log_level", "workers"})
    dd = DaemonConfig()
    level = _str("daemon", "log_level", dm.get("log_level", dd.log_level)).upper()
    if level not in ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"):
        raise ConfigError(f"[daemon] log_level: {level!r} is not one of "
                          "DEBUG, INFO, WARNING, ERROR, CRITICAL")
    daemon = DaemonConfig(
        state_dir=_path("daemon", "state_dir", dm["state_dir"], base) if "state_dir" in dm
        else dd.state_dir,
        auto_print=_bool("daemon", "auto_print", dm.get("auto_print", dd.auto_print)),
        log_level=level,
        workers=int(_num("daemon", "workers", dm.get("workers", dd.workers), lo=1, hi=64,
                         integer=True)),
    )

    sf = take("safety", {"allow_firmware_commands", "forbidden_gcodes"})
    ds = SafetyConfig()
    forbidden = sf.get("forbidden_gcodes", list(ds.forbidden_gcodes))
    if not isinstance(forbidden, list) or not all(isinstance(x, str) and x.strip()
                                                  for x in forbidden):
        raise ConfigError("[safety] forbidden_gcodes: expected a list of G-code words "
                          "like \"M502\"")
    safety = SafetyConfig(
        allow_firmware_commands=_bool("safety", "allow_firmware_commands",
                                      sf.get("allow_firmware_commands",
                                             ds.allow_firmware_commands)),
        forbidden_gcodes=tuple(x.strip().upper() for x in forbidden),
    )

    w = take("web", {"listen", "max_upload_mb"})
    listen = w.get("listen", WebConfig.listen)
    if not isinstance(listen, str) or (listen and split_listen(listen) is None):
        raise ConfigError(f"[web] listen: expected \"host:port\" or \"\" (off), got {listen!r}")
    web = WebConfig(listen=listen, max_upload_mb=_num(
        "web", "max_upload_mb", w.get("max_upload_mb", WebConfig.max_upload_mb), lo=0, hi=1e7,
        open_lo=True))

    profile = dict(data.get("profile", {}))
    return Config(spool=spool, printer=printer, limits=limits, daemon=daemon, safety=safety,
                  web=web, profile=profile, source=source)


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
    except ProfileError as e:
        raise ConfigError(f"[profile] {e}") from None


def setup_logging(level: str) -> None:
    logging.basicConfig(level=getattr(logging, level, logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("watchdog").setLevel(max(logging.INFO, logging.getLogger().level))
