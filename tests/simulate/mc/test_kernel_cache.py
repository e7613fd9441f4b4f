"""The compiled kernels are cached once per machine: a second process loads them and writes nothing.

Two fresh processes run :mod:`cache_probe` (the slab command and the fiber routes: every
kernel variant they use) against the same empty ``NUMBA_CACHE_DIR``. The first compiles and
fills the cache; the second must load every kernel from it (numba's per-dispatcher
``cache_hits``), compile nothing (no ``cache_misses``) and leave the cache directory exactly as
it was (same files, same contents). A kernel whose cache key changed per process
recompiled in every process and added a data file to the cache each time.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = Path(__file__).with_name("cache_probe.py")
REPO = Path(__file__).resolve().parents[3]
#: the kernel variants the routes run (drivers: loading one loads the batch kernel inside it)
KERNELS = ("simulate.montecarlo.kernel.run_batches", "simulate.montecarlo.kernel.run_batches_plain",
           "simulate.montecarlo.kernel.run_rows")


def _probe(cache: Path) -> dict[str, dict[str, int]]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    done = subprocess.run([sys.executable, str(PROBE)], env=env, capture_output=True, text=True, timeout=900,
                          check=False)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def _files(cache: Path) -> dict[str, str]:
    return {str(p.relative_to(cache)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(cache.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def two_processes(tmp_path_factory):
    cache = tmp_path_factory.mktemp("numba-cache")
    first = _probe(cache)
    after_first = _files(cache)
    second = _probe(cache)
    return first, after_first, second, _files(cache)


def test_first_process_compiles_into_the_cache(two_processes):
    first, after_first, _, _ = two_processes
    for name in KERNELS:
        assert first[name]["misses"] >= 1, (name, first.get(name))
    kernel_files = [f for f in after_first if "kernel" in f and f.endswith(".nbc")]
    assert kernel_files, sorted(after_first)


def test_second_process_loads_every_kernel_and_compiles_nothing(two_processes):
    _, _, second, _ = two_processes
    for name in KERNELS:
        assert second[name]["hits"] >= 1, (name, second.get(name))
    compiled = {name: s for name, s in second.items() if s["misses"]}
    assert not compiled, compiled


def test_second_process_leaves_the_cache_directory_unchanged(two_processes):
    _, after_first, _, after_second = two_processes
    assert sorted(set(after_second) - set(after_first)) == []
    changed = [f for f in after_first if after_second.get(f) != after_first[f]]
    assert changed == []
