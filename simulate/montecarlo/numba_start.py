"""Numba's first call without importing ``scipy.linalg``: a start-up shortcut.

The first time a process compiles or loads a cached numba function, numba imports its lowering
registries. One of them, ``numba.np.arraymath``, checks at import time that BLAS is there by
importing ``scipy.linalg.cython_blas`` (``numba.np.linalg.ensure_blas``). Importing that submodule
first runs ``scipy/linalg/__init__.py``, which pulls in most of ``scipy.linalg``, ``scipy._lib``
and ``numpy.f2py``: a noticeable share of a short run's start-up in every process that runs a
kernel, for a check whose only use is to let numba compile ``np.dot`` and the like
(docs/notes/implementation.md, "The photon kernel").

:func:`preload_blas_check` loads the ``cython_blas`` extension module from its own file (without the
package ``__init__``), imports ``numba.np.arraymath`` so that numba's check runs
against it, and removes the module from ``sys.modules`` again. A later
``import scipy.linalg.cython_blas`` therefore goes through the normal import machinery (it runs
``scipy.linalg``'s ``__init__`` and gets the same module object back: an extension module is
initialised once per process), and numba's BLAS calls look their functions up by module name as
usual. Nothing is done when ``scipy.linalg`` is already imported, when numba's registries are
already loaded, or when scipy is missing; if anything in the shortcut fails, numba imports
``scipy.linalg`` itself, as without the shortcut (``tests/simulate/mc/test_numba_start.py``).
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import os
import sys

__all__ = ["preload_blas_check"]

_BLAS = "scipy.linalg.cython_blas"


def preload_blas_check() -> bool:
    """Let numba check BLAS without importing ``scipy.linalg``; True if the shortcut was taken."""
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules or _BLAS in sys.modules:
        return False
    try:
        import scipy
    except ImportError:
        return False
    try:
        paths = [os.path.join(p, "linalg") for p in getattr(scipy, "__path__", [])]
        found = importlib.machinery.PathFinder.find_spec("cython_blas", paths)
        if found is None or not isinstance(found.loader, importlib.machinery.ExtensionFileLoader):
            return False
        spec = importlib.util.spec_from_file_location(_BLAS, found.origin)
        if spec is None or spec.loader is None:
            return False
        module = importlib.util.module_from_spec(spec)
        sys.modules[_BLAS] = module
        try:
            spec.loader.exec_module(module)
            importlib.import_module("numba.np.arraymath")
        finally:
            if sys.modules.get(_BLAS) is module:
                del sys.modules[_BLAS]
    except Exception:  # noqa: BLE001 -- any failure: numba does its own check later, as without this
        return False
    return True
