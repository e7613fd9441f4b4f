"""The compiled kernels are cached once per machine: another clone loads them and writes nothing.

One process compiles every kernel variant the slab command and the fiber routes use into a
``NUMBA_CACHE_DIR`` of this test's own; a fresh process running :mod:`cache_probe` against it, from
a copy of the package's sources in another folder (a second clone: new paths, new modification
times), must load every kernel from it (numba's per-dispatcher ``cache_hits``), compile nothing (no
``cache_misses``) and leave the cache directory exactly as it was (same files, same contents). A
kernel whose cache key changed per process or per folder recompiled there and added files to the cache.

The compiling process is the suite's kernel warm-up (``tests/warm_kernels.py``, which runs the same
routes before the workers start, in this tree, into the user's kernel cache,
:func:`simulate.kernelcache.cache_base`): its compiled kernels for these numba, llvmlite and Python
versions are copied into this test's directory. Without the warm-up (a run without workers) or when
the copy misses a kernel, a first :mod:`cache_probe` process in this tree compiles what is missing
and the second, in the copy, is the one judged.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from simulate import kernelcache

PROBE = Path(__file__).with_name("cache_probe.py")
REPO = Path(__file__).resolve().parents[3]
#: the kernel variants the routes run (drivers: loading one loads the batch kernel inside it)
KERNELS = ("simulate.montecarlo.kernel.run_batches", "simulate.montecarlo.kernel.run_batches_plain",
           "simulate.montecarlo.kernel.run_rows")


def _probe(cache: Path, tree: Path = REPO) -> dict[str, dict[str, int]]:
    """numba's statistics of a :mod:`cache_probe` process importing the packages from ``tree``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join(
        [str(tree)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    done = subprocess.run([sys.executable, str(PROBE)], env=env, capture_output=True, text=True, timeout=900,
                          check=False)
    assert done.returncode == 0, done.stderr
    stats = json.loads(done.stdout.strip().splitlines()[-1])
    assert Path(stats.pop("simulate")).resolve().is_relative_to(tree.resolve()), "the probe imported another tree"
    return stats


def _files(cache: Path) -> dict[str, str]:
    return {str(p.relative_to(cache)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(cache.rglob("*")) if p.is_file()}


def _copy_compiled_tree(cache: Path) -> int:
    """Copy the user's compiled kernels for these numba, llvmlite and Python versions into ``cache``, laid out as
    there; data files before indexes, so that an index never names a data file not yet there. Returns the
    number of files copied."""
    tag = kernelcache.version_tag()
    source = kernelcache.cache_base() / tag
    copied = 0
    for suffix in (".nbc", ".nbi"):
        for f in sorted(source.glob(f"**/*{suffix}")):
            dest = cache / tag / f.parent.relative_to(source)
            dest.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dest / f.name)
            copied += 1
    return copied


def _second_clone(dest: Path) -> Path:
    """The packages' sources copied to ``dest`` with new modification times (no compiled files)."""
    for top in ("simulate", "fabric_optics", "gonio", "compare"):
        shutil.copytree(REPO / top, dest / top, copy_function=shutil.copy,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return dest


@pytest.fixture(scope="module")
def compiled_then_loaded(tmp_path_factory):
    """``(compiled_by, cache files after compiling, the loading process's statistics, cache files after it)``;
    ``compiled_by`` is ``"warm-up"`` or the first probe's statistics (module docstring)."""
    cache = tmp_path_factory.mktemp("numba-cache")
    clone = _second_clone(tmp_path_factory.mktemp("second-clone"))
    compiled_by: object = "warm-up"
    loader = _probe(cache, clone) if _copy_compiled_tree(cache) else None
    if loader is None or any(s["misses"] for s in loader.values()):
        compiled_by = _probe(cache)
        after_compile = _files(cache)
        loader = _probe(cache, clone)
    else:
        # the copy was complete: the warm-up's files, loaded as they are (the probe wrote nothing: tested below)
        after_compile = _files(cache)
    return compiled_by, after_compile, loader, _files(cache)


def test_one_process_compiles_every_kernel_into_the_cache(compiled_then_loaded):
    compiled_by, after_compile, _, _ = compiled_then_loaded
    for name in KERNELS:
        if compiled_by != "warm-up":       # a probe filled the cache: it met every kernel
            assert name in compiled_by, (name, sorted(compiled_by))
        module, attr = name.rsplit(".", 1)
        # numba names a kernel's cache files after its function's qualified name
        qualname = getattr(importlib.import_module(module), attr).py_func.__qualname__.replace("<locals>", "locals")
        assert any(f.endswith(".nbc") and f".{qualname}-" in f for f in after_compile), (name, sorted(after_compile))


def test_another_process_loads_every_kernel_and_compiles_nothing(compiled_then_loaded):
    _, _, loader, _ = compiled_then_loaded
    for name in KERNELS:
        assert loader[name]["hits"] >= 1, (name, loader.get(name))
    compiled = {name: s for name, s in loader.items() if s["misses"]}
    assert not compiled, compiled


def test_the_loading_process_leaves_the_cache_directory_unchanged(compiled_then_loaded):
    _, after_compile, _, after_loading = compiled_then_loaded
    assert sorted(set(after_loading) - set(after_compile)) == []
    changed = [f for f in after_compile if after_loading.get(f) != after_compile[f]]
    assert changed == []
