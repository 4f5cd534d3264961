"""Bounded fuzzing of the web upload checks (see harness.py for the shared property)."""

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from targets_web import TARGETS

pytest.importorskip("aiohttp")


#: Examples per target: the multipart one runs an event loop per input.
EXAMPLES = {"upload-name": 1500, "upload-folder": 1500, "upload-multipart": 3000}


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.name)
def test_fuzz_web(target):
    @settings(ci_settings(EXAMPLES[target.name]))
    @given(target.strategy)
    def run(value):
        check_one(target, value)

    run()
