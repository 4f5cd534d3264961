"""Errors raised by the slicer (one human-readable line each)."""

from __future__ import annotations


class SliceError(ValueError):
    """The model cannot be sliced with this profile (too big, not closed, empty, ...)."""
