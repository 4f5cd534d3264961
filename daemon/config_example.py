"""The documented example config (``systemd/preflight.toml``), generated from the schema
in :mod:`daemon.config`: every key, its default and its one-line doc."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

from daemon.config import SECTIONS, Rule, rules

EXAMPLE_HEADER = """\
# /etc/preflight/preflight.toml - the preflight daemon's configuration.
# Every key is optional; the values shown are the built-in defaults unless noted.
# Generated from the schema in daemon/config.py by `preflight example-config`.
"""

EXAMPLE_PROFILE = """\
[profile]
# Any slicer profile setting (see `preflight slice --help`), e.g.:
# infill_percent = 15
# support = "auto"    # auto (where needed) | buildplate | everywhere | off
# brim = "auto"       # auto (tall parts on a small footprint) | on | off; brim_width = 5.0
# workers = "auto"    # processes per slice: auto (the CPUs; one for a small model) | 1..8
"""

EXAMPLE_PRINTERS = """\
# Several printers: instead of [printer], one [[printers]] table per printer with its
# keys and a unique name. Each job prints on one printer whose bed fits the model, and
# is repaired and sliced for its nozzle; pin a model with a sidecar <name>.toml holding
# nozzle=0.6, or by dropping it into the spool subfolder nozzle-0.6/ (README: Several
# printers). For example:
#[[printers]]
#name = "left"
#port = "/dev/serial/by-id/usb-Prusa_Research_Original_Prusa_MK3S-if00"
#[[printers]]
#name = "right"
#port = "auto"
#nozzle_diameter = 0.6
"""

COMMENT_COLUMN = 34


def _example_line(name: str, default: Any, rule: Rule) -> str:
    import tomli_w

    shown = rule.example if rule.example is not None else default
    if isinstance(shown, tuple):  # a list, wrapped; its doc goes on the line above
        prefix = f"{name} = ["
        items = textwrap.wrap(", ".join(tomli_w.dumps({"x": x})[4:].strip() for x in shown),
                              width=88 - len(prefix), break_long_words=False,
                              break_on_hyphens=False)
        body = ("\n" + " " * len(prefix)).join(items)
        mark = "# " if rule.commented else ""
        return f"# {rule.doc}\n" + "\n".join(
            mark + line for line in f"{prefix}{body}]".split("\n"))
    assignment = tomli_w.dumps({name: str(shown) if isinstance(shown, Path) else shown}).strip()
    doc = rule.doc + (f" ({' | '.join(rule.choices)})" if rule.choices else "")
    if rule.optional:
        doc += "; not set by default"
    elif rule.example is not None:
        doc += f" (default {tomli_w.dumps({'d': default}).strip()[4:]})"
    if rule.optional or rule.commented:
        assignment = "# " + assignment
    return f"{assignment.ljust(COMMENT_COLUMN - 2)}  # {doc}"


def example_config() -> str:
    """The documented example config (``systemd/preflight.toml``): every key, its default
    and its one-line doc, from the schema."""
    parts = [EXAMPLE_HEADER]
    for name, section in SECTIONS.items():
        lines = [f"[{name}]"] + [_example_line(key, default, rule)
                                 for key, default, rule in rules(section)]
        parts.append("\n".join(lines) + "\n")
        if name == "printer":
            parts.append(EXAMPLE_PRINTERS)
    parts.append(EXAMPLE_PROFILE)
    return "\n".join(parts)
