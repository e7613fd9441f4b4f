"""The fit's error and warning types (their own module so that every part of the fit can raise them)."""

from __future__ import annotations

__all__ = ["FitError", "FitWarning"]


class FitError(ValueError):
    """A fit that cannot start (bad parameter, bounds, measurement): one line, exit 2."""


class FitWarning(UserWarning):
    """A fit that finished with its outputs written but should not be trusted as it stands: its colour left off
    the measured one, or a search that never moved from its start (:attr:`FitResult.warnings` say why)."""
