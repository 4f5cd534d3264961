"""Bounded fuzzing of the web upload checks (see harness.py for the shared property)."""

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from targets_web import TARGETS

pytest.importorskip("aiohttp")


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.name)
def test_fuzz_web(target):
    @settings(ci_settings(1500))
    @given(target.strategy)
    def run(value):
        check_one(target, value)

    run()
