"""Bounded fuzz run of every mesh reader (the long run is ``bench/fuzz.py``): each input
ends in a Mesh or a one-line MeshReadError, never another exception or a hang."""

from __future__ import annotations

import pytest
from harness import check_one, ci_settings
from hypothesis import given, settings
from hypothesis import strategies as st
from targets_mesh import TARGETS

#: Examples per target; the six targets together take about half a minute on one core.
EXAMPLES = {"mesh-3mf": 300, "mesh-random-bytes": 600}
DEFAULT_EXAMPLES = 300


@pytest.mark.parametrize("target", TARGETS, ids=lambda target: target.name)
def test_mesh_reader_accepts_or_refuses_cleanly(target):
    @settings(ci_settings(EXAMPLES.get(target.name, DEFAULT_EXAMPLES)))
    @given(st.data())
    def run(data):
        check_one(target, data.draw(target.strategy))

    run()
