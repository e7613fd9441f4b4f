"""``gonio demo``: the embedded mock (red cotton) measured with a plan, into a folder of its own.

:func:`run_demo` starts the mock, opens both links and runs the session. The output folder is
replaced only where a previous demo wrote it: a demo marks its folder with
:data:`gonio.acquisition.rundir.DEMO_MARKER` (JSON: ``written_by`` and, once
the run ended, ``journal_start``: the SHA-256 of its journal's first line, the start record).
The next demo clears the run files (:data:`gonio.acquisition.rundir.RUN_DIR_FILES`) of a folder so marked
whose journal is still that demo's (or that a killed demo left before the hash was written);
a folder holding another run's journal or dataset is refused and left untouched.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

from gonio.acquisition.engine import RunResult
from gonio.acquisition.plan import Plan
from gonio.acquisition.rundir import DEMO_MARKER, JOURNAL_NAME, RUN_DIR_FILES
from gonio.acquisition.session import run_session
from gonio.data import atomic_write
from gonio.data.outputs import check_output
from gonio.instrument.probe import open_links

__all__ = ["run_demo", "replace_previous_demo", "is_previous_demo", "mark_demo"]

log = logging.getLogger(__name__)


def run_demo(out: str | Path, plan: Plan, *, seed: int = 0, timeout_s: float = 1.0,
             progress: bool | None = None, force: bool = False,
             wait_timeout_s: float | None = None) -> tuple[RunResult, float]:
    """Measure ``plan`` on the embedded red-cotton mock into ``out``.

    Returns the session's result and the wall time in seconds (mock start-up included).
    Raises :class:`gonio.data.outputs.OutputRefused` (nothing changed) when ``out``
    holds run files that a demo did not write (with ``force``: a dataset without a journal is
    replaced; a run folder never is, :mod:`gonio.data.outputs`).
    """
    from gonio.mock import MockInstrument

    out = Path(out)
    replace_previous_demo(out, force=force)
    t0 = time.monotonic()
    with MockInstrument(sample="red-cotton", modbus="tcp", serial="pty", speed="fast",
                        seed=seed) as mock:
        modbus, serial_link = open_links(mock.modbus_url, mock.serial_url, timeout_s)
        result = run_session(plan, modbus, serial_link, out, seed=seed, progress=progress,
                             force=force, writer="gonio demo", wait_timeout_s=wait_timeout_s)
    mark_demo(out, done=True)
    return result, time.monotonic() - t0


def is_previous_demo(out: Path) -> bool:
    """True when ``out`` was marked by a demo whose journal is still there unchanged (or that
    was killed before it wrote the journal's hash)."""
    try:
        marker = json.loads((out / DEMO_MARKER).read_text())
        return marker.get("written_by") == "gonio demo" and marker.get("journal_start") in (
            None, _journal_start_sha256(out))
    except (OSError, ValueError, AttributeError):
        return False


def replace_previous_demo(out: str | Path, *, force: bool = False) -> None:
    """Clear a previous demo's run files in ``out`` and mark it for this demo.

    Anything else follows :func:`gonio.data.outputs.check_output` (``OutputRefused``, nothing
    changed): another run's folder is refused, another dataset without ``force`` too.
    """
    out = Path(out)
    present = [n for n in RUN_DIR_FILES if n != DEMO_MARKER and (out / n).exists()]
    if present and is_previous_demo(out):
        for name in present:
            log.info("demo: replacing the previous demo's %s in %s", name, out)
            (out / name).unlink()
    else:
        check_output(out, "run", writer="gonio demo", force=force)
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
