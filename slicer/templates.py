"""Start/end G-code templates: ``{name}`` placeholders filled from profile values (no numpy)."""

from __future__ import annotations


def render_template(template: str, values: dict) -> str:
    """Fill ``{name}`` placeholders from ``values``; unknown names raise ValueError."""
    try:
        text = template.format_map(values)
    except (KeyError, IndexError, ValueError) as exc:
        raise ValueError(f"G-code template has an unknown or bad placeholder: {exc}") from None
    return text if text.endswith("\n") or not text else text + "\n"
