"""The one error the repair raises for an input it cannot make printable."""

from __future__ import annotations

__all__ = ["RepairError"]


class RepairError(ValueError):
    """The input cannot be made printable; the message is one human-readable line."""
