"""What listens to the engine: the journal, the progress display and the dataset writer.

bluesky habit: the engine (:class:`gonio.acquisition.engine.Engine`) emits documents
``(name, doc)`` and knows nothing of who stores or shows them. The names are the journal's record
types (``start``, ``calibration``, ``point``, ``event``: :data:`RECORD_TYPES`) and two that are not
journaled: ``todo`` (``{"total", "done"}``, when the points start) and ``stop`` (``{"status",
"complete", "measured", "records", "firmware"}``, after the instrument was left safe and the
journal closed; ``records`` is the journal as it is on disk).

- :class:`JournalWriter`: storage; appends and fsyncs every record (the checkpoint) and is what
  a session resumes from (:meth:`JournalWriter.open`);
- :class:`ProgressReporter`: a tqdm bar with ETA on a terminal, log lines otherwise;
- :class:`DatasetWriter`: on ``stop``, reduces the journal to the dataset
  (:func:`gonio.acquisition.reduce.dataset_from_journal`) and writes it atomically;
- :class:`gonio.acquisition.live.LiveView` (``--live``): the curves, position, retries and faults
  for a local web page, after the dataset writer.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import Protocol

from gonio.acquisition.calibration import WhiteStandard
from gonio.acquisition.journal import RECORD_TYPES, Journal, JournalContent
from gonio.acquisition.plan import Plan
from gonio.acquisition.reduce import dataset_from_journal
from gonio.data import write_dataset

__all__ = ["Subscriber", "JournalWriter", "ProgressReporter", "DatasetWriter", "RECORD_TYPES"]

log = logging.getLogger("gonio.acquisition.engine")


class Subscriber(Protocol):
    """A callable receiving every document the engine emits."""

    def __call__(self, name: str, doc: dict) -> None:
        """Receive one document ``doc`` of type ``name`` from the engine."""
        ...


class JournalWriter:
    """Journal every record to ``path`` (append, flush, fsync before returning)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.journal: Journal | None = None

    def open(self) -> JournalContent:
        """Open for appending; returns what the journal already holds (a torn last line cut)."""
        self.journal, content = Journal.open(self.path)
        return content

    def close(self) -> None:
        """Close the journal (idempotent)."""
        if self.journal is not None:
            self.journal.close()

    def __call__(self, name: str, doc: dict) -> None:
        """Append a record to the journal (other documents are ignored)."""
        if name in RECORD_TYPES:
            assert self.journal is not None, "JournalWriter.open() first"
            self.journal.append(doc)
        elif name == "stop":
            self.close()


class ProgressReporter:
    """A progress bar (tqdm, on stderr) or, without a terminal, one log line per point with ETA."""

    def __init__(self, label: str, bar: bool | None = None):
        self.label = label
        self.show_bar = sys.stderr.isatty() if bar is None else bar
        self.bar = None
        self.total = self.done = self.first = self.k = 0
        self.n_todo = 0
        self.t0 = 0.0

    def __call__(self, name: str, doc: dict) -> None:
        """Advance the progress display on the engine's documents."""
        if name == "todo":
            self.total, self.done = int(doc["total"]), int(doc["done"])
            self.n_todo, self.k = self.total - self.done, 0
            self.t0 = time.monotonic()
            if self.show_bar:
                from tqdm import tqdm
                self.bar = tqdm(total=self.total, initial=self.done, unit="point", desc=self.label,
                                file=sys.stderr, dynamic_ncols=True)
        elif name == "point":
            self.k += 1
            self.done += 1
            if self.bar is not None:
                self.bar.update(1)
                return
            eta = (time.monotonic() - self.t0) / self.k * max(self.n_todo - self.k, 0)
            source, detector, plane, rotation = doc["axes_deg"]
            log.info("point %d/%d theta_i=%g s=%g plane=%g rot=%g (ETA %.0f s)", self.done,
                     self.total, source, detector, plane, rotation, eta)
        elif name == "stop" and self.bar is not None:
            self.bar.close()
            self.bar = None


class DatasetWriter:
    """On ``stop``, write the dataset reduced from the journal into ``out_dir`` (atomically).

    ``path`` is the dataset's folder afterwards, or None when nothing was measured.
    """

    def __init__(self, out_dir: str | Path, plan: Plan, standard: WhiteStandard, *,
                 seed: int | None = None, links: dict | None = None, created: str | None = None):
        self.out_dir = Path(out_dir)
        self.plan, self.standard = plan, standard
        self.seed, self.links, self.created = seed, dict(links or {}), created
        self.path: Path | None = None

    def __call__(self, name: str, doc: dict) -> None:
        """On the engine's stop with points measured, write the dataset reduced from the journal."""
        if name != "stop" or not doc["measured"]:
            return
        ds = dataset_from_journal(doc["records"], self.plan, self.standard, seed=self.seed,
                                  links=self.links, firmware=doc["firmware"],
                                  complete=doc["complete"], created=self.created)
        write_dataset(ds, self.out_dir)
        self.path = self.out_dir
