"""Root conftest: settings of the docstring examples collected by ``--doctest-modules``."""

from __future__ import annotations

import numpy as np
import pytest
from _pytest.doctest import DoctestItem


@pytest.fixture(autouse=True)
def _doctest_numpy_scalars_print_as_python(request):
    """Docstring examples show what a reader expects (``True``, ``0.5``): numpy 2 prints its
    scalars as ``np.True_`` / ``np.float64(0.5)``; the 1.25 style is used while they run."""
    if not isinstance(request.node, DoctestItem):
        yield
        return
    previous = np.get_printoptions()
    np.set_printoptions(legacy="1.25")
    try:
        yield
    finally:
        np.set_printoptions(**previous)
