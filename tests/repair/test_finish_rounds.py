"""The finish's whole-arrangement rounds are bounded by what they do: a round that
would mend far more damage than the one before it, or one past
:data:`repair.finish.MAX_HULL_ROUNDS`, is not taken (issue 18: in bounded time)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from repair.check import check_printable
from repair.finish import (
    HULL_GROWTH,
    HULL_GROWTH_FLOOR,
    MAX_FINISH_ROUNDS,
    MAX_HULL_ROUNDS,
    _hull_round_refused,
    finish,
)
from repair.report import RepairTally

DATA = Path(__file__).resolve().parents[1] / "data"


def test_rounds_that_grow_the_damage_stop_with_the_reason() -> None:
    # The finish's input on CGAL's part x60 with needles and T-junctions (seed 1), saved
    # from main 6c1e829 (whose clean left the needles' neighbours unsplit): there each
    # whole-arrangement round re-created ~5.7x the crossings (1,120 -> 6,442 -> 36,835),
    # the third built 259k faces of stacked slabs and CGAL died of std::bad_alloc.
    d = np.load(DATA / "cgal_part_slabs.npz")
    v, f = d["vertices"].astype(np.float64), d["faces"].astype(np.int64)
    tally = RepairTally()
    out_v, out_f, verdict = finish(v, f, 0.4, tally)
    assert not verdict.ok
    assert "grew the damage" in tally.finish_stopped
    assert tally.passes < MAX_FINISH_ROUNDS
    # What it returns is this round's rounded mesh, and its verdict holds for it.
    again = check_printable(out_v, out_f)
    assert again.intersecting_pairs == verdict.intersecting_pairs
    assert len(out_f) < 2 * len(f)  # no arrangement of stacked slabs was taken


def test_the_rule_refuses_growth_and_too_many_rounds_only() -> None:
    assert _hull_round_refused([], 10**6) == ""  # the first round is always taken
    assert _hull_round_refused([1120], 6442) != ""
    grown = int(HULL_GROWTH * 1000) + 1
    assert "grew the damage 1000" in _hull_round_refused([1000], grown)
    assert _hull_round_refused([1000], grown - 1) == ""
    assert _hull_round_refused([2], HULL_GROWTH_FLOOR) == ""  # small damage: still taken
    assert _hull_round_refused([5] * (MAX_HULL_ROUNDS - 1), 5) == ""
    assert f"{MAX_HULL_ROUNDS} rounds" in _hull_round_refused([5] * MAX_HULL_ROUNDS, 1)
