"""Bounded fuzz run of the G-code lexer and policy (the long run is ``bench/fuzz.py``):
the lexer never raises; the policy accepts or refuses with a one-line UnsafeEntry."""

from __future__ import annotations

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from hypothesis import strategies as st
from targets_gcode import TARGETS

#: Examples per target; both together take well under half a minute on one core.
EXAMPLES = {"gcode-lexer": 1500, "gcode-policy": 600}


@pytest.mark.parametrize("target", TARGETS, ids=lambda target: target.name)
def test_gcode_accepted_or_refused_cleanly(target):
    @settings(ci_settings(EXAMPLES[target.name]))
    @given(st.data())
    def run(data):
        check_one(target, data.draw(target.strategy))

    run()
