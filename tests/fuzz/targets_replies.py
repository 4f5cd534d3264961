"""Fuzz targets for the parsers of what a printer sends back (``printer.replies``).

A reply line comes from a serial port: noise, a wrong baud rate or a strange firmware
can put anything in it. Every parser must return a value for any text and never
raise (``expected=()``). Inputs: random text, random bytes decoded as the host
decodes them, and mutations of the real reply strings in the reply tests.
"""

from __future__ import annotations

import ast
from pathlib import Path

from harness import Target
from hypothesis import strategies as st
from text_lines import mutated, with_long_numbers

from printer import replies


def _real_replies() -> tuple[str, ...]:
    """Every string literal of the reply tests: the real lines each firmware prints."""
    source = Path(__file__).resolve().parents[1] / "printer" / "test_printer_replies.py"
    tree = ast.parse(source.read_text(encoding="utf-8"))
    found = {node.value for node in ast.walk(tree)
             if isinstance(node, ast.Constant) and isinstance(node.value, str)}
    return tuple(sorted(found))


REAL_REPLIES = _real_replies()
_ALPHABET = "okNPBTRrsesendErro:,/.-+0123456789 \t!@WCAXYZ{}\"'_"


def _reply_line() -> st.SearchStrategy:
    return st.one_of(
        with_long_numbers(REAL_REPLIES),
        st.text(max_size=200),
        # what the host's reader makes of raw bytes
        st.binary(max_size=200).map(lambda data: data.decode("ascii", "replace")),
        st.text(alphabet=_ALPHABET, max_size=120),
        mutated(REAL_REPLIES, _ALPHABET),
        st.sampled_from(REAL_REPLIES),
    )


PARSERS = (
    replies.parse_reply, replies.parse_temperatures, replies.unknown_command_of,
    replies.parse_firmware_fields, replies.parse_capability, replies.parse_area,
    replies.parse_soft_endstops, replies.parse_axis_limits, replies.parse_filament_diameter,
    replies.parse_nozzle_reply,
)


def run_all_parsers(line: str) -> object:
    return [parse(line) for parse in PARSERS]


TARGETS = [
    Target("replies", _reply_line(), run_all_parsers, (), ("printer.replies",)),
]
