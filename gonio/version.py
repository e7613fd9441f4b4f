"""The version of fabric-optics and, in a git checkout, the commit it runs from.

Every dataset's ``meta.json`` (``software``), every simulation's provenance, every report and the
``--version`` of the three command lines take their figures from here, so that a result can be
traced to the code that made it: ``0.2.0`` is the installed distribution's version (its
``pyproject.toml`` when the package is not installed), ``abc1234`` the commit of the checkout the
code is imported from, ``+dirty`` when tracked files differ from it. An installed copy outside a
checkout has no commit (``None``).

>>> from gonio.version import VERSION, describe
>>> describe("gonio").startswith(f"gonio {VERSION}")
True
"""

from __future__ import annotations

import functools
import importlib.metadata
import re
import subprocess
from pathlib import Path

__all__ = ["VERSION", "commit", "describe", "software"]

#: the checkout (or installed tree) that holds the four packages
_ROOT = Path(__file__).resolve().parents[1]


def _version() -> str:
    try:
        return importlib.metadata.version("fabric-optics")
    except importlib.metadata.PackageNotFoundError:   # run from a source tree that is not installed
        pyproject = _ROOT / "pyproject.toml"
        found = re.search(r'(?m)^version\s*=\s*"([^"]+)"', pyproject.read_text()) if pyproject.is_file() else None
        return found.group(1) if found else "unknown"


#: the version of fabric-optics (``pyproject.toml``'s, as installed)
VERSION: str = _version()


@functools.lru_cache(maxsize=1)
def commit() -> str | None:
    """Give the short hash of the checkout's ``HEAD``, with ``+dirty`` when tracked files are modified.

    ``None`` outside a git checkout or without git.
    """
    if not (_ROOT / ".git").exists():
        return None

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(_ROOT), *args], capture_output=True, text=True, timeout=10,
                              check=True).stdout.strip()

    try:
        head = git("rev-parse", "--short=7", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{head}+dirty" if dirty else head


def describe(program: str = "fabric-optics") -> str:
    """What ``--version`` prints: ``"gonio 0.2.0 (git abc1234)"``, without the parenthesis outside a checkout."""
    c = commit()
    return f"{program} {VERSION}" + (f" (git {c})" if c else "")


def software() -> dict:
    """``{"package": "fabric-optics", "version": ..., "commit": ...}``: the provenance of a result."""
    return {"package": "fabric-optics", "version": VERSION, "commit": commit()}
