"""miepython through :func:`simulate.optics.mie._miepython`: its eagerly compiled kernel is cached.

miepython compiles ``_cn_dn_nb`` at import without ``cache=True`` (1.5-2 s in every
process). Two fresh processes import it through the wrapper against one empty ``NUMBA_CACHE_DIR``:
the first compiles it into the cache, the second loads it (numba's dispatcher statistics) and
compiles nothing; ``numba.njit`` is the original again after the import; the Mie numbers are
the published ones.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
PROBE = r"""
import json, numba
real = numba.njit
from simulate.optics import mie
mp = mie._miepython()
from miepython import mie_jit
stats = mie_jit._cn_dn_nb.stats
print(json.dumps({"hits": sum(stats.cache_hits.values()), "misses": sum(stats.cache_misses.values()),
                  "restored": numba.njit is real, "again": mie._miepython() is mp}))
"""


def _probe(cache: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), MIEPYTHON_USE_JIT="1", PYTHONPATH=os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=900,
                          check=False)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_eager_miepython_kernel_is_compiled_once_then_loaded(tmp_path):
    first = _probe(tmp_path)
    second = _probe(tmp_path)
    assert first["misses"] == 1 and first["hits"] == 0
    assert second["hits"] == 1 and second["misses"] == 0
    assert first["restored"] and second["restored"] and second["again"]
    assert any(p.name.startswith("mie_jit._cn_dn_nb") for p in tmp_path.rglob("*.nbi"))


def test_efficiencies_through_the_wrapper_match_bohren_huffman():
    """Bohren & Huffman (1983) App. A: m = 1.55, x = 5.21282 (the numbers do not depend on the import path)."""
    from simulate.optics import mie

    e = mie.efficiencies(1.55, 5.21282)
    assert abs(float(e.qsca) - 3.10542) < 1e-5
    assert abs(float(e.qback) - 2.92534) < 1e-5
    assert abs(float(e.g) - 0.63314) < 1e-5
