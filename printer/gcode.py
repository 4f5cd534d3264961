"""The one G-code lexer, and line framing for the Marlin host protocol.

:func:`lex` reads one line the way Marlin's ``GCodeParser`` does, so everything that
looks at G-code (the host, the virtual printer, the daemon's safety policy, the
slicer's summary) sees the commands the firmware will run:

* an optional line number ``N<n>`` (capital N, as Marlin's queue requires) and an
  optional ``*<checksum>`` suffix: the XOR of every byte before the ``*``, decimal;
* ``;`` comments and ``( )`` comments (not nested: the first ``)`` ends one, an
  unclosed ``(`` runs to the end of the line), as Marlin's PAREN_COMMENTS;
* the command word, a letter G/M/T and an integer, spaces allowed in between
  (``M 502`` is M502, ``m0502`` is M502) and an optional subcode (``M862.1``,
  ``G29.1``); any other first token (a Klipper macro such as ``SET_FAN_SPEED``) is
  the word as written, upper case;
* parameters: a letter (any case), optional spaces, an optional value with a sign
  and a decimal point anywhere (``X+900``, ``X-5``, ``.5``, ``5.``, ``-0``). No
  exponent: Marlin stops a number at ``E`` so that ``X1E5`` is X1 and E5;
* the string argument of M23/M28/M30/M32/M33/M117/M118/M928 (a file name or a
  message), taken verbatim.

A framed line is ``N<n> <command>*<checksum>`` (:func:`frame`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

#: Commands whose argument is free text (a message or a file name), not parameters.
STRING_ARGUMENT_CODES = frozenset({"M23", "M28", "M30", "M32", "M33", "M117", "M118", "M928"})

#: The range of a C ``long`` on the 32-bit boards printers run on (what strtol returns).
LONG_MIN, LONG_MAX = -(2**31), 2**31 - 1

_PAREN_COMMENT = re.compile(r"\([^)]*(?:\)|$)")
_LINE_NUMBER = re.compile(r"\s*N([-+]?\d+)\s*")
_CHECKSUM_VALUE = re.compile(r"\s*([-+]?\d+)")
_STANDARD_WORD = re.compile(r"([GgMmTt])[ \t]*(\d+)(?:\.(\d*))?[ \t]*")
_OTHER_WORD = re.compile(r"(\S+)\s*")
_PARAMETER = re.compile(r"([A-Za-z])[ \t]*([-+]?(?:\d+\.?\d*|\.\d+))?")


@dataclass(frozen=True, slots=True)
class GcodeLine:
    """One lexed line.

    raw: the line as given. number: the ``N`` line number, or None. word: the command
    word, normalised (``"G1"``, ``"M862.1"``, ``"T0"``, ``"SET_FAN_SPEED"``), or None
    for a blank or comment-only line. params: (letter, value) pairs in order, letter
    upper case, value None for a bare letter (``G28 X``). text: the string argument
    of a message / file command, or the rest of the line after a non-G/M/T word.
    checksum: the number after ``*`` (0 when no digits follow, as Marlin reads it),
    None without a ``*``. body: the text the checksum covers (before the ``*``).
    command: the command as a host streams it (no comments, line number, checksum;
    outer whitespace stripped), "" for none.
    """

    raw: str
    number: int | None
    word: str | None
    params: tuple[tuple[str, float | None], ...]
    text: str
    checksum: int | None
    body: str
    command: str

    def value(self, letter: str, default: float | None = None) -> float | None:
        """The value of parameter ``letter`` (the last one wins, as in Marlin), or default."""
        found = default
        for name, number in self.params:
            if name == letter and number is not None:
                found = number
        return found

    def has(self, letter: str) -> bool:
        """True when parameter ``letter`` is present, with or without a value."""
        return any(name == letter for name, _ in self.params)


def firmware_int(digits: str) -> int:
    """An optionally signed decimal integer read as a firmware's ``strtol`` does, saturating
    at the 32-bit ``long`` range (a number of any length: never Python's digit limit)."""
    negative = digits.startswith("-")
    magnitude = digits.lstrip("+-").lstrip("0")
    if len(magnitude) > 10:
        return LONG_MIN if negative else LONG_MAX
    value = -int(magnitude or "0") if negative else int(magnitude or "0")
    return min(max(value, LONG_MIN), LONG_MAX)


def strip_comments(raw: str) -> str:
    """``raw`` without its ``;`` comment and its ``( )`` comments."""
    code = raw.split(";", 1)[0]
    if "(" in code:
        code = _PAREN_COMMENT.sub("", code)
    return code


def _word_and_arguments(command: str) -> tuple[str | None, tuple, str]:
    standard = _STANDARD_WORD.match(command)
    if standard is None:
        other = _OTHER_WORD.match(command)
        if other is None:
            return None, (), ""
        return other.group(1).upper(), (), command[other.end():]
    letter, code, subcode = standard.groups()
    word = f"{letter.upper()}{firmware_int(code)}"
    if subcode:
        word += f".{firmware_int(subcode)}"
    rest = command[standard.end():]
    if word in STRING_ARGUMENT_CODES:
        return word, (), rest
    params = tuple(
        (name.upper(), float(number) if number else None)
        for name, number in _PARAMETER.findall(rest)
    )
    return word, params, ""


def _frame_parts(raw: str) -> tuple[int | None, str, int | None, str]:
    """(line number, command, checksum, checksummed body) of one line."""
    code = strip_comments(raw)
    star = code.find("*")
    checksum_value: int | None = None
    body = code
    if star >= 0:
        body = code[:star]
        digits = _CHECKSUM_VALUE.match(code, star + 1)
        checksum_value = firmware_int(digits.group(1)) if digits else 0
    if "N" not in body:
        return None, body.strip(), checksum_value, body
    line_number = _LINE_NUMBER.match(body)
    if line_number is None:
        return None, body.strip(), checksum_value, body
    number = firmware_int(line_number.group(1))
    return number, body[line_number.end():].strip(), checksum_value, body


def lex(raw: str) -> GcodeLine:
    """Lex one G-code line (see the module docstring for the grammar). Never raises."""
    number, command, checksum_value, body = _frame_parts(raw)
    word, params, text = _word_and_arguments(command)
    return GcodeLine(raw=raw, number=number, word=word, params=params, text=text,
                     checksum=checksum_value, body=body, command=command)


def checksum(text: str, encoding: str = "ascii") -> int:
    """XOR of the bytes of ``text`` (the part before ``*``).

    ``ascii`` (characters it cannot encode become ``?``) gives the bytes a host writes;
    ``latin-1`` gives back, byte for byte, what a firmware received.
    """
    value = 0
    for byte in text.encode(encoding, "replace"):
        value ^= byte
    return value


def frame(number: int, command: str) -> str:
    """``N<number> <command>*<checksum>`` without the trailing newline."""
    body = f"N{number} {command}"
    return f"{body}*{checksum(body)}"


def clean_line(raw: str) -> str | None:
    """The command of a G-code file line as a host streams it, or None when there is none.

    Comments, a line number of the file's own and a ``*`` checksum are removed (the
    host numbers and checksums each line itself).
    """
    return _frame_parts(raw)[1] or None


def clean_lines(raw_lines: Iterable[str]) -> list[str]:
    """The commands of a G-code file, comments and blank lines removed, in order."""
    out = []
    for raw in raw_lines:
        command = _frame_parts(raw)[1]
        if command:
            out.append(command)
    return out


def command_word(command: str) -> str | None:
    """The normalised command word of a line (``"m862.1 Q"`` -> ``"M862.1"``), or None."""
    return lex(command).word
