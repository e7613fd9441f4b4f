"""``gonio demo``'s output folder: replace only what a previous demo wrote.

A demo marks its folder with :data:`gonio.engine.DEMO_MARKER` (JSON: ``written_by`` and, once
the run ended, ``journal_start``: the SHA-256 of its journal's first line, the start record).
The next demo clears the run files (:data:`gonio.engine.RUN_DIR_FILES`) of a folder so marked
whose journal is still that demo's (or that a killed demo left before the hash was written);
a folder holding another run's journal or dataset is refused and left untouched.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

from gonio.data import atomic_write
from gonio.engine import DEMO_MARKER, JOURNAL_NAME, RUN_DIR_FILES, AcquisitionError

__all__ = ["replace_previous_demo", "mark_demo"]

log = logging.getLogger(__name__)


def replace_previous_demo(out: str | Path) -> None:
    """Clear a previous demo's run files in ``out`` and mark it for this demo.

    Raises :class:`gonio.engine.AcquisitionError` (nothing changed) when ``out`` is not a
    directory or holds run files that a demo did not write.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise AcquisitionError(f"--out {out}: not a directory")
    present = [n for n in RUN_DIR_FILES if n != DEMO_MARKER and (out / n).exists()]
    if present:
        try:
            marker = json.loads((out / DEMO_MARKER).read_text())
            ours = marker.get("written_by") == "gonio demo" and marker.get("journal_start") in (
                None, _journal_start_sha256(out))
        except (OSError, ValueError, AttributeError):
            ours = False
        if not ours:
            raise AcquisitionError(f"--out {out}: holds {', '.join(present)} that `gonio demo` "
                                   "did not write; nothing was changed: choose another --out")
        for name in present:
            log.info("demo: replacing the previous demo's %s in %s", name, out)
            (out / name).unlink()
    mark_demo(out, done=False)


def mark_demo(out: str | Path, *, done: bool) -> None:
    """Write the demo marker (``done``: with the hash of the journal's start record)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    marker = {"written_by": "gonio demo",
              "journal_start": _journal_start_sha256(out) if done else None}
    atomic_write(out / DEMO_MARKER, (json.dumps(marker) + "\n").encode())


def _journal_start_sha256(out: Path) -> str | None:
    try:
        with open(out / JOURNAL_NAME, "rb") as fh:
            return hashlib.sha256(fh.readline()).hexdigest()
    except FileNotFoundError:
        return None
