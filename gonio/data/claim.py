"""One writer per output: the claim a command holds on its output from its start to its final rename.

The output rule (:mod:`gonio.data.outputs`, ``--force``) is checked when a command starts; a second
command started on the same output a moment later passes the same check, and both would write:
the last rename wins and the first's output disappears although it reported success. So every
writer *claims* its output first and keeps the claim until its output is in place:

- the claim is an exclusive ``fcntl.flock`` on the lock file ``.NAME.lock`` beside the output
  ``NAME`` (same folder). It never waits: a second writer is refused at once with
  :class:`OutputBusy` (one line naming the output; the command lines print it and exit 2, the
  Python interface raises its typed error). The kernel drops the lock when the process ends,
  however it ends, so a killed writer never leaves a stale claim; the file is removed on release.
- the writers' final renames (:func:`gonio.data.atomic_write`,
  :func:`gonio.data.write_files_together`, :func:`simulate.outdir.write_dataset_dir`) call
  :func:`verify` first: when this thread holds a claim on the output, its lock file must still be
  the one it locked (a lock file removed or replaced behind its back is refused, nothing renamed).
- a claim is re-entrant within one thread (the command line claims, then calls the Python interface,
  which claims the same output again); another thread of the same process is refused like another
  process.

The run folders of ``gonio acquire`` are locked for a whole session by
:class:`gonio.acquisition.rundir.RunDirLock` in addition.
"""

from __future__ import annotations

import errno
import fcntl
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

__all__ = ["OutputBusy", "claim_output", "lock_path", "verify"]


class OutputBusy(ValueError):
    """Another writer holds the claim on this output (or the claim was lost before the final rename)."""


@dataclass
class _Held:
    fd: int
    thread: int
    depth: int
    ino: tuple[int, int]


_HELD: dict[Path, _Held] = {}
_GUARD = threading.Lock()


def lock_path(out: str | os.PathLike) -> Path:
    """The lock file of the output ``out``: ``.NAME.lock`` in the same folder."""
    p = _key(out)
    return p.parent / f".{p.name}.lock"


def _key(out: str | os.PathLike) -> Path:
    p = Path(os.path.abspath(os.fspath(out)))
    return p.parent.resolve() / p.name if p.name else p


def _busy(out: Path, option: str) -> OutputBusy:
    return OutputBusy(f"{option} {out}: another writer is writing this output now; nothing was changed: wait "
                      "until it ends, or choose another output")


def _acquire(out: Path, lock: Path, option: str) -> tuple[int, tuple[int, int]]:
    lock.parent.mkdir(parents=True, exist_ok=True)      # (parents=False: claim_output checked it exists)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise _busy(out, option) from None
        except BaseException:
            os.close(fd)
            raise
        st = os.fstat(fd)
        try:
            now = os.stat(lock, follow_symlinks=False)
        except FileNotFoundError:       # its holder released it (and removed it) meanwhile: lock anew
            os.close(fd)
            continue
        if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
            os.close(fd)
            continue
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass                        # the pid is for people reading the folder, not for the lock
        return fd, (st.st_dev, st.st_ino)


@contextmanager
def claim_output(out: str | os.PathLike, *, option: str = "--out", parents: bool = True) -> Iterator[Path]:
    """Hold the claim on the output ``out`` (a file or a folder, existing or not) for the block.

    Raises :class:`OutputBusy` at once when another process or thread holds it; :class:`OSError`
    (naming the lock file) when the lock file cannot be created, e.g. an output in a folder that
    cannot be written. ``option`` names the output in the message (``--out``, ``path=``).
    ``parents``: create the folders above ``out`` for the lock file (a folder output, which its
    writer creates anyway); ``False`` (a file output, whose writer refuses a missing folder): an
    output whose folder does not exist is not claimed, its writer's own refusal follows.
    Yields the lock file's path.
    """
    key = _key(out)
    lock = lock_path(out)
    me = threading.get_ident()
    if not parents and not lock.parent.is_dir():
        yield lock
        return
    with _GUARD:
        held = _HELD.get(key)
        if held is not None:
            if held.thread != me:
                raise _busy(Path(out), option)
            held.depth += 1
        else:
            try:
                fd, ino = _acquire(Path(out), lock, option)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK,):
                    raise _busy(Path(out), option) from None
                raise OSError(exc.errno, exc.strerror, exc.filename or str(lock)) from None
            held = _HELD[key] = _Held(fd, me, 1, ino)
    try:
        yield lock
    finally:
        with _GUARD:
            held.depth -= 1
            if held.depth == 0:
                del _HELD[key]
                try:
                    if _same(lock, held.ino):
                        os.unlink(lock)
                except OSError:
                    pass
                finally:
                    os.close(held.fd)     # closing the descriptor drops the flock


def _same(lock: Path, ino: tuple[int, int]) -> bool:
    try:
        st = os.stat(lock, follow_symlinks=False)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == ino


def verify(path: str | os.PathLike, *, option: str = "--out") -> None:
    """Check the claim at a writer's final rename of ``path``.

    When this thread claimed ``path`` or a folder above it, that claim's lock file must still be the one
    it locked; :class:`OutputBusy` otherwise (nothing is renamed). No claim held there by this thread:
    nothing to check (a caller that claims nothing, e.g. a cache).
    """
    if not _HELD:
        return
    key = _key(path)
    for out in (key, *key.parents):
        held = _HELD.get(out)
        if held is None or held.thread != threading.get_ident():
            continue
        if not _same(lock_path(out), held.ino):
            raise OutputBusy(f"{option} {out}: the claim on this output was lost (its lock file "
                             f"{lock_path(out)} was removed or replaced by someone else); nothing was renamed "
                             "into place: run the command again")
        return
