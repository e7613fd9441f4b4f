"""``simulate compile`` (:mod:`simulate.precompile`): a run's kernels compiled into the kernel cache ahead of it.

The command runs against a ``NUMBA_CACHE_DIR`` of the test's own, seeded with the user's compiled
kernels for these numba, llvmlite and Python versions (the suite's warm-up fills that cache) but
without miepython's: the red cotton's Mie scatterers need them, so the command must compile them into
the empty folder (numba's compile events, which the command counts, and the files appearing), and a
second run must compile nothing and leave every file of the cache as it was. A kernel the copy lacks
besides those is compiled by the first run too (a run without the warm-up pays that once).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fabric_optics.cli.simulate import main
from simulate import kernelcache
from simulate.precompile import probe_wavelengths

REPO = Path(__file__).resolve().parents[2]
COMMAND = ["compile", "red-cotton", "--method", "classic", "--plan", "quick"]


def _files(cache: Path) -> dict[str, str]:
    return {str(p.relative_to(cache)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(cache.rglob("*")) if p.is_file()}


def _seed_without_miepython(cache: Path) -> Path:
    """The user's compiled kernels of this version copied into ``cache`` but miepython's; the folder they need."""
    tag = kernelcache.version_tag()
    source = kernelcache.cache_base() / tag
    for suffix in (".nbc", ".nbi"):         # data files before indexes: an index never names a missing file
        for f in sorted(source.glob(f"**/*{suffix}")):
            relative = f.parent.relative_to(source)
            if relative.parts[:1] == ("miepython",):
                continue
            (cache / tag / relative).mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, cache / tag / relative / f.name)
    return cache / tag / "miepython"


def _compile(cache: Path, tables: Path) -> str:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), FABRIC_OPTICS_CACHE_DIR=str(tables),
               PYTHONPATH=os.pathsep.join([str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep)
                                                          if p]))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    env.pop("FABRIC_OPTICS_NO_CACHE", None)
    done = subprocess.run([sys.executable, "-m", "fabric_optics.cli.simulate", *COMMAND], env=env,
                          capture_output=True, text=True, timeout=900, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The command twice against one cache that lacks miepython's kernels: its messages and the cache's files."""
    root = tmp_path_factory.mktemp("compile")
    cache, tables = root / "numba", root / "tables"
    miepython = _seed_without_miepython(cache)
    first = _compile(cache, tables)
    files = _files(cache)
    second = _compile(cache, tables)
    return {"first": first, "second": second, "files": files, "after": _files(cache), "miepython": miepython,
            "tables": tables}


def test_the_command_compiles_the_missing_kernels_into_the_cache(runs):
    found = re.fullmatch(r"compiled (\d+) kernels of red-cotton --method classic into (.+) \(\d+\.\d s\)",
                         runs["first"])
    assert found, runs["first"]
    assert int(found.group(1)) > 0
    assert sorted(runs["miepython"].glob("*/*.nbi")), "no miepython kernel was written into the cache"


def test_a_second_run_compiles_nothing_and_changes_no_file(runs):
    assert runs["second"].startswith("compiled 0 kernels: those of red-cotton --method classic are in "), runs["second"]
    assert runs["after"] == runs["files"]


def test_the_command_writes_no_table(runs):
    assert not runs["tables"].exists() or not any(runs["tables"].rglob("*"))


@pytest.mark.parametrize(("argv", "names"), [
    (["compile", "--method", "mc"], "CONFIG"),
    (["compile", "no-such-config", "--method", "mc"], "no-such-config"),
    (["compile", "red-cotton", "--method", "fast"], "--method"),
    (["compile", "red-cotton"], "--method"),
    (["compile", "red-cotton", "--method", "mc", "--plan", "no-such-plan"], "--plan"),
])
def test_bad_arguments_get_one_line_and_exit_2(argv, names, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("simulate compile: error:") and names in err, err


def test_the_probe_takes_the_first_middle_and_last_wavelength():
    assert probe_wavelengths(range(390, 711, 10)).tolist() == [390.0, 550.0, 710.0]
    assert probe_wavelengths([450, 650]).tolist() == [450.0, 650.0]
    with pytest.raises(ValueError):
        probe_wavelengths([])
