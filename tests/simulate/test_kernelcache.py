"""The content-hash cache of the compiled kernels (:mod:`simulate.kernelcache`).

A tiny package of two cached kernels (``caller`` calls ``callee``, in another module) is compiled in
one folder ("a clone") against a ``NUMBA_CACHE_DIR`` of the test's own, then run from fresh copies
of it in other folders (new paths, new modification times): numba's dispatcher statistics count
what each process compiled (``cache_misses``) and loaded (``cache_hits``). Numba's own locators key
a cache on the module's absolute folder, and its stamp on the module's own file only: a copy would
compile everything again, and a changed callee would leave the caller's stale machine code in use
(the value it returns tells). The real package's keys are checked on a copy of its sources.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from simulate import kernelcache

REPO = Path(__file__).resolve().parents[2]

CALLEE = "import numba\n\n\n@numba.njit(cache=True)\ndef value():\n    return {value}\n"
CALLER = ("import numba\n\nfrom kcpkg.callee import value\n\n\n@numba.njit(cache=True)\ndef total(x):\n"
          "    return x + value()\n")
PROBE = """
import json, sys
from simulate import kernelcache
kernelcache.PACKAGE_GROUPS.append(("kcpkg",))
import kcpkg.caller as caller
result = caller.total(1)
stats = caller.total.stats
print(json.dumps({"result": result, "hits": sum(stats.cache_hits.values()),
                  "misses": sum(stats.cache_misses.values()), "file": caller.__file__}))
"""


def _write_package(folder: Path, value: int) -> Path:
    pkg = folder / "kcpkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "callee.py").write_text(CALLEE.format(value=value))
    (pkg / "caller.py").write_text(CALLER)
    (pkg / "other.py").write_text("LIMIT = 1\n")
    return folder


def _copy(src: Path, dest: Path) -> Path:
    """A second clone: the same files at another path, with new modification times (shutil.copy keeps none)."""
    shutil.copytree(src, dest, copy_function=shutil.copy)
    return dest


def _run(clone: Path, cache: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join(
        [str(clone), str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert Path(out["file"]).resolve().is_relative_to(clone.resolve()), out
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The tiny package compiled in a first clone, then run from a copy, a copy with its callee changed,
    a copy with an unrelated module changed, and the unchanged copy again (in that order)."""
    root = tmp_path_factory.mktemp("clones")
    cache = root / "numba-cache"
    first = _write_package(root / "first", value=1)
    second = _copy(first, root / "second")
    changed = _copy(first, root / "changed")
    (changed / "kcpkg" / "callee.py").write_text(CALLEE.format(value=5))
    unrelated = _copy(first, root / "unrelated")
    (unrelated / "kcpkg" / "other.py").write_text("LIMIT = 2\n")
    out = {"first": _run(first, cache)}
    out["second"] = _run(second, cache)
    out["changed"] = _run(changed, cache)
    out["unrelated"] = _run(unrelated, cache)
    out["second again"] = _run(second, cache)
    out["cache"] = cache
    return out


def test_the_first_clone_compiles(runs):
    assert runs["first"]["misses"] == 1 and runs["first"]["hits"] == 0
    assert runs["first"]["result"] == 2


def test_a_second_clone_compiles_nothing(runs):
    assert runs["second"]["misses"] == 0 and runs["second"]["hits"] == 1
    assert runs["second"]["result"] == 2


def test_a_changed_callee_recompiles_its_caller(runs):
    assert runs["changed"]["misses"] == 1 and runs["changed"]["hits"] == 0
    assert runs["changed"]["result"] == 6          # 1 + 5: not the stale 1 + 1


def test_a_module_the_kernel_does_not_import_changes_nothing(runs):
    assert runs["unrelated"]["misses"] == 0 and runs["unrelated"]["hits"] == 1


def test_both_sources_keep_their_kernels(runs):
    """The changed clone compiled beside the first one's kernels, not over them."""
    assert runs["second again"]["misses"] == 0 and runs["second again"]["result"] == 2
    folders = sorted(p.name for p in runs["cache"].glob(f"{kernelcache.version_tag()}/kcpkg/caller-*"))
    assert len(folders) == 2, folders


def test_the_cache_is_under_numba_cache_dir_or_the_user_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert kernelcache.cache_base() == tmp_path / "numba"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert kernelcache.cache_base() == tmp_path / "xdg" / "fabric-optics" / "numba"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert kernelcache.cache_base() == tmp_path / "home" / ".cache" / "fabric-optics" / "numba"


def test_the_version_tag_names_numba_llvmlite_and_python():
    import llvmlite
    import numba

    tag = kernelcache.version_tag()
    assert f"numba-{numba.__version__}-" in tag and f"llvmlite-{llvmlite.__version__}-" in tag
    assert sys.implementation.cache_tag in tag


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory):
    """A copy of the package's sources at another path with new modification times."""
    dest = tmp_path_factory.mktemp("tree")
    for top in ("simulate", "fabric_optics", "gonio", "compare"):
        shutil.copytree(REPO / top, dest / top, copy_function=shutil.copy,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def test_the_real_kernels_keys_do_not_depend_on_the_folder(tree_copy):
    for module in ("simulate/montecarlo/kernel.py", "simulate/raytrace/shading.py", "simulate/fiber/farfield.py"):
        assert kernelcache.source_key(tree_copy / module) == kernelcache.source_key(REPO / module), module


def test_the_real_kernels_keys_follow_their_imports(tree_copy):
    """kernel.py inlines rng.py's generator: editing rng.py changes kernel.py's key; the woven scene, which
    kernel.py does not import, does not."""
    kernel = tree_copy / "simulate/montecarlo/kernel.py"
    before = kernelcache.source_key(kernel)
    scene = tree_copy / "simulate/raytrace/scene.py"
    scene.write_text(scene.read_text() + "\n# edited\n")
    kernelcache._source_key.cache_clear()
    assert kernelcache.source_key(kernel) == before
    rng = tree_copy / "simulate/montecarlo/rng.py"
    rng.write_text(rng.read_text() + "\n# edited\n")
    kernelcache._source_key.cache_clear()
    assert kernelcache.source_key(kernel) != before
    assert kernelcache.source_key(REPO / "simulate/montecarlo/kernel.py") == before


LOCK_PATH = """
from simulate import kernelcache
kernelcache.PACKAGE_GROUPS.append(("kcpkg",))
import kcpkg.caller as caller
print(kernelcache.compile_lock_path(caller.total))
"""


def test_two_processes_needing_one_kernel_compile_it_once(tmp_path):
    """While the kernel's lock is held neither process gets past it; released, one compiles and saves, the
    other waits for it and loads what it saved (without the lock both would compile)."""
    import fcntl
    import time

    clone = _write_package(tmp_path / "clone", value=3)
    cache = tmp_path / "numba-cache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join([str(clone), str(REPO)]))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    path = subprocess.run([sys.executable, "-c", LOCK_PATH], env=env, capture_output=True, text=True,
                          check=True, timeout=300).stdout.strip().splitlines()[-1]
    assert Path(path).parent.is_relative_to(cache) and path.endswith(".lock"), path
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        procs = [subprocess.Popen([sys.executable, "-c", PROBE], env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True) for _ in range(2)]
        time.sleep(3.0)
        assert [p.poll() for p in procs] == [None, None]     # waiting at the lock (or still starting)
    finally:
        os.close(fd)
    outs = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=300)
        assert p.returncode == 0, stderr
        outs.append(json.loads(stdout.strip().splitlines()[-1]))
    assert sorted((o["misses"], o["hits"]) for o in outs) == [(0, 1), (1, 0)], outs
    assert [o["result"] for o in outs] == [4, 4]


UNCACHABLE = ("import numba\nimport numpy as np\n\nBIG = np.arange(200_000, dtype=np.float64)\n\n\n"
              "@numba.njit(cache=True)\ndef last():\n    return BIG[-1]\n")
UNCACHABLE_PROBE = """
import json, warnings
from simulate import kernelcache
kernelcache.PACKAGE_GROUPS.append(("kcpkg",))
import kcpkg.big as big
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    result = big.last()
print(json.dumps({"result": result, "warnings": [(str(w.message), w.filename) for w in caught]}))
"""


def test_a_kernel_numba_cannot_cache_runs_and_numba_says_why(tmp_path):
    """A kernel holding a global array over 1 MB is not cachable (numba keeps a pointer to it): numba warns,
    naming the kernel's file, and the kernel runs uncached; the locator must give numba that file."""
    clone = _write_package(tmp_path / "clone", value=1)
    (clone / "kcpkg" / "big.py").write_text(UNCACHABLE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"),
               PYTHONPATH=os.pathsep.join([str(clone), str(REPO)]))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    done = subprocess.run([sys.executable, "-c", UNCACHABLE_PROBE], env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["result"] == 199_999.0
    said = [Path(f).name for m, f in out["warnings"]
            if 'Cannot cache compiled function "last" as it uses dynamic globals' in m]
    assert said == ["big.py"], out
