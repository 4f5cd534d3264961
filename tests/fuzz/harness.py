"""One harness for every fuzz target: the property all of them share.

Every reader and parser faces bytes from strangers. For each input it must end in
one of two ways: success, or one of its *expected* errors with a human-readable,
one-line message. Never another exception (a traceback), never a hang.

A target module is ``tests/fuzz/targets_<area>.py`` with a module-level
``TARGETS: list[Target]``. The bounded pytest run (``tests/fuzz/test_fuzz_<area>.py``)
and the long coverage run (``bench/fuzz.py``) both take their targets from there,
so the same property is checked in CI and in the long run.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis.strategies import SearchStrategy

#: An input that takes longer than this (seconds) to accept or refuse is a hang.
HANG_SECONDS = 10.0
#: A refusal's message longer than this is not "one line a person reads".
MAX_MESSAGE = 500


@dataclass(frozen=True)
class Target:
    """One fuzzed entry point.

    name:     short id, e.g. ``"stl"`` or ``"gcode-policy"``.
    strategy: hypothesis strategy producing one input.
    run:      calls the product code on one input; returns anything, or raises.
    expected: the exception types that are a clean refusal of bad input.
    modules:  product modules the target exercises (the long run measures their coverage).
    """

    name: str
    strategy: SearchStrategy
    run: Callable[[Any], object]
    expected: tuple[type[BaseException], ...]
    modules: tuple[str, ...] = field(default=())


class Hang(AssertionError):
    """The input was neither accepted nor refused within HANG_SECONDS."""


def _on_alarm(signum, frame):  # noqa: ARG001 - signal handler signature
    raise Hang(f"no answer within {HANG_SECONDS:g} s")


def check_one(target: Target, value: Any, *, seconds: float = HANG_SECONDS) -> str:
    """Run ``target`` on ``value`` and check the shared property.

    Returns ``"ok"`` or ``"refused"``. Raises ``AssertionError`` (or ``Hang``)
    when the property is broken, and lets an unexpected exception through
    unchanged, so hypothesis shrinks and reports it with its traceback.
    Must be called from the main thread (it uses ``SIGALRM``).
    """
    previous = signal.signal(signal.SIGALRM, _on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        target.run(value)
    except Hang:
        raise
    except target.expected as exc:
        message = str(exc)
        assert message.strip(), f"{target.name}: {type(exc).__name__} with an empty message"
        assert "\n" not in message.strip(), (
            f"{target.name}: refusal is not one line: {message!r}")
        assert len(message) <= MAX_MESSAGE, (
            f"{target.name}: refusal is {len(message)} characters long")
        assert "Traceback" not in message, f"{target.name}: refusal carries a traceback"
        return "refused"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return "ok"


def ci_settings(max_examples: int = 150) -> settings:
    """Bounded settings for the default test run: no deadline flakiness, no database
    writes into the clone, and a fixed example budget so CI time stays flat."""
    return settings(
        max_examples=max_examples,
        deadline=None,
        database=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                               HealthCheck.filter_too_much],
    )
