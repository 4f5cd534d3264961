"""CLI for the printer link: ``virtual-printer``, ``printer info|list`` and ``print``."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time

from daemon.commands import fail
from daemon.commands.daemon import _config_arg, _load


def register(subparsers) -> None:
    """Add ``virtual-printer``, ``printer info`` and ``print`` to the preflight CLI."""
    vp = subparsers.add_parser(
        "virtual-printer", help="run a simulated printer on a pseudo-terminal until stopped"
    )
    vp.add_argument("--firmware", default="marlin",
                    choices=("marlin", "prusa", "buddy", "klipper", "rrf"))
    vp.add_argument("--nozzle", type=float, default=0.4, help="nozzle diameter, mm")
    vp.add_argument("--baud", type=int, default=115200)
    vp.add_argument("--speedup", type=float, default=1.0,
                    help="simulated time runs this many times faster")
    vp.add_argument("--log", help="append every executed command to this file")
    vp.add_argument("--link", help="keep a symlink to the pty here (like /dev/serial/by-id)")
    vp.add_argument("--build-volume", type=float, nargs=3, metavar=("X", "Y", "Z"),
                    default=(250.0, 210.0, 220.0))
    vp.add_argument("--advanced-ok", action="store_true", help="send ADVANCED_OK oks")
    vp.add_argument("--corrupt", type=float, default=0.0,
                    help="probability of corrupting each host->printer byte")
    vp.add_argument("--drop-ok", type=float, default=0.0, help="probability of losing an ok")
    vp.add_argument("--busy", type=float, default=0.0,
                    help="G28/G29 take this many seconds with busy keepalives")
    vp.add_argument("--reset-after", type=int, help="board resets after N lines")
    vp.add_argument("--disconnect-after", type=int, help="port hangs up after N lines")
    vp.add_argument("--reconnect-after", type=float,
                    help="seconds after a disconnect to come back on a new pty")
    vp.add_argument("--garbage", action="store_true", help="send line noise (wrong baud)")
    vp.add_argument("--event", action="append", default=[], metavar="N:WHAT",
                    help="after N lines: kill, thermal_runaway, runout:SECONDS, or a line "
                         "starting with // sent as it is (e.g. 3000://action:cancel)")
    vp.add_argument("--seed", type=int, default=1)
    vp.set_defaults(func=_virtual_printer)

    pr = subparsers.add_parser("printer", help="talk to a printer")
    psub = pr.add_subparsers(dest="printer_command", metavar="ACTION")
    info = psub.add_parser("info", help="print firmware, nozzle, build volume, filament")
    _port_args(info)
    info.add_argument("--json", action="store_true", help="print JSON")
    info.add_argument("--klipper-socket", default="/tmp/klippy_uds",
                      help="Klipper's API socket (nozzle and build volume of a Klipper printer)")
    info.add_argument("--klipper-config", default=None,
                      help="Klipper's printer.cfg, read when the API socket is not there")
    info.set_defaults(func=_printer_info)
    found = psub.add_parser("list", help="scan the serial ports for printers and say why each "
                            "was or was not taken")
    found.add_argument("--scan", action="append", metavar="GLOB",
                       help="where to look, in order (repeatable; default: the config's "
                            "[printer] scan, /dev/serial/by-id/*, /dev/ttyACM*, /dev/ttyUSB*)")
    found.add_argument("--baud", type=int, action="append", metavar="BAUD",
                       help="baud rates to try, in order (repeatable; default 115200, "
                            "250000, 230400, 57600)")
    found.add_argument("--probe-seconds", type=float, default=None,
                       help="how long each port and baud rate may take to answer "
                            "(default: the config's, 3 s)")
    found.add_argument("--json", action="store_true", help="print JSON")
    _config_arg(found)
    found.set_defaults(func=_printer_list)
    pr.set_defaults(func=lambda args: (pr.print_help(sys.stderr), 2)[1])

    pp = subparsers.add_parser("print", help="stream a G-code file to a printer")
    pp.add_argument("file", help="G-code file")
    _port_args(pp)
    pp.add_argument("--mode", default="auto", choices=("auto", "ping-pong", "buffered"))
    pp.add_argument("--allow-firmware-commands", action="store_true",
                    help="send EEPROM, firmware-update, SD-card file and network commands "
                         "too (refused by default, as in the daemon)")
    pp.set_defaults(func=_print)


def _port_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="serial port, e.g. /dev/ttyACM0")
    parser.add_argument("--baud", type=int, default=115200)
    parser.add_argument("--timeout", type=float, default=4.0,
                        help="seconds of silence before lost-ok recovery")
    parser.add_argument("--nozzle", type=float, default=None,
                        help="nozzle diameter (mm) to use when the printer cannot tell")
    parser.add_argument("--nozzle-macro", default=None,
                        help="Klipper macro that prints the nozzle diameter")


def _virtual_printer(args) -> int:
    from printer.virtual import Faults, VirtualPrinter

    try:
        events = tuple((int(spec.split(":", 1)[0]), spec.split(":", 1)[1]) for spec in args.event)
    except (ValueError, IndexError):
        return fail(f"--event takes N:WHAT, e.g. 500:kill (got {' '.join(args.event)})", 2)
    faults = Faults(
        corrupt=args.corrupt, drop_ok=args.drop_ok, busy_seconds=args.busy,
        reset_after=args.reset_after, disconnect_after=args.disconnect_after,
        reconnect_after=args.reconnect_after, garbage=args.garbage, seed=args.seed,
        events=events,
    )
    try:
        vp = VirtualPrinter(
            args.firmware, nozzle=args.nozzle, baud=args.baud, speedup=args.speedup,
            faults=faults, log_path=args.log, link=args.link,
            advanced_ok=True if args.advanced_ok else None,
            build_volume=tuple(args.build_volume),
        )
        path = vp.start()
    except (OSError, ValueError) as exc:
        return fail(f"cannot start the virtual printer: {exc}")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(path, flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        vp.stop()
    return 0


def _host(args, mode: str = "auto"):
    from printer.host import PrinterHost

    return PrinterHost(
        args.port, args.baud, mode=mode, nozzle_fallback=args.nozzle,
        nozzle_macro=args.nozzle_macro, timeout=args.timeout,
    )


def _printer_info(args) -> int:
    from printer.errors import PrinterError
    from printer.identify import query_info

    try:
        with _host(args) as host:
            info = query_info(host, klipper_socket=args.klipper_socket,
                              klipper_config=args.klipper_config).to_dict()
    except PrinterError as exc:
        return fail(str(exc))
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    volume = info["build_volume"]
    print(f"firmware:          {info['firmware']} ({info['flavour']})")
    print(f"nozzle_diameter:   {info['nozzle_diameter']} mm (from {info['nozzle_source']})")
    vol = " x ".join(f"{v:g}" for v in volume) + " mm" if volume else "unknown"
    print(f"build_volume:      {vol} (from {info['build_volume_source']})")
    print(f"filament_diameter: {info['filament_diameter']} mm (from {info['filament_source']})")
    caps = ", ".join(k for k, v in sorted(info["capabilities"].items()) if v) or "none reported"
    print(f"capabilities:      {caps}")
    return 0


def _printer_list(args) -> int:
    """Scan like the daemon does with ``port = "auto"`` (its config's ``scan`` and its
    remembered port first), but probe every port and say why each was (not) taken."""
    from daemon.config import ConfigError
    from printer.discovery import PROBE_BAUDS, default_host, discover, remembered_choice

    try:
        cfg = _load(args)
    except ConfigError as exc:
        return fail(str(exc), 2)
    probe_seconds = args.probe_seconds or cfg.printer.probe_seconds
    if probe_seconds <= 0:
        return fail("--probe-seconds must be > 0")
    chatty = sys.stderr.isatty() and not args.json
    found = discover(args.scan or cfg.printer.scan, args.baud or PROBE_BAUDS,
                     remembered=remembered_choice(cfg.daemon.state_dir),
                     make_host=default_host(probe_seconds), scan_all=True,
                     progress=(lambda text: print(text, file=sys.stderr)) if chatty else None)
    if args.json:
        print(json.dumps({"scanned": list(found.scanned),
                          "candidates": [c.to_dict() for c in found.candidates]}, indent=2))
    elif not found.candidates:
        print(found.summary())
    else:
        for candidate in found.candidates:
            print(candidate.line())
    return 0 if found.chosen is not None else 1


class _Progress:
    """A one-line progress display on stderr (only on a terminal)."""

    def __init__(self) -> None:
        self.enabled = sys.stderr.isatty()
        self.start = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        elapsed = max(time.monotonic() - self.start, 1e-6)
        rate = done / elapsed
        eta = (total - done) / rate if rate > 0 else 0.0
        mins, secs = divmod(int(eta), 60)
        sys.stderr.write(
            f"\rprinting {100.0 * done / total:5.1f}%  {done}/{total} lines  "
            f"{rate:6.0f} lines/s  ETA {mins:d}:{secs:02d} "
        )
        sys.stderr.flush()

    def finish(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _policy_refusal(args, build_volume) -> str | None:
    """Why the daemon's G-code policy refuses the file for this printer, or None."""
    from daemon.config import DEFAULT_FORBIDDEN_GCODES
    from daemon.safety import UnsafeEntry, check_gcode

    try:
        with open(args.file, encoding="utf-8", errors="replace") as fh:
            check_gcode(fh, forbidden=DEFAULT_FORBIDDEN_GCODES,
                        allow_firmware=args.allow_firmware_commands, build_volume=build_volume)
    except UnsafeEntry as exc:
        hint = ("" if args.allow_firmware_commands or "firmware-altering" not in str(exc)
                else " (--allow-firmware-commands sends it anyway)")
        return f"{args.file}: {exc}".replace(
            "; set [safety] allow_firmware_commands = true to allow it", "") + hint
    return None


def _print(args) -> int:
    from printer.control import ParkSettings, PrintControl
    from printer.errors import PrinterError

    try:
        with open(args.file, encoding="utf-8", errors="replace") as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        return fail(f"cannot read {args.file}: {exc.strerror}")
    refusal = _policy_refusal(args, None)  # before the port is even opened
    if refusal:
        return fail(refusal)
    cancel = threading.Event()
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, lambda *_: cancel.set())
    progress = _Progress()
    try:
        with _host(args, args.mode) as host:
            volume = host.query_info().build_volume
            refusal = _policy_refusal(args, volume)
            if refusal:
                return fail(refusal)
            control = PrintControl(ParkSettings(build_volume=volume))  # Ctrl-C parks in it
            result = host.stream(lines, progress=progress, cancel=cancel, control=control)
    except PrinterError as exc:
        progress.finish()
        return fail(str(exc), 130 if cancel.is_set() else 1)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    progress.finish()
    print(
        f"printed {result.lines} lines in {result.seconds:.1f} s ({result.mode}; "
        f"{result.resends} resends, {result.timeouts} timeouts recovered)",
        file=sys.stderr,
    )
    return 0
