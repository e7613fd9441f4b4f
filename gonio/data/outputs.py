"""The one rule for every ``gonio`` command that writes: what it may replace.

Every command that writes (``acquire``, ``replay``, ``demo``: a run folder; ``truth``,
``import``: a dataset folder; ``bench-driver``: a file) calls :func:`check_output` before it
starts, and the sessions call it again once they hold the run folder's lock. The rule:

1. **A run folder is never replaced.** A folder holding a non-empty journal
   (:data:`JOURNAL_NAME`) belongs to that run: only ``gonio acquire --resume`` continues it.
   Every other writer refuses it, ``--force`` included (its dataset is rebuilt from the journal,
   its journal is the only copy of the measured points). A file output that is one of a run
   folder's own files (``journal.jsonl``, ``radiance.csv``, ``meta.json``, the demo marker) is
   refused the same way.
2. **A previous output of the same command is replaced** (re-running a command is not a
   surprise): a dataset whose ``meta.json`` says ``"written_by": WRITER``, a file output
   whose JSON says so, a folder that ``gonio demo`` marked (:mod:`gonio.demo`).
3. **Anything else is replaced only when asked** (``--force``): a ``radiance.csv`` or
   ``meta.json`` that another command or the user wrote, an existing file.
4. A folder where a file is expected (or a file where a folder is) is refused.

The same rule serves every writer of the toolkit, ``simulate`` and ``compare`` and the Python
interface included: :func:`refuse_existing` is rule 3 for an output of no recognised kind (an
existing file, or a folder holding anything besides hidden files, is replaced only when asked),
:func:`prepare_folder` the whole check of a folder output whose own previous output a writer
recognises (``simulate fabric``, ``fiber``, ``fit``, ``bench``). ``option`` and ``ask`` word the
messages for the caller: ``--out`` and ``--force`` on a command line, ``out`` and ``force=True``
in Python.

Refusals raise :class:`OutputRefused` (one line naming the option, the path, why and what to do;
the command line prints it and exits 2), before anything is changed. The lesson is the one
``simulate fabric`` and ``compare report`` follow (their own previous output is replaced,
anything else refused), extended by the run folder, which nothing replaces.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Literal

from gonio.data.dataset import CSV_NAME, META_NAME

__all__ = ["JOURNAL_NAME", "RUN_FILES", "WRITTEN_BY", "OutputRefused", "check_output",
           "is_run_folder", "written_by", "occupied", "refuse_existing", "refuse_run_folder", "prepare_folder"]

#: The journal of an acquisition: a folder holding a non-empty one is a run folder.
JOURNAL_NAME = "journal.jsonl"
#: Files of a run folder that nothing but its own session writes (with the demo's marker).
RUN_FILES = (JOURNAL_NAME, CSV_NAME, META_NAME, ".gonio-demo.json")
#: Key of ``meta.json`` (and of a JSON file output) naming the command that wrote it.
WRITTEN_BY = "written_by"

OutputKind = Literal["run", "dataset", "file"]


class OutputRefused(ValueError):
    """An output that the rule of :mod:`gonio.data.outputs` does not let a command replace."""


def is_run_folder(path: str | os.PathLike) -> bool:
    """True when ``path`` is a folder holding a non-empty journal."""
    try:
        return (Path(path) / JOURNAL_NAME).stat().st_size > 0
    except OSError:
        return False


def written_by(path: str | os.PathLike) -> str | None:
    """The ``written_by`` of a JSON file (a dataset's ``meta.json``, a report), else None."""
    try:
        with open(path, "rb") as fh:
            data = json.loads(fh.read(1 << 20))
    except (OSError, ValueError, RecursionError):
        return None
    value = data.get(WRITTEN_BY) if isinstance(data, dict) else None
    return value if isinstance(value, str) else None


def check_output(path: str | os.PathLike, kind: OutputKind, *, writer: str, force: bool = False,
                 resume: bool = False, option: str = "--out",
                 previous: Callable[[Path], bool] | None = None) -> None:
    """Raise :class:`OutputRefused` unless ``writer`` may write ``path`` (see the module rule).

    ``kind``: ``"run"`` (a run folder: journal and dataset), ``"dataset"`` (a dataset folder) or
    ``"file"``. ``resume``: continue the run folder's own journal (``kind="run"`` only).
    ``previous(path)``: True when ``path`` holds a previous output of ``writer`` recognised
    otherwise than by ``written_by`` (the demo's marker).
    """
    p = Path(path)
    where = f"{option} {p}"
    if kind == "file":
        _check_file(p, where, writer, force)
        return
    if p.exists() and not p.is_dir():
        raise OutputRefused(f"{where}: is a file, not a folder; give a folder")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputRefused(f"{where}: is below {parent}, a file; give a folder")
            break
    if not p.is_dir():
        return
    ours = previous is not None and previous(p)
    if is_run_folder(p):
        if kind == "run" and (resume or ours):
            return
        if kind == "run":
            raise OutputRefused(f"{where}: a journal from an earlier run is there; continue it "
                                "with --resume or choose a new --out (a run folder is never "
                                "replaced, not even with --force)")
        refuse_run_folder(p, option=option)
    present = [n for n in (CSV_NAME, META_NAME) if (p / n).exists()]
    if not present or force or ours or written_by(p / META_NAME) == writer:
        return
    raise OutputRefused(f"{where}: holds {' and '.join(present)} that `{writer}` did not write; "
                        "nothing was changed: choose another --out, or add --force to "
                        "replace them")


def _check_file(p: Path, where: str, writer: str, force: bool) -> None:
    if p.is_dir():
        raise OutputRefused(f"{where}: is a folder; give a file name")
    if any(q.name in RUN_FILES and is_run_folder(q.parent) for q in (p, p.resolve())):
        raise OutputRefused(f"{where}: is a file of the run folder {p.parent} (it holds "
                            f"{JOURNAL_NAME}); a run folder's files are never replaced, not even "
                            "with --force: choose another file")
    if p.exists() or p.is_symlink():
        if force or written_by(p) == writer:
            return
        raise OutputRefused(f"{where}: the file exists and `{writer}` did not write it; nothing "
                            "was changed: choose another file, or add --force to replace it")


def refuse_run_folder(path: str | os.PathLike, *, option: str = "--out", ask: str = "--force") -> None:
    """Raise :class:`OutputRefused` when ``path`` is a run folder (rule 1: never replaced, ``force`` or not).

    Parameters
    ----------
    path : str or path-like
        The output folder.
    option : str
        How the message names the output: ``--out`` on a command line, ``path`` in Python.
    ask : str
        How the message names ``force``.
    """
    if is_run_folder(path):
        name = option if option.startswith("-") else "path"
        raise OutputRefused(f"{option} {Path(path)}: is a run folder (it holds {JOURNAL_NAME}; its dataset is "
                            f"rebuilt from that journal): choose another {name} (a run folder is never replaced, "
                            f"not even with {ask})")


def occupied(path: str | os.PathLike) -> bool:
    """True when ``path`` is a file (or a link), or a folder holding anything besides hidden files.

    Hidden files (a claim's lock, a killed write's temporary file) do not make a folder an output.

    Raises
    ------
    OSError
        The folder cannot be read.
    """
    p = Path(path)
    if p.is_dir():
        return any(not e.name.startswith(".") for e in p.iterdir())
    return p.exists() or p.is_symlink()


def refuse_existing(path: str | os.PathLike, *, force: bool, option: str = "--out", ask: str = "--force",
                    file: bool = False) -> None:
    """Raise :class:`OutputRefused` for an existing output unless ``force`` (rule 3).

    Parameters
    ----------
    path : str or path-like
        The output: a file, or a folder (empty or missing: accepted).
    force : bool
        Replace an existing output.
    option : str
        How the message names the output: ``--out`` on a command line, ``out`` in Python.
    ask : str
        What the message tells the user to pass: ``--force``, ``force=True``.
    file : bool
        A file output: a folder there is refused, ``force`` or not.
    """
    p = Path(path)
    where = f"{option} {p}"
    if file and p.is_dir():
        raise OutputRefused(f"{where}: is a folder; give a file name")
    try:
        if force or not occupied(p):
            return
    except OSError as exc:
        raise OutputRefused(f"{where}: cannot read the folder ({exc.strerror})") from None
    if p.is_dir():
        raise OutputRefused(f"{where}: the folder is not empty; pass {ask} to replace its output, "
                            "or choose a new folder")
    raise OutputRefused(f"{where}: exists; pass {ask} to replace it, or choose a new name")


def prepare_folder(path: str | os.PathLike, *, writer: str, force: bool = False, resume: bool = False,
                   previous: Callable[[Path], bool] | None = None, exclusive: bool = False,
                   option: str = "--out") -> None:
    """Check a folder output and create it, or raise :class:`OutputRefused` (nothing changed).

    A file there is refused. A folder holding anything is accepted when ``resume`` (the writer
    continues its own run there); when it holds a previous output of ``writer`` (``previous``),
    only with ``force``; anything else only with ``force``, and never when ``exclusive`` (the new
    output replaces the whole folder, so what it holds would be lost).

    Parameters
    ----------
    path : str or path-like
        The folder.
    writer : str
        The command that writes it (``simulate fabric``), named in the messages.
    force : bool
        Replace what the folder holds.
    resume : bool
        Continue the writer's own run in the folder.
    previous : callable, optional
        ``previous(path)``: True when the folder holds a previous output of ``writer``.
    exclusive : bool
        A folder holding anything but a previous output is refused, ``force`` or not.
    option : str
        How the messages name the folder.
    """
    p = Path(path)
    where = f"{option} {p}"
    if p.exists() and not p.is_dir():
        raise OutputRefused(f"{where}: exists and is not a directory; choose a directory path")
    try:
        full = occupied(p)
    except OSError as exc:
        raise OutputRefused(f"{where}: cannot read the directory ({exc.strerror})") from None
    if full and not resume:
        if previous is not None and previous(p):
            if not force:
                raise OutputRefused(f"{where}: holds a previous `{writer}` output; pass --force to replace it, "
                                    "or choose a new folder")
        elif exclusive:
            raise OutputRefused(f"{where}: directory is not empty and does not hold a previous `{writer}` "
                                "output; refusing to overwrite it (choose a new or empty directory)")
        else:
            refuse_existing(p, force=force, option=option)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputRefused(f"{where}: cannot create the directory ({exc.strerror})") from None
    if not os.access(p, os.W_OK):
        raise OutputRefused(f"{where}: directory is not writable")
