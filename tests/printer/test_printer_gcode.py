"""The G-code lexer, table-driven over real lines (PrusaSlicer, Cura, Marlin docs) and
tricky ones that Marlin's parser reads in a way a naive split does not."""

import pytest

from printer.gcode import checksum, clean_line, clean_lines, command_word, frame, lex

# (line, word, params, line number, checksum)
TABLE = [
    # PrusaSlicer
    ("G1 X94.614 Y88.263 E.03291", "G1", (("X", 94.614), ("Y", 88.263), ("E", 0.03291)), None,
     None),
    ("G1 Z.2 F720", "G1", (("Z", 0.2), ("F", 720.0)), None, None),
    # Marlin's parser reads the letters of a quoted name as parameters, as this does
    ("M862.3 P \"MK3S\" ; printer model check", "M862.3",
     (("P", None), ("M", None), ("K", 3.0), ("S", None)), None, None),
    ("M862.1 P0.4 ; nozzle diameter check", "M862.1", (("P", 0.4),), None, None),
    ("G1 E-.8 F2100", "G1", (("E", -0.8), ("F", 2100.0)), None, None),
    ("M73 P0 R16", "M73", (("P", 0.0), ("R", 16.0)), None, None),
    ("G29 ; mesh bed leveling", "G29", (), None, None),
    # Cura
    ("G0 F6000 X107.355 Y104.086 Z0.3", "G0",
     (("F", 6000.0), ("X", 107.355), ("Y", 104.086), ("Z", 0.3)), None, None),
    ("G1 F1500 E-6.5", "G1", (("F", 1500.0), ("E", -6.5)), None, None),
    (";LAYER:0", None, (), None, None),
    ("M107", "M107", (), None, None),
    # Marlin docs and host framing
    ("N0 M110 N0*125", "M110", (("N", 0.0),), 0, 125),
    ("N123 G1 X10 Y20*97", "G1", (("X", 10.0), ("Y", 20.0)), 123, 97),
    ("G29.1", "G29.1", (), None, None),
    ("M862.1 Q", "M862.1", (("Q", None),), None, None),
    ("T0", "T0", (), None, None),
    ("T1 S1", "T1", (("S", 1.0),), None, None),
    # tricky: what Marlin's parser accepts
    ("M 502", "M502", (), None, None),
    ("m0502", "M502", (), None, None),
    ("G1 X 10", "G1", (("X", 10.0),), None, None),
    ("g1 x10 y-5", "G1", (("X", 10.0), ("Y", -5.0)), None, None),
    ("G1 X+900", "G1", (("X", 900.0),), None, None),
    ("G1X10Y20", "G1", (("X", 10.0), ("Y", 20.0)), None, None),
    ("G1 X.5 Y5. Z-0", "G1", (("X", 0.5), ("Y", 5.0), ("Z", -0.0)), None, None),
    ("G1 X-.5", "G1", (("X", -0.5),), None, None),
    ("G1 X1E5", "G1", (("X", 1.0), ("E", 5.0)), None, None),  # Marlin stops a number at E
    ("G28 X", "G28", (("X", None),), None, None),
    ("(purge) G1 X5 (slow) F600", "G1", (("X", 5.0), ("F", 600.0)), None, None),
    ("G1 X5 (an unclosed comment Y900", "G1", (("X", 5.0),), None, None),
    ("G1 X5 *12 ; checksum before a comment", "G1", (("X", 5.0),), None, 12),
    ("N5 *", None, (), 5, 0),
    ("N-1 M105*10", "M105", (), -1, 10),
    ("n5 G1 X1", "N5", (), None, None),  # a lower-case n is not a line number to Marlin
    ("SET_FAN_SPEED FAN=part SPEED=0.5", "SET_FAN_SPEED", (), None, None),
    ("", None, (), None, None),
    ("   ; only a comment", None, (), None, None),
]


@pytest.mark.parametrize(("line", "word", "params", "number", "check"), TABLE)
def test_lex_table(line, word, params, number, check):
    lexed = lex(line)
    assert lexed.word == word
    assert lexed.params == params
    assert lexed.number == number
    assert lexed.checksum == check
    assert lexed.raw == line


@pytest.mark.parametrize(
    ("line", "word", "text"),
    [
        ("M117 Layer 1/20 (50%)", "M117", "Layer 1/20"),
        ("M117 X10 is not a move", "M117", "X10 is not a move"),
        ("M118 E1 hello host", "M118", "E1 hello host"),
        ("M23 /prints/cube x.gco", "M23", "/prints/cube x.gco"),
        ("M28 part.gco", "M28", "part.gco"),
        ("M30 old.gco ; delete", "M30", "old.gco"),
        ("M117", "M117", ""),
    ],
)
def test_string_arguments_are_verbatim(line, word, text):
    lexed = lex(line)
    assert (lexed.word, lexed.text.strip(), lexed.params) == (word, text, ())


def test_value_last_one_wins_and_has():
    lexed = lex("G1 X1 X2 E")
    assert lexed.value("X") == 2.0
    assert lexed.value("Y") is None and lexed.value("Y", 7.0) == 7.0
    assert lexed.has("E") and lexed.value("E") is None


def test_checksum_covers_body_as_framed():
    framed = frame(7, "G1 X10 Y20")
    lexed = lex(framed)
    assert lexed.number == 7 and lexed.command == "G1 X10 Y20"
    assert lexed.checksum == checksum(lexed.body)


def test_checksum_encodings():
    # what a host writes (unencodable -> '?') vs the bytes a firmware received
    assert checksum("M117 \u00e9") == checksum("M117 ?")
    assert checksum("M117 \u00e9", "latin-1") == checksum("M117 ", "latin-1") ^ 0xE9


def test_clean_lines_drop_file_line_numbers_and_checksums():
    raw = ["N10 G28*33", "N11 G1 X5 ; go", "(only a comment)", "", "M117 hi (x)"]
    assert clean_lines(raw) == ["G28", "G1 X5", "M117 hi"]
    assert clean_line("N10") is None


def test_command_word():
    assert command_word("m862.1 q") == "M862.1"
    assert command_word("   ") is None


@pytest.mark.parametrize("line", ["N" + "9" * 5000 + " G1", "G1." + "9" * 5000,
                                  "M" + "9" * 4301, "G1 X1*" + "9" * 5000, "N-" + "9" * 5000])
def test_numbers_of_any_length_saturate_as_strtol(line):
    """Fuzz regression: int() of more than 4300 digits raised ValueError in the lexer."""
    lexed = lex(line)
    assert lexed.number in (None, 2**31 - 1, -(2**31))
    assert lexed.checksum in (None, 2**31 - 1)
    assert lexed.word is None or len(lexed.word) < 20
