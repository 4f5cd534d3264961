"""Strategies for line-oriented text: real lines, lightly mutated, or with huge numbers."""

from __future__ import annotations

import re
from collections.abc import Sequence

from hypothesis import strategies as st


@st.composite
def mutated(draw, real: Sequence[str], alphabet: str) -> str:
    """One of the ``real`` lines with a few characters inserted, deleted or replaced
    (drawn from ``alphabet`` or any character)."""
    line = list(draw(st.sampled_from(real)))
    for _ in range(draw(st.integers(1, 4))):
        where = draw(st.integers(0, len(line)))
        char = draw(st.sampled_from(alphabet) | st.characters())
        action = draw(st.sampled_from(("insert", "delete", "replace")))
        if action == "insert" or not line:
            line.insert(where, char)
        elif action == "delete":
            del line[min(where, len(line) - 1)]
        else:
            line[min(where, len(line) - 1)] = char
    return "".join(line)


def with_long_numbers(real: Sequence[str]) -> st.SearchStrategy:
    """A real line whose every number is thousands of digits long (past Python's
    4300-digit limit for int())."""
    return st.builds(lambda line, digits: re.sub(r"\d+", "9" * digits, line),
                     st.sampled_from(real), st.integers(4200, 6000))
