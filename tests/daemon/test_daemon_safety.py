"""Refused names, refused spool entries, the G-code command policy and build volume."""

import os

import pytest

from daemon.config import DEFAULT_FORBIDDEN_GCODES
from daemon.safety import (
    UnsafeEntry,
    check_gcode,
    check_name,
    check_spool_entry,
    is_partial_name,
    sanitise_name,
    strip_gcode,
)
from printer.gcode import command_word


@pytest.mark.parametrize("name", ["../x.stl", "..\\..\\evil.stl", "a/b.stl", "a\x00.stl",
                                  "bell\x07.stl", "..", "."])
def test_bad_names_are_refused(name):
    with pytest.raises(UnsafeEntry):
        check_name(name)


@pytest.mark.parametrize("name, safe", [
    ("part.stl", "part.stl"),
    ("my part (v2).stl", "my part (v2).stl"),
    ("..\\..\\evil.stl", "_._evil.stl"),
    ("a;rm -rf $HOME.stl", "a_rm -rf _HOME.stl"),
    ("", "unnamed"),
])
def test_sanitise(name, safe):
    out = sanitise_name(name)
    assert out == safe
    assert "/" not in out and "\\" not in out and not out.startswith(".")


def test_sanitise_caps_length_and_keeps_suffix():
    out = sanitise_name("x" * 500 + ".gcode")
    assert len(out) <= 120 and out.endswith(".gcode")


@pytest.mark.parametrize("name, partial", [
    ("a.stl.part", True), ("a.tmp", True), ("a.stl~", True), (".hidden.stl", True),
    ("a.stl", False), ("a.gcode", False), ("..\\..\\evil.stl", False),
])
def test_partial_names(name, partial):
    assert is_partial_name(name) is partial


def test_spool_entries(tmp_path):
    spool = tmp_path / "spool"
    spool.mkdir()
    outside = tmp_path / "secret.stl"
    outside.write_text("solid x\nendsolid x\n")
    good = spool / "good.stl"
    good.write_text("solid x\nendsolid x\n")
    assert check_spool_entry(spool, good).st_size > 0
    link = spool / "link.stl"
    os.symlink(outside, link)
    with pytest.raises(UnsafeEntry, match="symbolic link"):
        check_spool_entry(spool, link)
    (spool / "dir.stl").mkdir()
    with pytest.raises(UnsafeEntry, match="not a regular file"):
        check_spool_entry(spool, spool / "dir.stl")
    # the spool itself reached through a symlinked parent is still the spool
    alias = tmp_path / "alias"
    os.symlink(spool, alias)
    check_spool_entry(alias, alias / "good.stl")
    with pytest.raises(UnsafeEntry, match="outside"):
        check_spool_entry(spool, tmp_path / "secret.stl")


def test_gcode_command_normalises():
    assert command_word("N12 m0502 ; reset") == "M502"
    assert command_word("G1 X1") == "G1"
    assert command_word("; only a comment") is None
    assert command_word("M862.1 Q") == "M862.1"
    assert command_word("M 502") == "M502"


@pytest.mark.parametrize("cmd", ["M 502", "m 0502", "N7 M 500", "M502X", "M 997 ; update"])
def test_spellings_marlin_reads_as_a_forbidden_command_are_refused(cmd):
    """Marlin skips spaces between the letter and the number: ``M 502`` is M502."""
    lines = strip_gcode(["G28", cmd])
    with pytest.raises(UnsafeEntry, match="firmware-altering"):
        check_gcode(lines, forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=False,
                    build_volume=None)


@pytest.mark.parametrize("move", ["G1 X+900", "G1 X 900", "G1X900", "g1 x900", "G0 Y+.5 X+300.",
                                  "G1 Z+500"])
def test_moves_marlin_reads_outside_the_volume_are_refused(move):
    """Signs, spaces after the letter, no space before it, lower case: all are moves."""
    lines = strip_gcode(["G28", "G1 X10 Y10", move])
    with pytest.raises(UnsafeEntry, match="outside"):
        check_gcode(lines, forbidden=(), allow_firmware=False, build_volume=[250, 210, 220])


def test_a_number_stops_at_e_as_in_marlin():
    # "X1E5" is X1 and E5 to Marlin, not X=100000: a move to X1, inside the volume
    res = check_gcode(strip_gcode(["G1 X1E5"]), forbidden=(), allow_firmware=False,
                      build_volume=[250, 210, 220])
    assert res.extents_max[0] == 1.0


@pytest.mark.parametrize("cmd", ["M500", "M501", "M502", "M997", "M552 S1", "M587 S\"net\"",
                                 "m502"])
def test_firmware_altering_commands_are_refused(cmd):
    lines = strip_gcode(["G28", "G1 X10 Y10 Z0.2 F3000", cmd, "G1 X20"])
    with pytest.raises(UnsafeEntry, match="firmware-altering"):
        check_gcode(lines, forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=False,
                    build_volume=None)
    res = check_gcode(lines, forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=True,
                      build_volume=None)
    assert res.lines == 4


def test_parenthesised_comment_cannot_hide_a_command():
    lines = strip_gcode(["(harmless)M502", "G1 X1"])
    with pytest.raises(UnsafeEntry, match="M502"):
        check_gcode(lines, forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=False,
                    build_volume=None)


def test_comments_do_not_trigger_the_policy():
    lines = strip_gcode(["; M502 is mentioned here", "G1 X1 ; M500", "M5020"])
    check_gcode(lines, forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=False,
                build_volume=None)


def test_build_volume():
    ok = strip_gcode(["G90", "G1 X0 Y-3 Z0.3 E1", "G1 X200 Y200 Z10", "G91", "G1 Z5", "G90"])
    res = check_gcode(ok, forbidden=(), allow_firmware=False, build_volume=[250, 210, 220])
    assert res.extents_max == (200.0, 200.0, 15.0)
    bad = strip_gcode(["G1 X10 Y10", "G91", "G1 X100", "G1 X100", "G1 X100"])
    with pytest.raises(UnsafeEntry, match="X from 10.0 to 310.0 mm, outside"):
        check_gcode(bad, forbidden=(), allow_firmware=False, build_volume=[250, 210, 220])
    # G92 shifts the logical origin: X0 after G92 X-100 at X100 is machine X200
    shifted = strip_gcode(["G1 X100", "G92 X0", "G1 X150"])
    with pytest.raises(UnsafeEntry, match="outside"):
        check_gcode(shifted, forbidden=(), allow_firmware=False, build_volume=[200, 200, 200])


@pytest.mark.parametrize("line", ["G1 X" + "9" * 201, "G1 X" + "9" * 6000,
                                  "N" + "9" * 5000 + " M502"])
def test_absurd_numbers_are_refused_in_one_short_line(line):
    """Fuzz regressions: a 200-digit coordinate made a 503-character refusal; 5000 digits
    in a line number raised ValueError instead of a refusal."""
    with pytest.raises(UnsafeEntry) as refusal:
        check_gcode(strip_gcode([line]), forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=False,
                    build_volume=[250, 210, 220])
    message = str(refusal.value)
    assert len(message) <= 200 and "\n" not in message
