"""Root conftest: the docstring examples' print settings, a private table cache, the kernels compiled once.

The docstring examples collected by ``--doctest-modules`` print numpy scalars the way a reader
expects; the numba kernels are compiled once before the xdist workers start.

The suite never reads or writes the user's table cache (:mod:`simulate.fiber.tablecache`): the test
run (the xdist controller, or the only process of a run without workers) makes a fresh temporary
directory, removed at its exit; the xdist workers and the processes the tests start inherit it
through the environment, so a table one worker computed is loaded by the other. The cache is safe
for concurrent processes (an entry is written to a temporary file and moved into place). A test
that counts the cache's entries, hits or misses uses the ``cache_dir`` fixture: a directory of its own.

With two or more xdist workers, the controller first runs ``tests/warm_kernels.py``: one process
per group of kernels, the groups at once, each compiling its kernels into numba's on-disk cache (the
kernels both groups use compiled by one, the other waiting for them: the script's docstring);
the workers then load them instead of each compiling every kernel it meets. The kernels are numba's cache
of the user (:mod:`simulate.kernelcache`: keyed by their sources' content, so a run from another clone of the
same sources only loads them and the warm-up takes seconds). A test that judges numba's cache
(``tests/simulate/mc/test_kernel_cache.py``) gives its own processes a ``NUMBA_CACHE_DIR`` of its own,
filled with a copy of the kernels this warm-up compiled.
"""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from _pytest.doctest import DoctestItem

#: the test run's table cache, set by the process that made it (the xdist controller) for its workers
_RUN_CACHE_ENV = "FABRIC_OPTICS_TEST_RUN_CACHE"
_inherited = os.environ.get(_RUN_CACHE_ENV, "")
if os.environ.get("PYTEST_XDIST_WORKER") and _inherited and os.path.isdir(_inherited):
    _TABLE_CACHE = _inherited
else:
    _TABLE_CACHE = tempfile.mkdtemp(prefix="fabric-optics-test-cache-")
    os.environ[_RUN_CACHE_ENV] = _TABLE_CACHE
    atexit.register(shutil.rmtree, _TABLE_CACHE, True)
os.environ["FABRIC_OPTICS_CACHE_DIR"] = _TABLE_CACHE
os.environ.pop("FABRIC_OPTICS_NO_CACHE", None)

_WARM_KERNELS = Path(__file__).with_name("tests") / "warm_kernels.py"
_WARM_GROUPS = ("monte-carlo", "fabric")
_warm_report: list[str] = []

# The thread-independence tests compare 1 and 2 compiled threads: numba's pool must hold at least 2
# (set before numba is first imported; on a 1-core machine the two threads share the core).
if int(os.environ.get("NUMBA_NUM_THREADS") or os.cpu_count() or 1) < 2:
    os.environ["NUMBA_NUM_THREADS"] = "2"


def _xdist_workers(config: pytest.Config) -> int:
    """How many xdist workers this (controller) process starts: 0 in a worker or without xdist."""
    if hasattr(config, "workerinput") or getattr(config.option, "dist", "no") == "no":
        return 0
    return len(getattr(config.option, "tx", None) or [])


def pytest_configure(config: pytest.Config) -> None:
    """With 2 or more workers: compile the kernels once, one process per group (module docstring).

    A group that fails is reported in the summary and the run goes on (its kernels are then compiled
    by the tests that use them, which also show the failure).

    Parameters
    ----------
    config : pytest.Config
        The run's configuration: its xdist options say how many workers start, and a run that only
        collects compiles nothing.
    """
    if _xdist_workers(config) < 2 or config.option.collectonly:
        return
    start = time.perf_counter()
    # the file by which the monte-carlo group tells the fabric group that their shared kernels are compiled
    ready_dir = tempfile.mkdtemp(prefix="fabric-optics-warm-kernels-")
    ready = Path(ready_dir) / "shared-ready"
    env = dict(os.environ, FABRIC_OPTICS_NO_CACHE="1", WARM_KERNELS_SHARED_READY=str(ready))
    procs = [(group, subprocess.Popen([sys.executable, "-P", str(_WARM_KERNELS), group], env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
             for group in _WARM_GROUPS]
    lines = []
    for group, proc in procs:
        out, _ = proc.communicate()
        ready.touch()     # a group that ended (the monte-carlo group comes first) keeps no other group waiting
        lines.append(out.strip().splitlines()[-1] if proc.returncode == 0 and out.strip()
                     else f"{group} failed (exit {proc.returncode}): {out.strip().splitlines()[-1:] or ''}")
    shutil.rmtree(ready_dir, ignore_errors=True)
    _warm_report.append(f"numba kernels compiled before the workers start: {time.perf_counter() - start:.1f} s "
                        f"({'; '.join(lines)})")


def pytest_terminal_summary(terminalreporter) -> None:
    """Print the kernel warm-up's line (its time and each group's last line) in the run's summary.

    Parameters
    ----------
    terminalreporter : _pytest.terminal.TerminalReporter
        pytest's terminal reporter, which writes the line.
    """
    for line in _warm_report:
        terminalreporter.write_line(line)


@pytest.fixture(autouse=True)
def _doctest_numpy_scalars_print_as_python(request):
    """Print numpy scalars in the 1.25 style while a docstring example runs.

    Docstring examples show what a reader expects (``True``, ``0.5``): numpy 2 prints its scalars as
    ``np.True_`` / ``np.float64(0.5)``. Other tests run with numpy's print options unchanged.
    """
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
    """An empty table-cache directory of this test's own, the cache switched on (not created here).

    Parameters
    ----------
    tmp_path : pathlib.Path
        The test's temporary directory, which holds the cache directory.
    monkeypatch : pytest.MonkeyPatch
        Sets ``FABRIC_OPTICS_CACHE_DIR`` and removes ``FABRIC_OPTICS_NO_CACHE`` for this test only.

    Returns
    -------
    pathlib.Path
        ``tmp_path / "cache"``, which does not exist yet.
    """
    d = tmp_path / "cache"
    monkeypatch.setenv("FABRIC_OPTICS_CACHE_DIR", str(d))
    monkeypatch.delenv("FABRIC_OPTICS_NO_CACHE", raising=False)
    return d
