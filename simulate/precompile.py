"""The compiled kernels of a fabric run, compiled ahead of it into the kernel cache (``simulate compile``).

A run's first use of a numba kernel compiles it (:mod:`simulate.kernelcache` keeps it for every later
run). The felt Monte Carlo compiles its ray tracer's shading after it has built its exit tables and
felts, so its process holds LLVM's compilation memory on top of them: a first ``simulate fabric
green-felt-mc --method mc`` peaks higher than the same run with its kernels cached (``make demo``'s peak).
:func:`compile_kernels` compiles them in a run of its own that holds next to nothing: the config's
model at one geometry, three of the wavelengths, a few photons, one thread, the table cache off (it
writes nothing but the kernel cache). A kernel already cached is only loaded.

The tiny run must give numba the argument types the real run will: a kernel is compiled once per
signature, which includes the layout of every array. The three wavelengths are the run's first,
middle and last: an exit table's rows are written one group of alike wavelengths at a time into
slices of the table, and a slice of some of the wavelengths has another layout than the whole table,
which one wavelength alone would give.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["COMPILE_METHODS", "Compiled", "compile_kernels", "probe_wavelengths"]

#: The methods whose kernels :func:`compile_kernels` compiles: the fabric models, and ``auto`` (all of them).
COMPILE_METHODS = ("classic", "summation", "mc", "auto")

#: The tiny run's accuracy and budget: the fewest photons the tables and the tracer take.
_TARGET = 0.5
_MAX_PHOTONS = 64


@dataclass(frozen=True)
class Compiled:
    """What :func:`compile_kernels` did.

    Attributes
    ----------
    kernels : tuple of str
        The cached kernels it compiled (``module.function``, once per signature), in order; empty
        when the cache held them all.
    cache : pathlib.Path
        The kernel cache's folder (:func:`simulate.kernelcache.cache_base`).
    seconds : float
        Wall time.
    """

    kernels: tuple[str, ...]
    cache: Path
    seconds: float


def probe_wavelengths(wavelengths_nm: Sequence[float] | np.ndarray) -> np.ndarray:
    """The wavelengths of the tiny run: the first, middle and last of ``wavelengths_nm`` (fewer if fewer).

    Parameters
    ----------
    wavelengths_nm : sequence of float
        The real run's wavelengths, in order.

    Returns
    -------
    numpy.ndarray
        At most three of them, in their order.

    Examples
    --------
    >>> probe_wavelengths([400, 450, 500, 550, 600]).tolist()
    [400.0, 500.0, 600.0]
    >>> probe_wavelengths([550]).tolist()
    [550.0]
    """
    wl = np.asarray(wavelengths_nm, float).reshape(-1)
    if wl.size == 0:
        raise ValueError("probe_wavelengths: no wavelength")
    return wl[sorted({0, wl.size // 2, wl.size - 1})]


@contextlib.contextmanager
def _quiet_without_tables() -> Iterator[None]:
    """The table cache off and the tiny run's warnings (its few photons reach few directions) not shown."""
    from simulate.fiber import tablecache

    previous_env = os.environ.get(tablecache.ENV_DISABLE)
    previous_disable = logging.root.manager.disable
    os.environ[tablecache.ENV_DISABLE] = "1"
    logging.disable(logging.WARNING)
    try:
        yield
    finally:
        logging.disable(previous_disable)
        if previous_env is None:
            os.environ.pop(tablecache.ENV_DISABLE, None)
        else:
            os.environ[tablecache.ENV_DISABLE] = previous_env


def compile_kernels(config: Any, method: str, wavelengths_nm: Sequence[float] | np.ndarray) -> Compiled:
    """Compile into the kernel cache the kernels a run of ``config`` by ``method`` needs, by a tiny run.

    Parameters
    ----------
    config : SimulationConfig
        The fabric (:func:`simulate.config.load_config`).
    method : str
        One of :data:`COMPILE_METHODS`; ``auto`` compiles the kernels of every fabric model.
    wavelengths_nm : sequence of float
        The real run's wavelengths (a plan's); the tiny run takes three (:func:`probe_wavelengths`).

    Returns
    -------
    Compiled
        The kernels compiled (none when they were all cached), the cache's folder and the time.

    Raises
    ------
    ValueError
        An unknown method or no wavelength.
    """
    from numba.core import event

    from simulate import kernelcache
    from simulate.products import MODELS, Geometries, RunSettings, evaluate

    if method not in COMPILE_METHODS:
        raise ValueError(f"method must be one of {', '.join(COMPILE_METHODS)}, got {method!r}")
    started = time.perf_counter()
    wl = probe_wavelengths(wavelengths_nm)
    one = Geometries(np.array([0.0]), np.array([0.0]), np.array([30.0]), np.array([0.0]))
    settings = RunSettings(target=_TARGET, seed=int(config.seed), threads=1, max_photons=_MAX_PHOTONS)
    compiled: list[str] = []
    with _quiet_without_tables(), event.install_recorder("numba:compile") as recorder:
        fiber = config.fiber(wl)
        for model in (MODELS if method == "auto" else (method,)):
            evaluate(model, config, fiber, one, wl, settings)
    for _, ev in recorder.buffer:
        dispatcher = ev.data["dispatcher"]
        if ev.is_start and kernelcache.compile_lock_path(dispatcher) is not None:
            compiled.append(f"{dispatcher.py_func.__module__}.{dispatcher.py_func.__qualname__}")
    return Compiled(tuple(compiled), kernelcache.cache_base(), time.perf_counter() - started)
