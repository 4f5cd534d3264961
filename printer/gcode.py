"""G-code line framing for the Marlin host protocol: line numbers and XOR checksums.

A framed line is ``N<n> <command>*<checksum>`` where the checksum is the XOR of
every byte before the ``*`` (RepRap/Marlin convention), as a decimal 0..255.
"""

from __future__ import annotations

from collections.abc import Iterable


def checksum(text: str) -> int:
    """XOR of the ASCII bytes of ``text`` (the part before ``*``)."""
    value = 0
    for byte in text.encode("ascii", "replace"):
        value ^= byte
    return value


def frame(number: int, command: str) -> str:
    """``N<number> <command>*<checksum>`` without the trailing newline."""
    body = f"N{number} {command}"
    return f"{body}*{checksum(body)}"


def clean_line(raw: str) -> str | None:
    """Strip comments (``;`` and parenthesised) and whitespace; None for an empty line.

    A checksum character ``*`` inside a command would corrupt the framing, so a
    line that contains one is cut there (slicers never emit it).
    """
    line = raw.split(";", 1)[0]
    if "(" in line:
        out = []
        depth = 0
        for ch in line:
            if ch == "(":
                depth += 1
            elif ch == ")" and depth:
                depth -= 1
            elif not depth:
                out.append(ch)
        line = "".join(out)
    line = line.split("*", 1)[0].strip()
    return line or None


def clean_lines(raw_lines: Iterable[str]) -> list[str]:
    """The commands of a G-code file, comments and blank lines removed, in order."""
    out = []
    for raw in raw_lines:
        line = clean_line(raw)
        if line is not None:
            out.append(line)
    return out


def command_word(command: str) -> str:
    """The G/M/T word of a command, upper case (``"M862.1 Q"`` -> ``"M862.1"``)."""
    word = command.split(None, 1)[0] if command.strip() else ""
    return word.upper()
