"""Dataset directories written atomically as a whole folder (``simulate fabric``, ``simulate sweep`` points).

:func:`gonio.data.dataset.write_dataset` replaces each of a dataset's two files atomically, but a
process killed (or a disk that fills) between the two renames leaves the new ``radiance.csv``
beside no ``meta.json`` (or the old one), and temporary files behind. Here the folder is the unit:

1. the dataset is written into a sibling temporary directory ``.NAME.<pid>.XXXXXXXX.partial``
   (same parent, so same file system) and flushed to disk;
2. an existing ``NAME`` (an empty directory, or a previous output the caller has recognised) is
   renamed aside to ``.NAME.<pid>.XXXXXXXX.old``;
3. the temporary directory is renamed to ``NAME`` and the parent directory flushed;
4. the old folder is deleted.

At every instant ``NAME`` is either the complete old output, absent (between 2 and 3), or the
complete new one. A failure in 1-3 (``OSError``, an interrupt) puts the old folder back and
removes the temporary one. A run killed outright leaves its ``.partial``/``.old`` folders; the
next write to the same ``NAME`` finds them (:func:`recover`): the folders of a process that no
longer exists are removed, after a ``.old`` one is renamed back to ``NAME`` if ``NAME`` is missing
(the previous output is restored, not lost). Folders of a live process are left alone.

The idea is the classic "write a new tree, then rename" of maildir and of package managers; POSIX
``rename(2)`` replaces an empty directory atomically, which step 2 uses to claim a unique name.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

from gonio.data import claim
from gonio.data.dataset import Dataset, write_dataset

__all__ = ["OutputError", "recover", "recover_all", "write_dataset_dir", "side_folders"]


class OutputError(Exception):
    """The dataset folder could not be written; the message names the folder (nothing was changed)."""


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"\.({re.escape(name)})\.(\d+)\.[a-z0-9_]{{8}}\.(partial|old)")


_ANY = re.compile(r"\.(.+)\.(\d+)\.[a-z0-9_]{8}\.(partial|old)")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:     # another user's process: alive
        return True
    return True


def _scan(parent: Path, pattern: re.Pattern[str]) -> list[tuple[Path, str, int, str]]:
    found = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return []
    for entry in entries:
        m = pattern.fullmatch(entry.name)
        if m and entry.is_dir(follow_symlinks=False):
            found.append((Path(entry.path), m.group(1), int(m.group(2)), m.group(3)))
    return found


def side_folders(out: Path) -> list[tuple[Path, int, str]]:
    """The ``.partial``/``.old`` folders of ``out`` in its parent: ``(path, pid, kind)``."""
    out = Path(out)
    return [(path, pid, kind) for path, _, pid, kind in _scan(out.parent, _pattern(out.name))]


def _recover(parent: Path, folders: list[tuple[Path, str, int, str]]) -> list[Path]:
    removed = []
    dead = [f for f in folders if not _alive(f[2])]
    for path, name, _, kind in sorted(dead, key=lambda f: f[3] != "old"):
        if kind == "old" and not (parent / name).exists():
            os.rename(path, parent / name)
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


def recover(out: Path) -> list[Path]:
    """Clean up after killed writes of ``out`` (module docstring); returns the folders removed.

    A dead run's ``.old`` folder is renamed back to ``out`` when ``out`` is missing (the
    previous output comes back); its other folders are deleted.
    """
    out = Path(out)
    return _recover(out.parent, _scan(out.parent, _pattern(out.name)))


def recover_all(parent: Path) -> list[Path]:
    """:func:`recover` for every output in ``parent`` at once (one directory scan: a sweep's points)."""
    return _recover(Path(parent), _scan(Path(parent), _ANY))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _side(out: Path, kind: str) -> Path:
    return Path(tempfile.mkdtemp(prefix=f".{out.name}.{os.getpid()}.", suffix=f".{kind}", dir=out.parent))


def write_dataset_dir(dataset: Dataset, out: str | os.PathLike, *, recovered: bool = False) -> Path:
    """Write ``dataset`` as the directory ``out``, replacing it as one folder (module docstring).

    ``out`` may be missing, or a directory the caller has checked may be replaced (empty, or a
    previous output of the same command): everything in it is replaced. Returns ``out``.
    ``recovered=True``: the caller ran :func:`recover_all` on the parent (skip the scan).

    Raises
    ------
    OutputError
        ``OUT: cannot write the dataset (No space left on device); OUT was left as it was`` for
        any ``OSError`` on the way, after restoring the previous folder and removing the
        temporary one.
    """
    out = Path(out)
    tmp: Path | None = None
    old: Path | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        if not recovered:
            recover(out)
        tmp = _side(out, "partial")
        write_dataset(dataset, tmp)
        os.chmod(tmp, 0o777 & ~_umask())     # mkdtemp's 0700 is for secrets; a dataset is shared
        claim.verify(out)                    # the claim still ours at the final rename
        if out.exists():
            old = _side(out, "old")
            os.rename(out, old)              # replaces the empty placeholder atomically
        os.rename(tmp, out)
        tmp = None
        _fsync_dir(out.parent)
    except OSError as exc:
        raise OutputError(f"{out}: cannot write the dataset ({exc.strerror or exc}); "
                          f"{out} was left as it was") from None
    finally:
        if tmp is not None:                  # failed before the swap: put the old folder back
            if old is not None and not out.exists():
                os.rename(old, out)
                old = None
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    dataset.path = out
    return out


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
