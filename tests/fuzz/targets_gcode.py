"""Fuzz targets for G-code: the lexer and the daemon's G-code policy.

The lexer faces any line of any file: it must never raise (``expected=()``). The
policy (``daemon.safety.check_gcode`` on ``strip_gcode``'s output) faces short
programs of real and mutated lines; its one clean refusal is ``UnsafeEntry``.
"""

from __future__ import annotations

from harness import Target
from hypothesis import strategies as st
from text_lines import mutated, with_long_numbers

from daemon.config import DEFAULT_FORBIDDEN_GCODES
from daemon.safety import UnsafeEntry, check_gcode, strip_gcode
from printer.gcode import checksum, frame, lex

#: Real lines: PrusaSlicer, Cura, the Marlin docs, host framing, and tricky spellings.
REAL_LINES = (
    "G1 X94.614 Y88.263 E.03291", "G1 Z.2 F720", "M862.3 P \"MK3S\" ; printer model check",
    "M862.1 P0.4 ; nozzle diameter check", "G1 E-.8 F2100", "M73 P0 R16", "G29 ; mesh",
    "G0 F6000 X107.355 Y104.086 Z0.3", "G1 F1500 E-6.5", ";LAYER:0", "M107", "M104 S215",
    "M109 S215", "M140 S60", "M190 S60", "G28 W ; home all without mesh bed level",
    "G92 E0", "G90", "G91", "M82", "M83", "N0 M110 N0*125", "N123 G1 X10 Y20*97", "G29.1",
    "M862.1 Q", "T0", "M 502", "m0502", "G1 X 10", "G1 X+900", "G1X10Y20", "G1 X.5 Y5. Z-0",
    "G1 X1E5", "G28 X", "(purge) G1 X5 (slow) F600", "G1 X5 (unclosed Y900", "N5 *",
    "M117 Layer 1/20", "M23 /prints/cube.gco", "M500", "M997", "M552 S1", "G2 X10 Y10 I5 J0",
    "SET_FAN_SPEED FAN=part SPEED=0.5", "", "   ; only a comment",
)

_ALPHABET = "GMTNXYZEFSPIJQRgmtnxyz0123456789.+-* ;()\t\"/:="


mutated_line = mutated(REAL_LINES, _ALPHABET)


#: Very long numbers in every position a number can take (a file's line can be long).
long_numbers = st.builds(lambda prefix, digits: prefix + "9" * digits,
                         st.sampled_from(("N", "N-", "G1 X", "G1 X-", "M", "G1.", "T", "G1 X1*",
                                          "G1 X.", "M117 ")),
                         st.integers(1, 6000))


def _any_line() -> st.SearchStrategy:
    return st.one_of(
        long_numbers,
        with_long_numbers(REAL_LINES),
        st.text(max_size=120),
        st.binary(max_size=120).map(lambda data: data.decode("latin-1")),
        st.text(alphabet=_ALPHABET, max_size=80),
        mutated_line,
        st.sampled_from(REAL_LINES),
    )


def run_lexer(line: str) -> object:
    lexed = lex(line)
    if lexed.command:
        # the line as the host frames it reads back as the same command and number
        framed = lex(frame(7, lexed.command))
        assert (framed.number, framed.command) == (7, lexed.command), (line, framed)
        assert framed.checksum == checksum(framed.body), (line, framed)
    return lexed


def run_policy(lines: list[str]) -> object:
    return check_gcode(strip_gcode(lines), forbidden=DEFAULT_FORBIDDEN_GCODES,
                       allow_firmware=False, build_volume=[250.0, 210.0, 220.0])


TARGETS = [
    Target("gcode-lexer", _any_line(), run_lexer, (), ("printer.gcode",)),
    Target("gcode-policy", st.lists(st.one_of(st.sampled_from(REAL_LINES), mutated_line,
                                              long_numbers,
        with_long_numbers(REAL_LINES),
                                              st.text(alphabet=_ALPHABET, max_size=40)),
                                    max_size=12),
           run_policy, (UnsafeEntry,), ("daemon.safety", "printer.gcode")),
]
