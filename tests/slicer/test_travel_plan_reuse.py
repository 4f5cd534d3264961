"""A router serves a run of identical layers and keeps the plans it found: the same travels
get the same plan, exactly what a fresh router finds."""

import numpy as np
from manifold3d import CrossSection

from slicer.travel import PLANS_KEPT, TravelRouter


def _c_shape() -> CrossSection:
    """A 40 mm square with a slot cut in from one side: travels across the slot must route."""
    return CrossSection.square([40, 40]) - CrossSection.square([30, 6]).translate([0, 17])


def _travels(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    prev = np.c_[rng.uniform(2, 28, 12), rng.uniform(2, 15, 12)]  # below the slot
    starts = np.c_[rng.uniform(2, 28, 12), rng.uniform(25, 38, 12)]  # above it
    return prev, starts, np.ones(12, dtype=bool)


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.leaves, b.leaves)
    np.testing.assert_array_equal(a.length, b.length)
    for wa, wb in zip(a.waypoints, b.waypoints, strict=True):
        assert (wa is None) == (wb is None)
        if wa is not None:
            np.testing.assert_array_equal(wa, wb)


def test_repeated_travels_get_the_plan_a_fresh_router_finds():
    router = TravelRouter(_c_shape(), 0.45)
    first = [router.plan(*_travels(s)) for s in range(3)]
    assert any(w is not None for w in first[0].waypoints)  # some travels are routed
    for s in range(3):
        again = router.plan(*_travels(s))
        assert again is first[s]  # kept, not searched again
        _same(again, TravelRouter(_c_shape(), 0.45).plan(*_travels(s)))
    prev, starts, moving = _travels(0)
    moving[3] = False  # other travels: another plan
    other = router.plan(prev, starts, moving)
    assert other is not first[0]
    _same(other, TravelRouter(_c_shape(), 0.45).plan(prev, starts, moving))


def test_kept_plans_are_bounded():
    router = TravelRouter(_c_shape(), 0.45)
    for s in range(3 * PLANS_KEPT):
        router.plan(*_travels(s))
        assert len(router._plans) <= PLANS_KEPT
