"""``gonio demo``: the embedded mock measured with a plan, into a folder of its own.

:func:`run_demo` starts the mock with a virtual sample (``sample``: the meaning of ``gonio mock
--sample``: ``lambert:RHO``, ``red-cotton`` -- the default, the analytic stand-in --, a dataset
directory or an RGL ``.bsdf`` file such as the real green felt
``fixtures/real/acrylic_felt_green_rgb.bsdf``), opens both links and runs the session on the real
protocol endpoints (Modbus TCP on loopback, the head on a pseudo-terminal).

What was measured is written down: the dataset's ``sample`` (the plan's ``[sample]``) gets a
``mock_sample`` entry, the mock sample's own description
(:meth:`gonio.mock.samples.Sample.describe`: the analytic model, or the file, its description and
SHA-256), so that a report can say that the measurement is the mock's and of what
(:mod:`compare.report.samples`). A real instrument does not know its sample; the demo does.
When the plan's ``[sample]`` names another sample than the mock holds (the default plan
``red-cotton`` with ``sample="FILE.bsdf"``), ``name_from_sample`` replaces the plan's name and
material by the mock sample's (the CLI does this when ``--plan`` is not given). The output folder is
replaced only where a previous demo wrote it: a demo marks its folder with
:data:`gonio.acquisition.rundir.DEMO_MARKER` (JSON: ``written_by`` and, once
the run ended, ``journal_start``: the SHA-256 of its journal's first line, the start record).
The next demo clears the run files (:data:`gonio.acquisition.rundir.RUN_DIR_FILES`) of a folder so marked
whose journal is still that demo's (or that a killed demo left before the hash was written);
a folder holding another run's journal or dataset is refused and left untouched.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import time
from collections.abc import Sequence
from pathlib import Path

from gonio.acquisition.engine import RunResult
from gonio.acquisition.plan import Plan
from gonio.acquisition.rundir import DEMO_MARKER, JOURNAL_NAME, RUN_DIR_FILES
from gonio.acquisition.session import run_session
from gonio.acquisition.subscribers import Subscriber
from gonio.data import atomic_write
from gonio.data.outputs import check_output
from gonio.instrument.probe import open_links

__all__ = ["run_demo", "replace_previous_demo", "is_previous_demo", "mark_demo", "demo_sample_meta"]

log = logging.getLogger(__name__)


def run_demo(out: str | Path, plan: Plan, *, seed: int = 0, timeout_s: float = 1.0,
             progress: bool | None = None, force: bool = False,
             wait_timeout_s: float | None = None, sample: str = "red-cotton",
             name_from_sample: bool = False, subscribers: Sequence[Subscriber] = ()) -> tuple[RunResult, float]:
    """Measure ``plan`` on the embedded mock holding ``sample`` into ``out``.

    Returns the session's result and the wall time in seconds (mock start-up included).
    ``subscribers`` are handed to :func:`gonio.acquisition.session.run_session` (the live view).
    Raises :class:`gonio.mock.samples.SampleError` for a sample the mock cannot hold (before
    anything is written), :class:`gonio.data.outputs.OutputRefused` (nothing changed) when ``out``
    holds run files that a demo did not write (with ``force``: a dataset without a journal is
    replaced; a run folder never is, :mod:`gonio.data.outputs`).
    """
    from gonio.mock import MockInstrument
    from gonio.mock.samples import make_sample

    out = Path(out)
    truth = make_sample(sample)        # a bad sample: one error before the folder is touched
    sample_meta = demo_sample_meta(plan.sample, truth, name_from_sample=name_from_sample)
    measured_incidences = truth.describe().get("measured_incidence_deg")
    if measured_incidences is not None:     # a file: which of the plan's incidences it measured, which it interpolates
        from gonio.data.formats.rgl_bsdf import incidence_meta

        sample_meta["incidences"] = incidence_meta(measured_incidences, plan.incidence_deg, Path(sample).name)
    plan = dataclasses.replace(plan, sample=sample_meta)
    replace_previous_demo(out, force=force)
    t0 = time.monotonic()
    with MockInstrument(sample=sample, modbus="tcp", serial="pty", speed="fast",
                        seed=seed) as mock:
        modbus, serial_link = open_links(*mock.urls(), timeout_s)
        result = run_session(plan, modbus, serial_link, out, seed=seed, progress=progress,
                             force=force, writer="gonio demo", wait_timeout_s=wait_timeout_s,
                             subscribers=subscribers)
    mark_demo(out, done=True)
    return result, time.monotonic() - t0


def demo_sample_meta(plan_sample: dict, truth, *, name_from_sample: bool = False) -> dict:
    """The dataset's ``sample``: the plan's, with ``mock_sample`` (``truth.describe()``) added.

    With ``name_from_sample`` the name and material are the mock sample's.

    >>> from gonio.mock.samples import LambertSample
    >>> demo_sample_meta({"name": "red cotton"}, LambertSample(0.5), name_from_sample=True)["name"]
    'lambert:0.5'
    """
    described = truth.describe()
    meta = dict(plan_sample)
    meta.pop("incidences", None)
    if name_from_sample:
        meta["name"] = str(described.get("description") or truth.name)
        meta["material"] = f"the mock's virtual sample {truth.name} ({described.get('model')})"
    meta["mock_sample"] = described
    return meta


def is_previous_demo(out: Path) -> bool:
    """True when ``out`` was marked by a demo whose journal is still there unchanged.

    Or by a demo killed before it wrote the journal's hash.
    """
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
