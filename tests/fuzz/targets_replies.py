"""Fuzz targets for the parsers of what a printer sends back (``printer.replies``).

A reply line comes from a serial port: noise, a wrong baud rate or a strange firmware
can put anything in it. Every parser must return a value for any text and never
raise (``expected=()``). Inputs: random text, random bytes decoded as the host
decodes them, and mutations of the real reply strings in the reply tests.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from harness import Target
from hypothesis import strategies as st

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


@st.composite
def mutated_reply(draw) -> str:
    """A real reply with characters inserted, deleted or replaced, or digits lengthened."""
    line = list(draw(st.sampled_from(REAL_REPLIES)))
    for _ in range(draw(st.integers(1, 4))):
        where = draw(st.integers(0, len(line)))
        action = draw(st.sampled_from(("insert", "delete", "replace", "digits")))
        char = draw(st.sampled_from(_ALPHABET) | st.characters())
        if action == "digits":
            line.insert(where, "9" * draw(st.integers(1, 20) | st.integers(4200, 6000)))
        elif action == "insert" or not line:
            line.insert(where, char)
        elif action == "delete":
            del line[min(where, len(line) - 1)]
        else:
            line[min(where, len(line) - 1)] = char
    return "".join(line)


#: Real replies with every number made very long (a noisy line can be 4 kB of digits).
long_numbers = st.builds(lambda line, digits: re.sub(r"\d+", "9" * digits, line),
                         st.sampled_from(REAL_REPLIES), st.integers(4200, 6000))


def _reply_line() -> st.SearchStrategy:
    return st.one_of(
        long_numbers,
        st.text(max_size=200),
        # what the host's reader makes of raw bytes
        st.binary(max_size=200).map(lambda data: data.decode("ascii", "replace")),
        st.text(alphabet=_ALPHABET, max_size=120),
        mutated_reply(),
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
