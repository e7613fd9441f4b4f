"""The kernel module makes numba's OpenMP threads wait passively unless the user chose otherwise.

libgomp spin-waits at the end of every parallel region by default; on a loaded machine that cost
~5 ms of CPU per kernel call (simulate.montecarlo.kernel, comment at OMP_WAIT_POLICY). A fresh
interpreter is needed: the variable must be set before numba starts its threads.
"""

from __future__ import annotations

import os
import subprocess
import sys

_PROBE = "import os, simulate.montecarlo.kernel; print(os.environ.get('OMP_WAIT_POLICY'))"


def _probe(**env: str) -> str:
    base = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", _PROBE], env={**base, **env}, capture_output=True, text=True,
                         check=True, timeout=900)
    return out.stdout.strip()


def test_passive_by_default_and_the_users_choice_kept():
    assert _probe() == "passive"
    assert _probe(OMP_WAIT_POLICY="active") == "active"
