"""The fit's error type (its own module so that every part of the fit can raise it)."""

from __future__ import annotations

__all__ = ["FitError"]


class FitError(ValueError):
    """A fit that cannot start (bad parameter, bounds, measurement): one line, exit 2."""
