"""Bounded fuzz run of the printer-reply parsers (the long run is ``bench/fuzz.py``):
every parser returns a value for any line, never an exception or a hang."""

from __future__ import annotations

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from hypothesis import strategies as st
from targets_replies import TARGETS

#: Examples per target: about ten seconds on one core.
EXAMPLES = {"replies": 1500}


@pytest.mark.parametrize("target", TARGETS, ids=lambda target: target.name)
def test_replies_always_parse(target):
    @settings(ci_settings(EXAMPLES[target.name]))
    @given(st.data())
    def run(data):
        check_one(target, data.draw(target.strategy))

    run()
