"""A content-addressed disk cache of Monte Carlo tables and of the felt Monte Carlo's built felts.

The tables are the woven yarn table, the surface albedo, the structured summation's walks and the
exit tables.

A table is stored under the SHA-256 of everything it depends on (:func:`content_key`): the
inputs as canonical bytes (:func:`content_hash` walks dataclasses, arrays, numbers, strings),
the code that computes it (:func:`code_version`: the source text of the modules named, plus the
numpy / numba / miepython versions) and the run's photons and seed. The same key is the same
table, so a hit returns the bit-identical arrays a miss would have computed; anything changed
is a different key (a miss), never a stale table.

Where and how much (environment variables, read at every call so a test or a CLI flag can set them):

- ``FABRIC_OPTICS_CACHE_DIR``: the directory (default ``$XDG_CACHE_HOME/fabric-optics``, else
  ``~/.cache/fabric-optics``);
- ``FABRIC_OPTICS_CACHE_MAX_BYTES``: the size bound (default 2 GiB); after a store the least
  recently used entries (by mtime; a hit touches its entry) are deleted until the total is below.
  Entries this process stored or read are evicted last (a run never evicts a table it made for
  itself while older ones remain), and only when the run's own tables exceed the bound, which is
  then said in a warning naming the bound to raise. Every eviction is logged at INFO (``-v``):
  the entry's kind, size and last use, and the cache's total before and after.
  Sizes: a summation fit of the felt (``green-felt`` on its 10 nm plan) stores six structured-walk
  entries, 129 MB in all; a felt fit with its Monte Carlo stores exit tables (351 MB) and yarn
  tables (294 MB), about 0.65 GB: a third of the default bound, which therefore holds one felt fit
  with room for about two more before the oldest entries go (the bound is not raised). A felt Monte
  Carlo run also stores its felt realisations (``felt-*`` entries, :func:`simulate.geometry.felt.cached_felt_mesh`;
  ``[method] felt_realisations``, 4 by default), counted and evicted as any entry: 16 MB each for
  ``green-felt-mc`` (26 MB with 13 % crimp), once per felt structure (a fit freeing a ``[structure]`` field
  stores them per structure it runs);
- ``FABRIC_OPTICS_NO_CACHE=1`` (``simulate ... --no-cache``): neither read nor written.

Safety: an entry is one file, ``MAGIC + sha256(payload) + payload`` (``payload`` an uncompressed
``.npz`` without pickles), written to a temporary file in the same directory and moved into
place with :func:`os.replace` (atomic on POSIX): concurrent writers of the same key each move a
complete file, the last one stays, a reader sees one whole file or none. A reader checks each
array against the zip's own CRC-32 of its member (the ``.npy`` header and every data byte, computed
over the bytes as they are read into the array: no second pass) and the archive's structure (its
directory at the file's end, each member's local header, shape x dtype = the member's size); a
truncated or corrupted entry is deleted and reported as a miss (the caller
recomputes and stores again). What this gives up against a SHA-256 of the whole file (still
written in the header, no longer read): a CRC-32 finds every burst of up to 32 flipped bits and
misses a random corruption with probability 2^-32 per array, and it is no defence against a file
altered on purpose (the cache directory is the user's own); bytes outside the arrays (the header's
digest, the zip's timestamps) are not checked, as they do not change what is read. A cache that cannot be written (read-only, full disk) only logs a
warning: the run goes on with the computed table.

Design after the usual content-addressed build caches (ccache's hash of inputs + compiler
identity; joblib.Memory's hash of arguments + function code), with git's write-then-rename for
atomicity: https://ccache.dev/manual/latest.html#_how_ccache_works ,
https://joblib.readthedocs.io/en/stable/memory.html .
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import importlib.metadata
import importlib.util
import io
import logging
import math
import os
import struct
import threading
import time
import zipfile
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from simulate.montecarlo.transport import ParameterError

__all__ = ["ENV_DIR", "ENV_MAX_BYTES", "ENV_DISABLE", "DEFAULT_MAX_BYTES", "SUFFIX", "CacheError", "cache_dir", "stored",
           "max_bytes", "enabled", "content_hash", "code_version", "content_key", "load", "store", "cached",
           "entries", "evict"]

log = logging.getLogger(__name__)

ENV_DIR = "FABRIC_OPTICS_CACHE_DIR"
ENV_MAX_BYTES = "FABRIC_OPTICS_CACHE_MAX_BYTES"
ENV_DISABLE = "FABRIC_OPTICS_NO_CACHE"
DEFAULT_MAX_BYTES = 2 * 1024 ** 3
SUFFIX = ".fotab"
_MAGIC = b"FOTAB\x00\x01\n"
_DIGEST = 32


class CacheError(ParameterError):
    """A cache setting that cannot be used (the message names the environment variable; CLI exit 2)."""


def cache_dir() -> Path:
    """The cache directory (module docstring); not created here."""
    explicit = os.environ.get(ENV_DIR, "").strip()
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "fabric-optics"


def max_bytes() -> int:
    """The size bound in bytes (``FABRIC_OPTICS_CACHE_MAX_BYTES``, default 2 GiB)."""
    text = os.environ.get(ENV_MAX_BYTES, "").strip()
    if not text:
        return DEFAULT_MAX_BYTES
    try:
        value = int(float(text))
    except ValueError:
        raise CacheError(f"{ENV_MAX_BYTES}={text!r}: expected a number of bytes, e.g. 2147483648") from None
    if value < 0:
        raise CacheError(f"{ENV_MAX_BYTES}={text!r}: must be >= 0")
    return value


def enabled() -> bool:
    """False when ``FABRIC_OPTICS_NO_CACHE`` is set to anything but ``""``, ``0``, ``false``, ``no``."""
    return os.environ.get(ENV_DISABLE, "").strip().lower() in ("", "0", "false", "no")


def _feed(h: Any, obj: Any) -> None:
    """Feed a canonical, type-tagged byte form of ``obj`` into the hash ``h``."""
    if not (_feed_scalar(h, obj) or _feed_composite(h, obj)):
        raise TypeError(f"content_hash: no canonical form for {type(obj).__qualname__}")


def _feed_scalar(h: Any, obj: Any) -> bool:
    """Feed ``obj`` into ``h`` when it is None, a bool, a number, a string or bytes; False for anything else."""
    if obj is None or isinstance(obj, (bool, np.bool_)):
        h.update(b"N" if obj is None else (b"T" if obj else b"F"))
    elif isinstance(obj, (int, np.integer)):
        h.update(b"i" + str(int(obj)).encode() + b";")
    elif isinstance(obj, (float, np.floating)):
        h.update(b"f" + struct.pack("<d", float(obj)))
    elif isinstance(obj, (complex, np.complexfloating)):
        h.update(b"c" + struct.pack("<dd", complex(obj).real, complex(obj).imag))
    elif isinstance(obj, str):
        b = obj.encode()
        h.update(b"s" + str(len(b)).encode() + b":" + b)
    elif isinstance(obj, bytes):
        h.update(b"b" + str(len(obj)).encode() + b":" + obj)
    else:
        return False
    return True


def _feed_composite(h: Any, obj: Any) -> bool:
    """Feed ``obj`` into ``h`` when it is an array, an enum, a dataclass, a dict, a list or a tuple; else False."""
    if isinstance(obj, np.ndarray):
        if obj.dtype.hasobject:
            raise TypeError("content_hash: object arrays have no canonical bytes")
        a = np.ascontiguousarray(obj)
        h.update(b"a" + a.dtype.str.encode() + repr(a.shape).encode())
        h.update(a.tobytes())
    elif isinstance(obj, enum.Enum):
        h.update(b"e" + type(obj).__qualname__.encode() + b".")
        _feed(h, obj.value)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(b"D" + type(obj).__module__.encode() + b"." + type(obj).__qualname__.encode() + b"{")
        for f in dataclasses.fields(obj):
            _feed(h, f.name)
            _feed(h, getattr(obj, f.name))
        h.update(b"}")
    elif isinstance(obj, dict):
        h.update(b"d" + str(len(obj)).encode() + b"{")
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
        h.update(b"}")
    elif isinstance(obj, (list, tuple)):
        h.update((b"l" if isinstance(obj, list) else b"t") + str(len(obj)).encode() + b"[")
        for x in obj:
            _feed(h, x)
        h.update(b"]")
    else:
        return False
    return True


def content_hash(obj: Any) -> str:
    """SHA-256 (hex) of a canonical byte form of ``obj`` (dataclasses by field, arrays by dtype/shape/bytes).

    Equal content gives the same hash in every process.

    Parameters
    ----------
    obj : object
        None, a bool, number, string, bytes, array, enum, dataclass, dict, list or tuple (nested freely).

    Returns
    -------
    str
        The hash in hex.

    Raises
    ------
    TypeError
        For an object without a canonical form (it cannot be a key).

    Examples
    --------
    >>> content_hash({"a": 1.0, "b": (1, 2)}) == content_hash({"b": (1, 2), "a": 1.0})
    True
    >>> content_hash(1.0) == content_hash(1)
    False
    """
    h = hashlib.sha256()
    _feed(h, obj)
    return h.hexdigest()


_CODE_VERSIONS: dict[tuple[str, ...], str] = {}


def code_version(modules: Iterable[str]) -> str:
    """SHA-256 of the source text of ``modules`` (dotted names) and of numpy/numba/miepython's versions.

    Any edit to one of these files changes every key built with it (memoised per process).

    Parameters
    ----------
    modules : iterable of str
        Dotted names of the modules whose source a table depends on.

    Returns
    -------
    str
        The hash in hex.
    """
    names = tuple(sorted(modules))
    if names not in _CODE_VERSIONS:
        h = hashlib.sha256()
        for name in names:
            spec = importlib.util.find_spec(name)
            if spec is None or spec.origin is None:
                raise ValueError(f"code_version: module {name} not found")
            h.update(name.encode() + b"\0" + Path(spec.origin).read_bytes() + b"\0")
        for dist in ("numpy", "numba", "miepython"):
            try:   # installed versions, without importing them (miepython's import compiles)
                version = importlib.metadata.version(dist)
            except importlib.metadata.PackageNotFoundError:
                version = "absent"
            h.update(f"{dist}={version}\0".encode())
        _CODE_VERSIONS[names] = h.hexdigest()
    return _CODE_VERSIONS[names]


def content_key(kind: str, inputs: Any, modules: Iterable[str]) -> str:
    """The key of a table: ``kind`` and the hash of its inputs and of its code's version.

    Parameters
    ----------
    kind : str
        A file-name-safe word naming the table's kind (it begins the entry's file name).
    inputs : object
        Everything the table depends on (:func:`content_hash`).
    modules : iterable of str
        The modules that compute it (:func:`code_version`).

    Returns
    -------
    str
        ``"<kind>-<hash>"``.
    """
    return f"{kind}-{content_hash((kind, inputs, code_version(modules)))[:40]}"


def _path(key: str, directory: Path | None = None) -> Path:
    if not key or "/" in key or key.startswith("."):
        raise ValueError(f"tablecache: bad key {key!r}")
    return (cache_dir() if directory is None else directory) / (key + SUFFIX)


def load(key: str) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``key``, or None (absent, disabled, or corrupt: then deleted).

    Parameters
    ----------
    key : str
        A :func:`content_key`.

    Returns
    -------
    dict of str to numpy.ndarray, or None
        The entry's arrays by name.
    """
    if not enabled():
        return None
    path = _path(key)
    # read straight from the file into the arrays' buffers, each member's CRC-32 (the zip's own
    # checksum, over the .npy header and the data) computed over the bytes read: one pass, one copy
    # (the SHA-256 of the whole file, then numpy's chunked reads through zipfile, cost 2.8 CPU s for
    # the felt run's 0.6 GB of tables; this reads and checks them in ~0.4 s)
    try:
        f = open(path, "rb")
    except OSError:
        return None
    with f:
        try:
            arrays = _read_entry(f)
        except _UNREADABLE as exc:
            log.warning("table cache: %s is corrupt (%s); it is recomputed", path, exc)
            f.close()
            _unlink(path)
            return None
    try:
        os.utime(path)  # recently used: the LRU order of evict()
    except OSError:
        pass
    with _STORED_LOCK:
        _USED.add(str(path))
    return arrays


#: what a corrupt, truncated or foreign entry can raise while :func:`_read_entry` parses it
_NPY_LEAD = 12
_UNREADABLE = (ValueError, OSError, KeyError, EOFError, OverflowError, NotImplementedError, UnicodeDecodeError,
               struct.error, zipfile.BadZipFile)


def _read_entry(f: Any) -> dict[str, np.ndarray]:
    """The arrays of an open entry, every byte of every member checked against the zip's CRC-32.

    An entry's payload is an uncompressed ``.npz`` (``np.savez``): each array a stored ``.npy``
    member. The archive's directory (at the file's end: a truncated file has none) gives each
    member's offset, size and CRC-32; the members must follow one another from the header to the
    directory (none missing), each one's local header must name the same file and it must lie
    inside the file (checked before anything is allocated); the data are read into
    the array's buffer and the CRC-32 of ``.npy`` header + data must match before the header is
    parsed; its shape and dtype must account for exactly the data. Anything else raises one of
    ``_UNREADABLE``.
    """
    head = f.read(len(_MAGIC) + _DIGEST)
    if len(head) < len(_MAGIC) + _DIGEST or head[:len(_MAGIC)] != _MAGIC:
        raise ValueError("not a table-cache entry (header)")
    size = os.fstat(f.fileno()).st_size
    with zipfile.ZipFile(f) as z:       # zipfile finds the archive after the leading bytes
        members = z.infolist()
        directory = z.start_dir         # type: ignore[attr-defined]
    arrays: dict[str, np.ndarray] = {}
    at = len(head)                      # the members tile the payload: none is missing or in between
    for info in members:
        name = info.filename
        if info.header_offset != at:
            raise ValueError(f"member {name!r}: not where the previous one ends")
        if not name.endswith(".npy") or info.compress_type != zipfile.ZIP_STORED or \
                info.file_size != info.compress_size or info.flag_bits & 0x1:
            raise ValueError(f"member {name!r} is not a stored .npy")
        f.seek(info.header_offset)
        local = f.read(30)
        if len(local) != 30 or local[:4] != b"PK\x03\x04":
            raise ValueError(f"member {name!r}: no local header")
        n_name, n_extra = struct.unpack("<HH", local[26:30])
        if f.read(n_name) != info.orig_filename.encode("utf-8" if info.flag_bits & 0x800 else "cp437"):
            raise ValueError(f"member {name!r}: its local header names another file")
        start = info.header_offset + 30 + n_name + n_extra
        if start + info.file_size > size:
            raise ValueError(f"member {name!r}: beyond the end of the file")
        f.seek(start)
        lead = f.read(_NPY_LEAD)        # the .npy magic, version and header length, then its header
        if len(lead) != _NPY_LEAD or lead[:6] != b"\x93NUMPY" or lead[6:8] not in (b"\x01\x00", b"\x02\x00"):
            raise ValueError(f"member {name!r}: not a .npy (1.0 or 2.0)")
        n_head = 10 + struct.unpack("<H", lead[8:10])[0] if lead[6] == 1 else 12 + struct.unpack("<I", lead[8:12])[0]
        if n_head > info.file_size:
            raise ValueError(f"member {name!r}: header longer than the member")
        f.seek(start)
        npy_head = f.read(n_head)
        raw = np.empty(info.file_size - n_head, np.uint8)
        buf = memoryview(raw.data)
        if len(npy_head) != n_head or f.readinto(buf) != raw.size:
            raise ValueError(f"member {name!r}: truncated")
        if zlib.crc32(buf, zlib.crc32(npy_head)) != info.CRC:
            raise ValueError(f"member {name!r}: checksum")
        # the bytes are those written: the header is numpy's own, parsed only now
        header = io.BytesIO(npy_head)
        version = np.lib.format.read_magic(header)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read_header(header)
        if dtype.hasobject or math.prod(shape) * dtype.itemsize != raw.size:
            raise ValueError(f"member {name!r}: shape and dtype do not match its size (or an object array)")
        arrays[name[:-4]] = raw.view(dtype).reshape(shape, order="F" if fortran else "C")
        at = start + info.file_size
    if at != directory:
        raise ValueError("the archive's directory does not follow its last member")
    return arrays


_STORED: dict[str, int] = {}
_STORED_LOCK = threading.Lock()
#: paths of the entries this process stored or read: evicted last (module docstring)
_USED: set[str] = set()


def stored(kind: str) -> int:
    """How many entries of ``kind`` (the first word of :func:`content_key`) this process has written.

    What an interrupted command can honestly say it left behind (``simulate fit``'s Ctrl-C message).

    Parameters
    ----------
    kind : str
        The entries' kind.

    Returns
    -------
    int
        The count.
    """
    with _STORED_LOCK:
        return _STORED.get(kind, 0)


class _Payload:
    """The file ``f`` from ``offset`` on, as :func:`np.savez` sees it.

    The archive it writes there is byte for byte the one it would write alone (its offsets count from
    the payload's start).
    """

    def __init__(self, f: Any, offset: int) -> None:
        self._f, self._offset = f, offset

    def write(self, data: Any) -> int:
        return self._f.write(data)

    def read(self, size: int = -1) -> bytes:      # np.savez takes an object with ``read`` for a file
        return self._f.read(size)

    def tell(self) -> int:
        return self._f.tell() - self._offset

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._f.seek(pos + self._offset if whence == 0 else pos, whence) - self._offset

    def flush(self) -> None:
        self._f.flush()


#: bytes read back at a time to hash an entry's payload
_HASH_BLOCK = 16 * 2 ** 20


def _write_entry(f: Any, arrays: dict[str, Any]) -> None:
    """Write the entry ``MAGIC + sha256(payload) + payload`` of ``arrays`` into the open file ``f`` (``w+b``).

    The archive goes straight into the file (numpy writes each array in blocks of 16 MiB) and is then read
    back in blocks to hash it: no copy of the payload is held in memory (the felt's exit tables are 285 MB
    each, and an in-memory archive plus its concatenation with the header held two copies beside the
    table: the Monte Carlo fit's peak memory).
    """
    f.write(_MAGIC + bytes(_DIGEST))
    start = f.tell()
    np.savez(_Payload(f, start), **{k: np.asarray(v) for k, v in arrays.items()})  # type: ignore[arg-type]
    f.flush()
    h = hashlib.sha256()
    f.seek(start)
    block = bytearray(_HASH_BLOCK)
    view = memoryview(block)
    while True:
        n = f.readinto(block)
        if not n:
            break
        h.update(view[:n])
    f.seek(len(_MAGIC))
    f.write(h.digest())


def store(key: str, arrays: dict[str, Any]) -> Path | None:
    """Write ``arrays`` under ``key`` (temporary file + :func:`os.replace`), then :func:`evict`.

    Parameters
    ----------
    key : str
        A :func:`content_key`.
    arrays : dict of str to array_like
        The entry's arrays by name.

    Returns
    -------
    pathlib.Path or None
        The entry's file; None when the cache is disabled or the write failed.
    """
    if not enabled():
        return None
    path = _path(key)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.{time.monotonic_ns()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "w+b") as f:
            _write_entry(f, arrays)
        os.replace(tmp, path)
    except OSError as exc:
        log.warning("table cache: cannot write %s (%s); the run goes on without it", path, exc)
        _unlink(tmp)
        return None
    with _STORED_LOCK:
        kind = key.split("-", 1)[0]
        _STORED[kind] = _STORED.get(kind, 0) + 1
        _USED.add(str(path))
    evict()
    return path


def cached(key: str, compute: Callable[[], dict[str, Any]]) -> tuple[dict[str, np.ndarray], bool]:
    """``(arrays, hit)``: the stored arrays of ``key``, else ``compute()`` stored and returned as loaded.

    On a miss the arrays returned are those :func:`load` would give (same dtypes, numpy arrays),
    so a later hit is bit-identical to this miss.

    Parameters
    ----------
    key : str
        A :func:`content_key`.
    compute : callable
        Makes the arrays on a miss.

    Returns
    -------
    arrays : dict of str to numpy.ndarray
        The entry's arrays.
    hit : bool
        Whether they were read from the cache.
    """
    got = load(key)
    if got is not None:
        return got, True
    arrays = {k: np.asarray(v) for k, v in compute().items()}
    store(key, arrays)
    return arrays, False


def entries(directory: Path | None = None) -> list[tuple[float, int, Path]]:
    """``(mtime, size, path)`` of the cache's entries, oldest first.

    Parameters
    ----------
    directory : pathlib.Path, optional
        The cache's folder (default: :func:`cache_dir`).

    Returns
    -------
    list of (float, int, pathlib.Path)
        One tuple per entry.
    """
    d = cache_dir() if directory is None else directory
    out = []
    try:
        it = list(d.iterdir())
    except OSError:
        return []
    for p in it:
        if p.suffix != SUFFIX or p.name.startswith("."):
            continue
        try:
            st = p.stat()
        except OSError:
            continue
        out.append((st.st_mtime, st.st_size, p))
    out.sort(key=lambda e: (e[0], e[2].name))
    return out


#: the name prefix of a finished fit's entry (:mod:`fabric_optics.fitting.reuse`): evicted after the tables
FIT_PREFIX = "fit-"


def _mb(n: float) -> str:
    return f"{n / 1e6:,.1f} MB"


def evict(limit: int | None = None) -> int:
    """Delete the least recently used entries until the total is at most ``limit`` (default :func:`max_bytes`).

    A finished fit's entry goes after every table, and entries this process stored or read go last
    (module docstring); each eviction is logged at INFO,
    and a warning says when this process's own tables alone exceed the bound. Also removes temporary
    files older than an hour (left by a killed writer).

    Parameters
    ----------
    limit : int, optional
        The bound in bytes.

    Returns
    -------
    int
        The bytes freed.
    """
    limit = max_bytes() if limit is None else limit
    d = cache_dir()
    now = time.time()
    try:
        for p in d.glob(".*.tmp"):
            try:
                if now - p.stat().st_mtime > 3600:
                    _unlink(p)
            except OSError:
                pass
    except OSError:
        pass
    items = entries(d)
    total = sum(size for _, size, _ in items)
    if total <= limit:
        return 0
    with _STORED_LOCK:
        used = set(_USED)
    # least recently used first; a finished fit (a few MB, a whole fit to compute again) after every table; this
    # process's own entries after every other one
    others = [e for e in items if str(e[2]) not in used]
    order = ([e for e in others if not e[2].name.startswith(FIT_PREFIX)]
             + [e for e in others if e[2].name.startswith(FIT_PREFIX)] + [e for e in items if str(e[2]) in used])
    start, freed, gone, own = total, 0, 0, 0
    for mtime, size, p in order:
        if total <= limit:
            break
        if _unlink(p):
            mine = str(p) in used
            total -= size
            freed += size
            gone += 1
            own += mine
            log.info("table cache: evicted %s (%s, %s, last used %s%s) to keep %s within its bound of %s",
                     p.name, p.name.split("-", 1)[0], _mb(size), time.strftime("%Y-%m-%d %H:%M", time.localtime(mtime)),
                     ", made or read by this run" if mine else "", d, _mb(limit))
    if gone:
        log.info("table cache: %d entr%s evicted (%s, least recently used first): %s -> %s of %s",
                 gone, "y" if gone == 1 else "ies", _mb(freed), _mb(start), _mb(total), _mb(limit))
    if own:
        mine_bytes = sum(size for _, size, p in items if str(p) in used)
        log.warning("table cache: this run's own tables (%s) exceed the cache's bound of %s: %d of them evicted, so "
                    "a later run computes them again; set %s to at least %d or run with --no-cache",
                    _mb(mine_bytes), _mb(limit), own, ENV_MAX_BYTES, mine_bytes)
    return freed


def _unlink(path: Path) -> bool:
    try:
        path.unlink()
        return True
    except OSError:
        return False
