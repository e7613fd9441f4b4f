"""numba's first call in a process that imported the Monte Carlo package skips ``scipy.linalg``,
and BLAS still works afterwards (:mod:`simulate.montecarlo.numba_start`).

Each case runs in a fresh interpreter: what is tested is the state of ``sys.modules`` and of
numba's registries from the first import on.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]

_FIRST_CALL = """
import sys
import numba
import numpy as np
import simulate.montecarlo  # noqa: F401  (takes the shortcut)

@numba.njit
def add_one(x):
    return x + 1

assert add_one(1) == 2                       # numba's registries are loaded now
print("scipy.linalg imported:", "scipy.linalg" in sys.modules)
from numba.np import arraymath
assert arraymath._HAVE_BLAS is True          # numba's BLAS check passed

import scipy.linalg.cython_blas              # the normal import, afterwards
assert "dgemm" in scipy.linalg.cython_blas.__pyx_capi__

@numba.njit
def matvec(a, b):
    return np.dot(a, b)                      # numba calls BLAS through cython_blas

assert np.array_equal(matvec(np.array([[2.0, 0.0], [0.0, 3.0]]), np.array([1.0, 2.0])), [2.0, 6.0])
print("ok")
"""


def _run(code: str) -> str:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True,
                          text=True, timeout=900, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_first_numba_call_does_not_import_scipy_linalg_and_blas_still_works():
    out = _run(_FIRST_CALL)
    assert "scipy.linalg imported: False" in out
    assert out.strip().endswith("ok")


def test_scipy_linalg_imported_first_is_left_alone():
    out = _run("import scipy.linalg\n" + _FIRST_CALL)
    assert "scipy.linalg imported: True" in out
    assert out.strip().endswith("ok")
