"""Bounded fuzz run of the repair targets (see targets_repair.py and harness.py)."""

from __future__ import annotations

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from targets_repair import TARGETS

#: Examples per target in the default run (about 25 s on one core).
MAX_EXAMPLES = 300


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.name)
def test_repair_target_accepts_or_refuses_cleanly(target):
    @settings(ci_settings(MAX_EXAMPLES))
    @given(target.strategy)
    def run(value):
        check_one(target, value)

    run()
