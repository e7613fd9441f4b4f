"""Numba's compiled kernels cached once per machine, keyed by their source's content, not by where it lies.

Numba's own cache locators put a module's compiled kernels beside it (``__pycache__``) or, with
``NUMBA_CACHE_DIR``, in a folder named after the hash of the module's absolute folder: a fresh clone
of the project, or a second worktree, never finds the kernels an earlier one compiled, and compiles
them all again. Its source stamp is the module's own file: a kernel that inlines
or calls a kernel of another module is not recompiled when only that other module changes.

:class:`ContentHashLocator` (installed by :func:`install`, which ``simulate`` and ``fabric_optics``
call on import) caches the kernels of the project's packages (:data:`PACKAGE_GROUPS`; and miepython's,
whose kernels :mod:`simulate.optics.mie` caches) under::

    <base>/<numba, llvmlite, Python, machine>/<package-relative folder>/<module>-<key>/

- ``<base>``: ``NUMBA_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/fabric-optics/numba``, else
  ``~/.cache/fabric-optics/numba`` (beside the table cache of :mod:`simulate.fiber.tablecache`, which
  neither counts nor evicts it; ``FABRIC_OPTICS_NO_CACHE`` concerns the tables only);
- ``<key>`` (:func:`source_key`): the SHA-256 of the module's package-relative path and content and
  those of every module of its package group it imports, transitively: what a kernel calls, inlines
  or reads as a constant is a global of its module, bound by those imports. Every import counts,
  also those inside functions (a superset: they are found by a pattern over the text, 20x cheaper
  than parsing it; a docstring line that reads like an import only adds a file to the key). Editing
  a module recompiles the kernels of the modules that import it and no others.

A kernel is loaded or compiled under a file lock beside its index (:func:`compile_lock_path`): two
processes that need the same kernel at once (the commands a first ``make demo`` starts side by side)
compile it once, the second loading what the first saved.

Numba's index inside that folder still keys each compiled variant on its signature, the CPU and the
function's bytecode. Two clones of the same sources share one folder; clones whose sources differ
use different folders and never overwrite each other's files (a loaded kernel is always the one its
index was written with). A module keeps the :data:`KEEP` folders used last; older ones are removed
when a new one is made. A folder that cannot be made or written (read-only home) leaves the kernel
to numba's own locators. ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, is numba's to obey:
nothing is installed.

Design after the content-hash locators of cmomy (https://github.com/usnistgov/cmomy,
``src/cmomy/cache.py``) and numba's caching notes
(https://numba.readthedocs.io/en/stable/developer/caching.html).
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import importlib.abc
import importlib.machinery
import os
import platform
import re
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

__all__ = ["PACKAGE_GROUPS", "KEEP", "cache_base", "version_tag", "source_key", "install", "ContentHashLocator",
           "compile_lock_path"]

#: top-level packages whose kernels this locator caches; a module's key follows its imports within its own group
PACKAGE_GROUPS: list[tuple[str, ...]] = [("simulate", "fabric_optics", "gonio", "compare"), ("miepython",)]
#: key folders kept per module (the most recently used); a new one removes the older ones
KEEP = 8

_IMPORT = re.compile(rb"^[ \t]*(?:from[ \t]+([.\w]+)[ \t]+import[ \t]+(\([^)]*\)|[^\n#;]+)|import[ \t]+([^\n#;]+))",
                     re.M)


def cache_base() -> Path:
    """The folder under which the kernels are cached (module docstring); read at every call."""
    explicit = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "fabric-optics" / "numba"


@functools.cache
def version_tag() -> str:
    """``numba-<v>-llvmlite-<v>-<python cache tag>-<machine>``: a compiled kernel is reused only by these."""
    import llvmlite
    import numba

    return (f"numba-{numba.__version__}-llvmlite-{llvmlite.__version__}-{sys.implementation.cache_tag}-"
            f"{platform.machine() or 'unknown'}")


@functools.cache
def _package_root(py_file: str) -> tuple[str, str] | None:
    """``(folder holding the top-level package, top-level package)`` of a module file, or None outside a package."""
    folder = os.path.dirname(py_file)
    if not os.path.isfile(os.path.join(folder, "__init__.py")):
        return None
    while os.path.isfile(os.path.join(os.path.dirname(folder), "__init__.py")):
        folder = os.path.dirname(folder)
    return os.path.dirname(folder), os.path.basename(folder)


def _group(top: str) -> tuple[str, ...] | None:
    for group in PACKAGE_GROUPS:
        if top in group:
            return group
    return None


@functools.cache
def _group_modules(root: str, group: tuple[str, ...]) -> dict[str, str]:
    """Dotted module name -> file of every module of the group's packages under ``root``.

    A package's file is its ``__init__.py``; one listing per folder, once per process.
    """
    out: dict[str, str] = {}
    for top in group:
        for folder, dirs, files in os.walk(os.path.join(root, top)):
            dirs[:] = [d for d in dirs if d != "__pycache__" and not d.startswith(".")]
            package = os.path.relpath(folder, root).replace(os.sep, ".")
            for f in files:
                if f.endswith(".py"):
                    out[package if f == "__init__.py" else f"{package}.{f[:-3]}"] = os.path.join(folder, f)
    return out


def _module_files(modules: dict[str, str], dotted: str) -> list[str]:
    """The files importing ``dotted`` runs (each package's ``__init__.py`` on the way, then the module)."""
    parts = dotted.split(".")
    out = []
    for i in range(1, len(parts) + 1):
        f = modules.get(".".join(parts[:i]))
        if f is None:
            break
        out.append(f)
    return out


@functools.cache
def _imports(py_file: str, root: str, group: tuple[str, ...], mtime_ns: int, size: int) -> tuple[str, ...]:
    """The files of ``group`` that ``py_file``'s import statements name (memoised by the file's stamp)."""
    with open(py_file, "rb") as f:
        text = f.read()
    modules = _group_modules(root, group)
    package = os.path.relpath(os.path.dirname(py_file), root).split(os.sep)
    found: list[str] = []
    for source, names, plain in _IMPORT.findall(text):
        if plain:
            for item in plain.decode("utf-8", "replace").split(","):
                found += _module_files(modules, item.split(" as ")[0].strip())
            continue
        module = source.decode("utf-8", "replace")
        level = len(module) - len(module.lstrip("."))
        if level:
            base = package[:len(package) - level + 1] if level <= len(package) else []
            module = ".".join(base + ([module[level:]] if module[level:] else []))
        found += _module_files(modules, module)
        for item in names.decode("utf-8", "replace").strip("()").replace("\\", " ").split(","):
            name = item.split(" as ")[0].strip()
            if name.isidentifier():
                found += _module_files(modules, f"{module}.{name}")
    return tuple(dict.fromkeys(found))


def source_key(py_file: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of a module's and its group's imported modules' package-relative paths and contents.

    Memoised per file and process (the files are read once per process, as numba reads its sources).

    Parameters
    ----------
    py_file : str or os.PathLike
        A module file of one of :data:`PACKAGE_GROUPS`' packages.

    Returns
    -------
    str
        The key, 64 hex digits.

    Raises
    ------
    ValueError
        For a file outside :data:`PACKAGE_GROUPS`' packages.
    """
    return _source_key(os.path.realpath(py_file))


@functools.cache
def _source_key(path: str) -> str:
    found = _package_root(path)
    group = _group(found[1]) if found else None
    if found is None or group is None:
        raise ValueError(f"{path}: not a module of {PACKAGE_GROUPS}")
    root = found[0]
    seen: dict[str, os.stat_result] = {}
    todo = [path]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        st = seen[f] = os.stat(f)
        todo += _imports(f, root, group, st.st_mtime_ns, st.st_size)
    digest = hashlib.sha256()
    for rel, f in sorted((os.path.relpath(f, root).replace(os.sep, "/"), f) for f in seen):
        digest.update(rel.encode() + b"\0")
        digest.update(_content_digest(f, seen[f].st_mtime_ns, seen[f].st_size))
    return digest.hexdigest()


@functools.cache
def _content_digest(py_file: str, mtime_ns: int, size: int) -> bytes:
    """SHA-256 of a file's bytes (memoised by its stamp, as numba memoises its own source hashes)."""
    with open(py_file, "rb") as f:
        return hashlib.sha256(f.read()).digest()


def _prune(module_dir: Path, stem: str, keep: int) -> None:
    """Remove all but the ``keep`` most recently modified key folders of one module (best effort)."""
    folders = []
    for p in module_dir.glob(f"{stem}-*"):
        try:
            folders.append((p.stat().st_mtime, p))
        except OSError:
            continue
    for _, p in sorted(folders, reverse=True)[keep:]:
        shutil.rmtree(p, ignore_errors=True)


@functools.cache
def _place(py_file: str, base: str) -> tuple[str, str, str, str] | None:
    """``(cache folder, module folder, module name, key)`` of a module of :data:`PACKAGE_GROUPS`, else None."""
    path = os.path.realpath(py_file)
    found = _package_root(path)
    if found is None or _group(found[1]) is None:
        return None
    key = _source_key(path)
    relative = os.path.relpath(path, found[0])
    module_dir = os.path.join(base, version_tag(), os.path.dirname(relative))
    stem = os.path.splitext(os.path.basename(relative))[0]
    return os.path.join(module_dir, f"{stem}-{key[:24]}"), module_dir, stem, key


#: cache folders this process made sure of (made, writable, pruned around)
_ready: set[str] = set()


def _ensure(cache_path: str, module_dir: str, stem: str) -> None:
    """Make the cache folder and check it is writable (OSError if not), once per process; prune its module's."""
    if cache_path in _ready:
        return
    new = not os.path.isdir(cache_path)
    os.makedirs(cache_path, exist_ok=True)
    tempfile.TemporaryFile(dir=cache_path).close()
    if new:
        _prune(Path(module_dir), stem, KEEP)
    else:
        os.utime(cache_path)       # a folder in use is among the newest: pruning keeps it
    _ready.add(cache_path)


def _locator_class() -> type:
    """:class:`ContentHashLocator`, defined once numba's caching module is there."""
    from numba.core.caching import _CacheLocator

    class ContentHashLocator(_CacheLocator):  # type: ignore[misc]
        """Numba cache locator of the project's kernels (module docstring)."""

        def __init__(self, py_func: Any, py_file: str, place: tuple[str, str, str, str]) -> None:
            self._lineno = py_func.__code__.co_firstlineno
            self._py_file = py_file            # numba's warning on a kernel it cannot cache names the file
            self._cache_path, self._module_dir, self._stem, self._key = place

        def ensure_cache_path(self) -> None:
            _ensure(self._cache_path, self._module_dir, self._stem)

        def get_cache_path(self) -> str:
            return self._cache_path

        def get_source_stamp(self) -> str:
            return self._key

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if not os.path.isfile(py_file):
                return None
            try:
                place = _place(py_file, str(cache_base()))
                if place is None:
                    return None
                self = cls(py_func, py_file, place)
                self.ensure_cache_path()
            except OSError:
                return None                    # numba's own locators take it
            _lock_compiles()
            return self

    return ContentHashLocator


ContentHashLocator: type | None = None

#: the lock files this process holds (a kernel compiled again inside its own compilation passes through)
_held: set[str] = set()


def compile_lock_path(dispatcher: Any) -> str | None:
    """The lock file of ``dispatcher``'s compilation, beside its cache index.

    Parameters
    ----------
    dispatcher : numba dispatcher
        A ``cache=True`` kernel.

    Returns
    -------
    str or None
        The lock file's path, or None when the kernel is not cached by :class:`ContentHashLocator`.
    """
    cache = getattr(dispatcher, "_cache", None)
    locator: Any = getattr(getattr(cache, "_impl", None), "locator", None)  # numba's locator, or ours
    if ContentHashLocator is None or not isinstance(locator, ContentHashLocator):
        return None
    folder: str = getattr(locator, "get_cache_path")()  # noqa: B009 - typed as a plain type above
    return os.path.join(folder, f"{getattr(cache, '_impl').filename_base}.lock")  # noqa: B009


def _locked(compile_: Any) -> Any:
    """``Dispatcher.compile`` that holds a per-kernel file lock while it loads or compiles.

    Two processes that need the same kernel (two commands started at once on a fresh machine) would
    both compile it; with the lock the second waits and then loads what the first saved. The lock is
    taken inside numba's own compiler lock (one compiling thread per process), so a kernel compiled
    inside another's compilation cannot deadlock; the kernel releases it when its process ends,
    however it ends.
    """
    from numba.core.compiler_lock import global_compiler_lock

    @functools.wraps(compile_)
    def compile(self: Any, sig: Any) -> Any:
        path = compile_lock_path(self)
        if path is None:
            return compile_(self, sig)
        with global_compiler_lock:
            if path in _held:
                return compile_(self, sig)
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError:
                return compile_(self, sig)       # a folder we cannot write: compile without the lock
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
                _held.add(path)
                return compile_(self, sig)
            finally:
                _held.discard(path)
                os.close(fd)

    compile.__wrapped_by_kernelcache__ = True  # type: ignore[attr-defined]
    return compile


def _lock_compiles() -> None:
    """Make numba's dispatchers take :func:`compile_lock_path`'s lock when they compile (once)."""
    dispatcher = sys.modules.get("numba.core.dispatcher")
    cls = getattr(dispatcher, "Dispatcher", None)
    if cls is not None and not getattr(cls.compile, "__wrapped_by_kernelcache__", False):
        cls.compile = _locked(cls.compile)


def _register(caching: ModuleType) -> None:
    global ContentHashLocator
    from numba.core import config

    if config.CACHE_LOCATOR_CLASSES:
        return
    if ContentHashLocator is None:
        ContentHashLocator = _locator_class()
    classes = caching.CacheImpl._locator_classes
    if ContentHashLocator not in classes:
        classes.insert(0, ContentHashLocator)


class _RegisterOnImport(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Registers the locator right after ``numba.core.caching`` is executed (numba is not imported for it)."""

    _name = "numba.core.caching"

    def find_spec(self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None) -> Any:
        if fullname != self._name:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None:
            return None
        self._loader = spec.loader
        spec.loader = self
        return spec

    def create_module(self, spec: Any) -> ModuleType | None:
        return self._loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self._loader.exec_module(module)  # type: ignore[attr-defined]
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        _register(module)


def install() -> None:
    """Put :class:`ContentHashLocator` first among numba's cache locators, now or when numba is imported.

    Must run before a ``cache=True`` kernel is defined (``simulate`` and ``fabric_optics`` call it on
    import). Idempotent.
    """
    caching = sys.modules.get("numba.core.caching")
    if caching is not None:
        _register(caching)
    elif not any(isinstance(f, _RegisterOnImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _RegisterOnImport())

