"""The ``preflight`` console script: one parser, sub-commands from daemon.commands."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from daemon import __version__
from daemon import commands as _commands


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="preflight",
        description="Repair, slice and print 3D models dropped into a spool folder.",
    )
    parser.add_argument("--version", action="version", version=f"preflight {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(_commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{_commands.__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(func(args) or 0)
    except KeyboardInterrupt:
        print("preflight: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
