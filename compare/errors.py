"""The user-facing error of the comparison.

A :class:`CompareError` means that the inputs cannot be compared as asked (no normal-incidence
points on both sides of the normal, a zero or negative normal value, wavelength grids with too
little in common, no shared geometry). Its message is one sentence for a person: it names the
dataset (its directory) and what is missing, and what to do. The command line prints it and exits
with status 2; programming errors stay tracebacks.
"""

from __future__ import annotations

__all__ = ["CompareError"]


class CompareError(ValueError):
    """The datasets cannot be compared as requested; ``str()`` says which dataset and why."""
