"""Root conftest: the docstring examples' print settings, a private table cache, the kernels compiled beside the tests.

The docstring examples collected by ``--doctest-modules`` print numpy scalars the way a reader
expects; with xdist workers, the numba kernels are compiled while the first tests run.

The suite never reads or writes the user's table cache (:mod:`simulate.fiber.tablecache`): the test
run (the xdist controller, or the only process of a run without workers) makes a fresh temporary
directory, removed at its exit; the xdist workers and the processes the tests start inherit it
through the environment, so a table one worker computed is loaded by the other. The cache is safe
for concurrent processes (an entry is written to a temporary file and moved into place). A test
that counts the cache's entries, hits or misses uses the ``cache_dir`` fixture: a directory of its own.

With two or more xdist workers, the controller starts ``tests/warm_kernels.py`` beside them: one
process per group of kernels, each compiling its kernels into numba's on-disk cache while the workers run
the first files, which need none (``testpaths``: the instrument, the comparison and the command lines come
first). A kernel is compiled once: :mod:`simulate.kernelcache` locks each kernel's compilation, so a worker
that meets a kernel being compiled waits for it and loads it. The kernels are numba's cache of the user
(:mod:`simulate.kernelcache`: keyed by their sources' content, so a run from another clone of the same
sources only loads them and the warm-up takes seconds). A test that judges numba's cache
(``tests/simulate/mc/test_kernel_cache.py``) gives its own processes a ``NUMBA_CACHE_DIR`` of its own,
filled with a copy of the kernels compiled so far.
"""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import sys
import tempfile
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
#: the warm-up's processes (group, process), started by the controller
_warm_procs: list[tuple[str, subprocess.Popen]] = []

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
    """With 2 or more workers: start compiling the kernels, one process per group, beside the workers.

    The processes are collected at the end of the run; a group that failed is reported in the summary
    (its kernels are then compiled by the tests that use them, which also show the failure).

    Parameters
    ----------
    config : pytest.Config
        The run's configuration: its xdist options say how many workers start, and a run that only
        collects compiles nothing.
    """
    if _xdist_workers(config) < 2 or config.option.collectonly:
        return
    env = dict(os.environ, FABRIC_OPTICS_NO_CACHE="1")
    for group in _WARM_GROUPS:
        proc = subprocess.Popen([sys.executable, "-P", str(_WARM_KERNELS), group], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        _warm_procs.append((group, proc))
    atexit.register(_stop_warm_up)


#: the files that need no compiled kernel, run first (module docstring): the instrument, its command line
#: and the comparison, whose tests mostly wait on the mock's serial and Modbus replies or draw figures
_NO_KERNEL_FIRST = ("tests/gonio/", "tests/cli/", "gonio/", "compare/", "tests/compare/")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Run the files that need no kernel first, the rest in their collected order (a stable sort).

    Parameters
    ----------
    config : pytest.Config
        The run's configuration (its root, against which the items' paths are read).
    items : list of pytest.Item
        The collected tests, sorted in place.
    """
    root = config.rootpath

    def later(item: pytest.Item) -> bool:
        """Whether ``item`` runs after the files of :data:`_NO_KERNEL_FIRST`."""
        path = item.path.relative_to(root).as_posix() if item.path.is_relative_to(root) else ""
        return not path.startswith(_NO_KERNEL_FIRST)

    items.sort(key=later)


def _stop_warm_up() -> None:
    """Stop the warm-up processes still running when the run ends early (an interrupted run)."""
    for _, proc in _warm_procs:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def pytest_terminal_summary(terminalreporter) -> None:
    """The warm-up's line: each group's seconds, or how it failed.

    Parameters
    ----------
    terminalreporter : _pytest.terminal.TerminalReporter
        pytest's terminal reporter, which writes the line (none without a warm-up).
    """
    lines = []
    for group, proc in _warm_procs:
        out, _ = proc.communicate()
        lines.append(out.strip().splitlines()[-1] if proc.returncode == 0 and out.strip()
                     else f"{group} failed (exit {proc.returncode}): {out.strip().splitlines()[-1:] or ''}")
    if lines:
        terminalreporter.write_line(f"numba kernels compiled beside the first tests ({'; '.join(lines)})")


@pytest.fixture(autouse=True)
def _table_cache_switch_reset():
    """Leave the table cache switched on after every test.

    ``--no-cache`` switches the cache off for the whole process (``os.environ``, inherited by the processes a
    sweep starts), so a test that runs a command with it in-process would otherwise switch it off for every
    later test of its worker, and a test that asserts what the cache holds would fail or pass by the order
    the workers drew.
    """
    yield
    os.environ.pop("FABRIC_OPTICS_NO_CACHE", None)


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
