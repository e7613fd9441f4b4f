"""The fit's error and warning types (their own module so that every part of the fit can raise them)."""

from __future__ import annotations

__all__ = ["FitError", "FitWarning"]


class FitError(ValueError):
    """A fit that cannot start (bad parameter, bounds, measurement): one line, exit 2."""


class FitWarning(UserWarning):
    """A fit that finished with its outputs written but should not be trusted as it stands.

    Its colour is off the measured one, or its search never moved from its start
    (:attr:`FitResult.warnings` say why). A warning, not an error, so the outputs are kept for a look.
    """
