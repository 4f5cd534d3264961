"""A finish that stops taking the whole arrangement again (issue 18: bounded rounds,
:data:`repair.finish.HULL_GROWTH`) says why, end to end: through :func:`repair_mesh`,
the exact path's refusal, the fallback's reason, and the fallback's own finish.

The input: two wavy sheets crossing each other, 20 km from the origin, repaired with an
eps of 3 um -- where float32 values are ~2 um apart, so the slabs of thickness eps the
sheets become are a ulp or two thick, and rounding the arrangement's vertices makes
their faces cross again, more each time the whole arrangement is taken again."""

from __future__ import annotations

import numpy as np
import pytest

from repair.errors import RepairError
from repair.finish import HULL_GROWTH
from repair.pipeline import NOT_PRINTABLE, repair_mesh

#: Far from the origin (mm): float32 spacing there is 2**-9 mm ~ 2 um.
FAR = 20_000.0
#: The nozzle (mm): a ulp or two.
TINY_EPS = 0.003
#: What the finish says when it refuses a round that grows the damage.
GREW = "whole-arrangement rounds grew the damage"


def _wavy_sheets(cells: int = 8, size: float = 10.0, amp: float = 0.5):
    """Two open height-field sheets, z = +-amp sin(1.3 x) cos(0.7 y) over a square of
    ``size`` mm in ``cells`` x ``cells`` squares (two triangles each), crossing each other
    along curves; moved by :data:`FAR` on every axis."""
    g = np.linspace(0.0, size, cells + 1)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    z = amp * np.sin(1.3 * x) * np.cos(0.7 * y)
    i = (np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]).ravel()
    sheet = np.r_[np.c_[i, i + 1, i + cells + 2], np.c_[i, i + cells + 2, i + cells + 1]]
    v = np.r_[np.c_[x, y, z], np.c_[x, y, -z]] + FAR
    return v, np.r_[sheet, sheet + len(x)]


@pytest.mark.slow  # ~10 s of CPU: two finishes that each run until they stop
def test_a_finish_that_stops_growing_says_why_on_both_paths() -> None:
    v, f = _wavy_sheets()
    with pytest.raises(RepairError) as raised:
        repair_mesh(v, f, TINY_EPS)
    message = str(raised.value)
    # The exact path's finish refused a round over HULL_GROWTH times the damage of the
    # one before; that refusal is the fallback's reason ...
    assert message.startswith(NOT_PRINTABLE)
    exact, _, fallback = message.partition(", and the fallback failed: ")
    assert fallback, message  # the fallback was tried
    assert GREW in exact and f"over {HULL_GROWTH:g}x a round" in exact
    # ... and the fallback's own finish stopped the same way: its reason is given too,
    # not only the verdict's failures.
    assert GREW in fallback
    for part in (exact, fallback):
        grown = [int(n) for n in part.split(GREW)[1].split("(")[0].split("->")]
        assert grown[1] > HULL_GROWTH * grown[0]


def test_a_fallback_whose_union_comes_out_inside_out_says_so() -> None:
    # At eps 1 um, half a float32 ulp here, manifold3d's union of the sheets' slabs is one
    # shell of negative volume (-0.06 mm³, edges of three faces); dropping inward shells
    # (cavities) left nothing, and the reason read "the mesh has no triangles".
    v, f = _wavy_sheets()
    with pytest.raises(RepairError) as raised:
        repair_mesh(v, f, 0.001)
    fallback = str(raised.value).partition(", and the fallback failed: ")[2]
    assert "no outward-facing shell" in fallback and "inside out" in fallback
    assert "no triangles" not in fallback
