"""Root conftest: settings of the docstring examples collected by ``--doctest-modules``; a private table cache.

The suite never reads or writes the user's table cache (:mod:`simulate.fiber.tablecache`): every
test process (and the processes it starts, which inherit the environment) uses a fresh temporary
directory, removed at exit.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import numpy as np
import pytest
from _pytest.doctest import DoctestItem

_TABLE_CACHE = tempfile.mkdtemp(prefix="fabric-optics-test-cache-")
os.environ["FABRIC_OPTICS_CACHE_DIR"] = _TABLE_CACHE
os.environ.pop("FABRIC_OPTICS_NO_CACHE", None)
atexit.register(shutil.rmtree, _TABLE_CACHE, True)

# The thread-independence tests compare 1 and 2 compiled threads: numba's pool must hold at least 2
# (set before numba is first imported; on a 1-core machine the two threads share the core).
if int(os.environ.get("NUMBA_NUM_THREADS") or os.cpu_count() or 1) < 2:
    os.environ["NUMBA_NUM_THREADS"] = "2"


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


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    """An empty table-cache directory of this test's own, the cache switched on (not created here)."""
    d = tmp_path / "cache"
    monkeypatch.setenv("FABRIC_OPTICS_CACHE_DIR", str(d))
    monkeypatch.delenv("FABRIC_OPTICS_NO_CACHE", raising=False)
    return d
