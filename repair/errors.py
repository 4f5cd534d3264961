"""The error the repair raises for an input it cannot make printable, and the kind
that says a stage ran out of its memory budget."""

from __future__ import annotations

__all__ = ["BudgetExceeded", "RepairError"]


class RepairError(ValueError):
    """The input cannot be made printable; the message is one human-readable line."""


class BudgetExceeded(RepairError):
    """A stage of the exact repair would need more memory than it is allowed (its
    exact test would hold too many candidate face pairs): the repair takes its
    fallback path instead, or refuses the input with this reason."""
