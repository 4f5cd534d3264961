"""The ``preflight`` console script: one parser, sub-commands from daemon.commands."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from daemon import __version__
from daemon import commands as _commands


def _command_modules() -> list[str]:
    """The modules of daemon/commands, by name. Listed from the folder rather than with
    pkgutil.iter_modules, whose import cost some 6 ms of CPU in every run of every
    command (measured on a busy 2-core machine)."""
    folder = _commands.__path__[0]
    return sorted(n[:-3] for n in os.listdir(folder)
                  if n.endswith(".py") and not n.startswith("_"))


def _terminal_columns() -> int:
    """The width shutil.get_terminal_size() gives: $COLUMNS, else stdout's terminal, else 80."""
    try:
        columns = int(os.environ.get("COLUMNS", "0"))
    except ValueError:
        columns = 0
    if columns <= 0:
        try:
            columns = os.get_terminal_size(sys.__stdout__.fileno()).columns
        except (AttributeError, ValueError, OSError):
            columns = 0
    return columns if columns > 0 else 80


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's help layout, sized without importing shutil: argparse builds a formatter
    for every add_argument (to check its metavar), and its default sizing imports shutil
    with its compression modules, ~2 ms of CPU in each run of every command."""

    def __init__(self, prog: str, indent_increment: int = 2, max_help_position: int = 24,
                 width: int | None = None) -> None:
        super().__init__(prog, indent_increment, max_help_position,
                         _terminal_columns() - 2 if width is None else width)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser with :class:`_HelpFormatter`; its sub-parsers are of this class too."""

    def __init__(self, *args, formatter_class=_HelpFormatter, **kwargs) -> None:
        super().__init__(*args, formatter_class=formatter_class, **kwargs)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole CLI's parser; with ``only`` (a module of daemon/commands), just that
    module's sub-commands: ``preflight slice ...`` then neither imports the other command
    modules nor builds their ~30 parsers (some 15 ms of CPU in a run that is mostly start-up
    on a small model)."""
    parser = _Parser(
        prog="preflight",
        description="Repair, slice and print 3D models dropped into a spool folder.",
    )
    parser.add_argument("--version", action="version", version=f"preflight {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in [only] if only else _command_modules():
        module = importlib.import_module(f"{_commands.__name__}.{name}")
        module.register(sub)
    parser.commands = sub.choices  # type: ignore[attr-defined]
    return parser


def _own_module(argv: list[str]) -> str | None:
    """The command module named like the sub-command in ``argv`` (``slice``, ``repair``),
    None when there is none (``run``, ``--help``...): then every module is registered."""
    word = argv[0] if argv else ""
    return word if word in _command_modules() else None


def _dispatch(argv: list[str] | None) -> tuple[int, argparse.Namespace | None]:
    """Parse ``argv`` and run its command: (exit status, the parsed arguments)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    only = _own_module(argv)
    parser = build_parser(only)
    if only and only not in parser.commands:  # a module, not a command: e.g. "daemon"
        parser = build_parser()
    args = parser.parse_args(argv)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help(sys.stderr)
        return 2, args
    try:
        return int(func(args) or 0), args
    except KeyboardInterrupt:
        print("preflight: interrupted", file=sys.stderr)
        return 130, args


def main(argv: list[str] | None = None) -> int:
    """Run the command in ``argv`` (default: the process's); its exit status."""
    return _dispatch(argv)[0]


def script() -> None:
    """The ``preflight`` console script (and ``python -m daemon.cli``): main(), then exit.
    A command that sets ``quick_exit`` (``slice``, ``repair``: its output is written and
    synced, its workers done, nothing is left to clean up) ends with os._exit once stdout
    and stderr are flushed, skipping the interpreter's teardown, which frees every imported
    module's objects one by one: ~10 ms of CPU, a few per cent of slicing a small model
    (after a 500k-triangle repair, with its arrays and native libraries, ~0.08 s)."""
    code, args = _dispatch(None)
    if getattr(args, "quick_exit", False):
        try:
            for stream in (sys.stdout, sys.stderr):
                if stream is not None:  # None: started with that descriptor closed
                    stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: the usual exit reports it
            sys.exit(code)
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    script()
