"""The run directory: the files a session owns there, and the lock that makes it one session's.

A run directory holds the journal (:data:`JOURNAL_NAME`), the dataset written from it
(``radiance.csv``, ``meta.json``) and, for ``gonio demo``, its marker (:data:`DEMO_MARKER`).
A session locks the directory for its whole duration (:class:`RunDirLock`).
"""

from __future__ import annotations

import fcntl
import os
import re
from pathlib import Path

from gonio.acquisition.journal import JournalError
from gonio.data import CSV_NAME, META_NAME
from gonio.data.outputs import JOURNAL_NAME, RUN_FILES

__all__ = ["JOURNAL_NAME", "DEMO_MARKER", "RUN_DIR_FILES", "owned_by_run", "RunDirLock", "RunDirLocked"]

#: Marker of a run directory written by ``gonio demo`` (what it may replace on the next demo).
DEMO_MARKER = ".gonio-demo.json"
#: Files of a run directory that a session owns (besides the dataset writer's temporary files).
RUN_DIR_FILES = (JOURNAL_NAME, CSV_NAME, META_NAME, DEMO_MARKER)
assert set(RUN_DIR_FILES) == set(RUN_FILES), "gonio.data.outputs.RUN_FILES names the same files"
_DATASET_TEMP = re.compile(r"\.(?:radiance\.csv|meta\.json)\..*\.tmp")


def owned_by_run(run_dir: str | os.PathLike, path: str | os.PathLike) -> bool:
    """True when ``path`` is (or would be) one of the files a session owns in ``run_dir``.

    Those are :data:`RUN_DIR_FILES` and the dataset writer's temporary files, symlinks resolved.
    """
    p, d = Path(path).resolve(), Path(run_dir).resolve()
    return p.parent == d and (p.name in RUN_DIR_FILES
                              or bool(_DATASET_TEMP.fullmatch(p.name)))


class RunDirLocked(JournalError):
    """Another session holds the run directory's lock (:class:`RunDirLock`)."""


class RunDirLock:
    """Exclusive lock on a run directory for one whole session (``fcntl.flock`` on the folder).

    Two sessions on one run directory would interleave two instruments' points in one journal:
    the second is refused at once (:meth:`acquire` never waits). The lock is advisory, held on
    an open descriptor of the directory itself (no lock file is left behind), and the kernel
    releases it when the process ends, however it ends (a killed session never leaves a stale
    lock).
    """

    def __init__(self, path: Path, fd: int):
        self.path = path
        self._fd: int | None = fd      # None once released

    @classmethod
    def acquire(cls, run_dir: str | os.PathLike) -> RunDirLock:
        """Create ``run_dir`` if needed and lock it; :class:`RunDirLocked` if it is taken."""
        path = Path(run_dir)
        path.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RunDirLocked(f"{path}: another gonio session is using this run directory; "
                               "wait until it ends, or choose another --out") from None
        except BaseException:
            os.close(fd)
            raise
        return cls(path, fd)

    def release(self) -> None:
        """Unlock (idempotent)."""
        if self._fd is not None:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None

    def __enter__(self) -> RunDirLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
