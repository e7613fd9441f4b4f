"""Atomic writes of output files: one file, or several together, never half-written.

The one writer of the toolkit's outputs (datasets, reports, tables): :func:`atomic_write` replaces one
file through a temporary file, fsync and rename; :func:`write_files_together` stages several and
renames them only once all are on disk. A crash or a full disk leaves the old files or the new ones.
Both honour the output claim of :mod:`gonio.data.claim`.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import BinaryIO

from gonio.data import claim

__all__ = ["atomic_write", "fsync_dir", "remove_stale_temp_files", "write_files_together"]


def atomic_write(path: str | os.PathLike, data: bytes | Callable[[BinaryIO], object]) -> None:
    """Write ``data`` to ``path`` atomically: temporary file in the same folder, fsync, rename.

    The file gets the usual permissions (``0666 & ~umask``), not ``mkstemp``'s private 0600:
    datasets and reports are meant to be shared. A crash leaves either the old file or the new one.
    ``data`` may also be a function that writes the file's bytes to the open handle it is given
    (a mesh exporter, a large table). Every :class:`OSError` names ``path`` (``exc.filename``:
    the final name, not the temporary one), a full disk included. When this thread claimed ``path``
    or its folder (:func:`gonio.data.claim.claim_output`), the claim is checked before the rename.
    This is the one atomic file writer of the toolkit's outputs.
    """
    path = Path(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as handle:
            if callable(data):
                data(handle)
            else:
                handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        claim.verify(path)
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass


def write_files_together(out_dir: str | os.PathLike, files: Mapping[str, bytes]) -> list[Path]:
    """Write ``files`` (path relative to ``out_dir`` -> bytes) into ``out_dir`` together; return their paths.

    Every file is written and fsynced into a hidden folder ``out_dir/.writing-XXXXXXXX.tmp/`` first and
    only then renamed into place, so a write that fails (a full disk) leaves ``out_dir`` as it was:
    the staged files are removed, as are the folders this call created; files already in ``out_dir``
    are replaced only once every new one is on disk. The `OSError` raised names the file
    (its final path) whose write failed.
    """
    out = Path(out_dir)
    rel = {Path(name): data for name, data in files.items()}
    for r in rel:
        if r.is_absolute() or ".." in r.parts or not r.parts:
            raise ValueError(f"{r}: not a file name inside {out}")
    created: list[Path] = []
    for d in [out, *sorted({out / r.parent for r in rel if r.parent != Path(".")})]:
        missing = [a for a in [d, *d.parents] if not a.exists()][::-1]
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            _remove_empty(created + missing)
            raise OSError(exc.errno, exc.strerror, str(d)) from None
        created += missing
    umask = os.umask(0)
    os.umask(umask)
    stage = None
    try:
        stage = Path(tempfile.mkdtemp(prefix=".writing-", suffix=".tmp", dir=out))
        for r, data in rel.items():
            tmp = stage / r
            try:
                tmp.parent.mkdir(parents=True, exist_ok=True)
                with open(tmp, "wb") as handle:
                    handle.write(data)
                    handle.flush()
                    os.fsync(handle.fileno())
                os.chmod(tmp, 0o666 & ~umask)
            except OSError as exc:
                raise OSError(exc.errno, exc.strerror, str(out / r)) from None
        claim.verify(out)
        for r in rel:
            os.replace(stage / r, out / r)
    except BaseException:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
        _remove_empty(created)
        raise
    shutil.rmtree(stage, ignore_errors=True)
    fsync_dir(out)
    return [out / r for r in rel]


def _remove_empty(folders: list[Path]) -> None:
    """Remove the ``folders`` (deepest first) that are empty: those a failed write created."""
    for d in sorted(set(folders), key=lambda p: len(p.parts), reverse=True):
        try:
            d.rmdir()
        except OSError:
            pass


#: Names of `atomic_write`'s temporary files for a dataset's two files: ``mkstemp`` with
#: prefix ``.NAME.`` and suffix ``.tmp`` puts 8 characters of ``[a-z0-9_]`` between them.
_TEMP_NAME = re.compile(r"\.(?:radiance\.csv|meta\.json)\.[a-z0-9_]{8}\.tmp")


def remove_stale_temp_files(out_dir: str | os.PathLike) -> list[Path]:
    """Remove temporary files that `write_dataset` left in ``out_dir`` (a killed write).

    Only regular files whose names match the writer's own pattern
    (``.radiance.csv.XXXXXXXX.tmp``, ``.meta.json.XXXXXXXX.tmp``) are removed; anything else is
    left alone. The caller must be the only writer of ``out_dir`` (the engine holds the run
    directory's lock). Returns the removed paths.
    """
    out = Path(out_dir)
    removed: list[Path] = []
    try:
        entries = list(os.scandir(out))
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for entry in entries:
        if _TEMP_NAME.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            try:
                os.unlink(entry.path)
            except FileNotFoundError:
                continue
            removed.append(Path(entry.path))
    return removed


def fsync_dir(path: Path) -> None:
    """Flush the folder ``path``'s entries to disk (renames into it survive a crash); errors are ignored."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

