"""The G-code policy as the firmware reads G-code: every evasion is refused, arcs are
checked along their sweep, legitimate slicer output passes, and the check streams."""

from __future__ import annotations

import math
import tracemalloc
from pathlib import Path

import pytest

from daemon.config import DEFAULT_FORBIDDEN_GCODES
from daemon.safety import UnsafeEntry, arc_extents, check_gcode
from printer.gcode import checksum, lex

VOLUME = [100.0, 100.0, 100.0]  # with the 5 mm margin: -5 .. 105 on each axis
DATA = Path(__file__).resolve().parents[1] / "data"


def check(lines, volume=VOLUME, allow=False):
    return check_gcode(lines, forbidden=DEFAULT_FORBIDDEN_GCODES, allow_firmware=allow,
                       build_volume=volume)


def framed(command: str, n: int = 7) -> str:
    body = f"N{n} {command}"
    return f"{body}*{checksum(body)}"


@pytest.mark.parametrize("line", [
    "M28 evil.gco", "M 28 evil.gco", "m28 evil.gco", "M028 evil.gco", "M29", "m 29",
    "M30 /cfg.g", "M 30 config.g", "M32 P !start.g#", "M23 part.gco", "M24", "m 24",
    "M928 log.txt", framed("M28 x.gco"), framed("M 30 x.g"), "N12 M24*99",
    "(select) M23 a.gco", "M23 a.gco ; select a file", "  \tM24  ", "M502 (reset)",
    "M500*5", "m 0500", "M997", framed("M552 S1"), "M587 S\"net\" P\"pw\"",
])
def test_evasions_of_the_command_policy_are_refused(line):
    """Spaces, signs, lower case, leading zeros, line numbers, checksums and comments
    around a forbidden command: Marlin runs each of these, so each is refused."""
    with pytest.raises(UnsafeEntry, match="firmware-altering"):
        check(["G28", "G1 X10 Y10 Z1 F3000", line, "G1 X20"])
    # and the same file passes when the user allows firmware commands
    assert check(["G28", "G1 X10 Y10 Z1 F3000", line, "G1 X20"], allow=True).lines == 4


@pytest.mark.parametrize("line", ["; M28 evil.gco", "G1 X1 ; M30", "(M24) G1 X2", "M280 P0 S90",
                                  "M117 M28 in a message", "M118 E1 M30"])
def test_mentions_and_neighbours_are_not_refused(line):
    check(["G28", line])


@pytest.mark.parametrize("moves, why", [
    # full circles (I/J form: end = start), both directions
    (["G1 X50 Y50", "G2 X50 Y50 I40 J0"], "X from"),
    (["G1 X50 Y50", "G3 X50 Y50 I-40 J0"], "X from"),
    (["G1 X50 Y50", "G3 I0 J-40"], "Y from"),  # no end given: a full circle in place
    # a half circle whose end points are inside but whose sweep is not
    (["G1 X80 Y20", "G3 X80 Y80 I0 J30"], "X from"),
    (["G1 X20 Y20", "G2 X20 Y80 I0 J30"], "X from"),
    # R form: the short and the long (negative R) arc
    (["G1 X80 Y20", "G3 X80 Y80 R30"], "X from"),
    (["G1 X80 Y40", "G3 X80 Y60 R-20"], "X from"),
    # relative coordinates, spaces, signs and lower case in an arc
    (["G1 X80 Y20", "G91", "g 3 x+0 y+60 i 0 j+30"], "X from"),
    # P: extra full turns on a short arc
    (["G1 X50 Y90", "G2 X55 Y89.75 I0 J-50 P1"], "Y from"),
    # an arc in the ZX plane (G18) that climbs out of the top
    (["G1 X50 Y50 Z10", "G18", "G2 X50 Z10 K50"], "Z from"),
    # and one hidden behind a checksum
    (["G1 X50 Y50", framed("G2 X50 Y50 I40 J0")], "X from"),
])
def test_arcs_leaving_the_volume_are_refused(moves, why):
    with pytest.raises(UnsafeEntry, match=f"{why}.*outside"):
        check(["G28", "G90", *moves])


@pytest.mark.parametrize("moves", [
    ["G1 X80 Y20", "G2 X80 Y80 I0 J30"],    # the other way round the same circle
    ["G1 X20 Y20", "G3 X20 Y80 I0 J30"],
    ["G1 X80 Y20", "G2 X80 Y80 R30"],
    ["G1 X80 Y40", "G3 X80 Y60 R20"],       # the short arc
    ["G1 X50 Y50", "G2 X50 Y50 I20 J0"],    # a full circle that fits
    ["G1 X50 Y50 Z1", "G2 X60 Y60 Z5 I5 J5"],  # helical
])
def test_arcs_inside_the_volume_pass(moves):
    res = check(["G28", "G90", *moves])
    assert max(res.extents_max) <= 105 and min(res.extents_min) >= -5


def test_arc_extents_match_a_dense_sampling_of_the_sweep():
    """The analytic box equals the box of 20 000 points along the arc, for arcs of every
    start angle, sweep, direction and form."""
    cases = [((80, 20, 0), (80, 80, 0), "G3 X80 Y80 I0 J30", False),
             ((80, 20, 0), (80, 80, 0), "G2 X80 Y80 I0 J30", True),
             ((30, 40, 0), (26, 22, 0), "G2 X26 Y22 I7 J-11", True),
             ((30, 40, 0), (26, 22, 0), "G3 X26 Y22 I7 J-11", False),
             ((80, 40, 0), (80, 60, 0), "G3 X80 Y60 R-20", False),
             ((80, 40, 0), (80, 60, 0), "G2 X80 Y60 R20", True)]
    for start, end, text, clockwise in cases:
        lexed = lex(text)
        lo, hi = arc_extents(start, end, lexed, clockwise=clockwise)
        samples = _sample_arc(start, end, lexed, clockwise)
        for k in range(2):
            assert lo[k] == pytest.approx(min(p[k] for p in samples), abs=1e-3)
            assert hi[k] == pytest.approx(max(p[k] for p in samples), abs=1e-3)


def _sample_arc(start, end, lexed, clockwise):
    """An independent construction: the centre from I/J, or from R by intersecting the
    two circles of radius |R| around the end points and picking the side by sweep."""
    r = lexed.value("R")
    if r is None:
        cx, cy = start[0] + lexed.value("I", 0), start[1] + lexed.value("J", 0)
    else:
        mx, my = (start[0] + end[0]) / 2, (start[1] + end[1]) / 2
        dx, dy = end[0] - start[0], end[1] - start[1]
        d = math.hypot(dx, dy)
        h = math.sqrt(max(r * r - d * d / 4, 0))
        options = [(mx - h * dy / d, my + h * dx / d), (mx + h * dy / d, my - h * dx / d)]
        want_long = r < 0
        cx, cy = next(c for c in options
                      if (abs(_sweep(start, end, c, clockwise)) > math.pi) == want_long)
    sweep = _sweep(start, end, (cx, cy), clockwise)
    a0 = math.atan2(start[1] - cy, start[0] - cx)
    radius = math.hypot(start[0] - cx, start[1] - cy)
    return [(cx + radius * math.cos(a0 + sweep * i / 20000),
             cy + radius * math.sin(a0 + sweep * i / 20000)) for i in range(20001)]


def _sweep(start, end, centre, clockwise):
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
    ccw = (a1 - a0) % (2 * math.pi)
    return ccw - 2 * math.pi if clockwise else ccw


def prusaslicer_style_arcs(cx: float, cy: float, radius: float = 10.0) -> list[str]:
    """G-code written as PrusaSlicer 2.6+ writes it with arc fitting (``emit_center``):
    its header, ``;TYPE:`` and ``;WIDTH:`` comments, relative E, and G2/G3 with I J."""
    lines = ["; generated by PrusaSlicer 2.6.1+linux-x64-GTK3 on 2023-09-18 at 10:12:01 UTC",
             "", "; external perimeters extrusion width = 0.45mm", "M73 P0 R5", "M201 X1000 Y1000",
             "M107", ";TYPE:Custom", "G90 ; use absolute coordinates", "M83 ; extruder relative",
             "M104 S215", "M140 S60", "M190 S60", "M109 S215", "G28 W ; home all without mesh",
             "G1 Z0.2 F720", "G1 Y-3 F1000", "G92 E0", "G1 X60 E9 F1000 ; intro line",
             "G92 E0", "M221 S95"]
    a = radius / math.sqrt(2)  # the seam at 45 degrees, as PrusaSlicer's aligned seam
    for layer in range(1, 6):
        z = 0.2 * layer
        lines += [";LAYER_CHANGE", f";Z:{z:.1f}", ";HEIGHT:0.2", f"G1 Z{z:.1f} F720",
                  f"G1 X{cx + a:.3f} Y{cy + a:.3f} F9000", ";TYPE:External perimeter",
                  ";WIDTH:0.449999", f"G3 X{cx - a:.3f} Y{cy - a:.3f} I{-a:.3f} J{-a:.3f} "
                  "E1.04720 F1800", f"G3 X{cx + a:.3f} Y{cy + a:.3f} I{a:.3f} J{a:.3f} E1.04720",
                  f"G2 X{cx:.3f} Y{cy + a:.3f} R{a:.3f} E.3"]
    lines += ["G1 E-.8 F2100", "M104 S0 ; turn off temperature", "M140 S0", "M107",
              "G1 Z30 F720", "M84 X Y E ; disable motors", "M73 P100 R0", "",
              "; prusaslicer_config = begin", "; arc_fitting = emit_center",
              "; prusaslicer_config = end"]
    return lines


def test_prusaslicer_style_output_with_arcs_passes_and_the_same_near_the_edge_is_refused():
    res = check(prusaslicer_style_arcs(50.0, 50.0))
    assert res.extents_max[0] == pytest.approx(60.0)
    assert res.extents_min[1] == pytest.approx(-3.0)
    # moved so that every end point is inside (X <= 104) but the circles bulge to X 108.5
    edge = prusaslicer_style_arcs(94.0, 50.0, radius=14.5)
    ends = [lex(line).value("X") for line in edge if lex(line).word in ("G1", "G2", "G3")]
    assert max(x for x in ends if x is not None) < 105
    with pytest.raises(UnsafeEntry, match="X from .* to 108.5 mm, outside"):
        check(edge)


def test_embedded_slicer_output_passes(tmp_path):
    from slicer.engine import slice_file
    from slicer.profile import Profile

    out = tmp_path / "cube.gcode"
    slice_file(DATA / "cube_20mm.3mf", out, Profile.for_printer())
    with open(out, encoding="utf-8") as f:
        res = check(f, volume=[250.0, 210.0, 220.0])
    assert res.lines > 100 and res.extents_max[2] > 19.0


def test_the_check_streams_a_file_in_bounded_memory(tmp_path):
    """A file is checked from the open file, never held in memory at once: the peak
    is a fraction of the file's size (the list of its lines would be twice its size)."""
    path = tmp_path / "big.gcode"
    block = "".join(f"G1 X{10 + i % 80}.5 Y{20 + i % 70}.25 E0.0123 F1800 ; move\n"
                    for i in range(1000))
    with open(path, "w") as f:
        f.write("G28\nG90\n")
        for _ in range(30):
            f.write(block)
    size = path.stat().st_size
    assert size > 1e6
    tracemalloc.start()
    try:
        with open(path, encoding="utf-8") as f:
            res = check(f, volume=[250.0, 210.0, 220.0])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert res.lines == 30 * 1000 + 2
    assert peak < size / 4, f"the check held {peak / 1e6:.2f} MB of a {size / 1e6:.1f} MB file"
