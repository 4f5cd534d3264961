"""Bounded fuzz run of the daemon's config loader (see targets_config.py)."""

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from targets_config import TARGETS


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.name)
def test_config_loader_accepts_or_refuses_in_one_line(target):
    @settings(ci_settings(300))
    @given(target.strategy)
    def run(value):
        check_one(target, value)

    run()
