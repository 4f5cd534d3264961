"""Bounded fuzz run of the closure, stitch and scan targets (targets_closure.py, harness.py)."""

from __future__ import annotations

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from targets_closure import TARGETS

#: Examples per target in the default run (a few seconds each).
MAX_EXAMPLES = 150


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.name)
def test_closure_target_keeps_its_invariants(target):
    @settings(ci_settings(MAX_EXAMPLES))
    @given(target.strategy)
    def run(value):
        check_one(target, value)

    run()
