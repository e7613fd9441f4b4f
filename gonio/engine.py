"""The acquisition engine: executes a plan on the devices, checkpointing every point.

bluesky habit: the plan (:mod:`gonio.plan`) is data; this engine executes it and emits records
to storage (:mod:`gonio.journal`): ``start``, ``calibration``, one ``point`` per geometry (every
wavelength), ``event`` records (resume, safe stop, session end with its retry counts). The dataset
(:func:`gonio.data.write_dataset`, kind ``"measured"``) is computed from the journal alone, so
a resumed run and an uninterrupted run with the same mock seed write identical ``radiance.csv``.

Sequence
--------
0. refuse a plan that ``gonio check-plan`` refuses (:meth:`gonio.plan.PlanCheck.refusal`), and
   on ``--resume`` a journal holding a point that is not a measurable point of the plan;
1. connect (checksum mode on, ``*IDN?``, firmware), refuse an open interlock or a pressed
   emergency stop, lamp on, shutter closed, sample slot, home;
2. calibration at the reference geometry (default 0/45): dark ``D`` at every step of the
   auto-ranging ladder (shutter closed), then the white standard ``S_ref`` per wavelength
   (auto-ranged) with the reference slot in the beam - or, on ``--resume``, the journal's last
   calibration when still valid (a valid calibration, same plan and standard files, same
   instrument, younger than ``calibration_max_age_min``; otherwise it is measured again and the
   reason logged). A calibration is valid when the white standard stands above the dark by
   :data:`gonio.calibration.MIN_REFERENCE_Z` standard errors at every wavelength
   (:func:`gonio.calibration.calibration_problem`); an invalid one is never journaled (a
   ``calibration_invalid`` event says why and the session stops safely, exit 1);
3. every measurable point in motion order: move (axis commands ordered around the beam-block
   zone; after a following error or a lost homing every axis is stopped and brought to rest,
   the recoverable faults are reset and the axes re-homed, and the move repeated),
   settle, shutter open, and per wavelength auto-range from the same initial integration time
   and gain (:meth:`gonio.plan.AcquisitionSettings.ladder`; a saturated reading is never
   stored), then append the point to the journal and fsync;
4. always: shutter closed and drives stopped (``shutdown``), a ``session_end`` event with the
   retry counts, and the dataset written atomically from the journal (what was measured).

Retry counts survive a killed session: every ``calibration`` and ``point`` record carries the
session's cumulative retry counter (``retries``) at its checkpoint. The meta's ``retries`` sum,
over the sessions (a ``start`` record or a ``resume`` event opens one), each session's last
snapshot - its ``session_end`` counts when it ended, else those of its last checkpoint (retries
spent on a point that was never journaled are lost with that point). ``sessions`` counts every
session, killed ones included. Journals written before the snapshots existed sum their
``session_end`` events as before.

The radiance factor and its uncertainty come from :func:`gonio.calibration.radiance_factor`.

Exit status (:class:`RunResult.exit_code`): 0 complete; 1 stopped safely by an instrument
fault that retries did not clear (the measured points are kept; continue with ``--resume``);
any other exception (a bug, a full disk) also stops safely and keeps the points, then propagates;
2 usage or input error (plan, journal of another plan, unreachable device); 130 interrupted by
SIGINT or SIGTERM (the measured points are kept).
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import re
import sys
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from gonio import protocol
from gonio.calibration import (WhiteStandard, calibration_problem, load_white_standard,
                               radiance_factor)
from gonio.data import (CSV_NAME, META_NAME, make_dataset, new_meta, remove_stale_temp_files,
                           write_dataset)
from gonio.devices import (RECOVERABLE_FAULTS, AxisFaultError, DeviceError, MotionController,
                           PhotometerHead, RetryPolicy)
from gonio.journal import (Journal, JournalContent, JournalError, check_consistency,
                           read_journal)
from gonio.plan import Plan, PlanPoint

__all__ = ["Engine", "RunResult", "AcquisitionError", "Interrupted", "EXIT_OK", "EXIT_STOPPED",
           "EXIT_USAGE", "EXIT_INTERRUPTED", "dataset_from_journal", "retry_totals", "JOURNAL_NAME",
           "DEMO_MARKER", "RUN_DIR_FILES", "owned_by_run", "usable_points"]

log = logging.getLogger(__name__)

EXIT_OK = 0
EXIT_STOPPED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
JOURNAL_NAME = "journal.jsonl"
#: Marker of a run directory written by ``gonio demo`` (what it may replace on the next demo).
DEMO_MARKER = ".gonio-demo.json"
#: Files of a run directory that a session owns (besides the dataset writer's temporary files).
RUN_DIR_FILES = (JOURNAL_NAME, CSV_NAME, META_NAME, DEMO_MARKER)
_REHOME_ATTEMPTS = 3


class AcquisitionError(ValueError):
    """A user error that prevents the run (bad journal, plan mismatch): exit status 2."""


class Interrupted(Exception):
    """Raised by a signal handler (SIGTERM) to stop the run like Ctrl-C."""


@dataclass
class RunResult:
    """Outcome of :meth:`Engine.run`."""

    status: str                      # "complete" | "stopped" | "interrupted"
    exit_code: int
    points_measured: int
    points_total: int
    dataset_path: Path | None
    message: str = ""
    retries: dict = field(default_factory=dict)


def owned_by_run(run_dir: str | os.PathLike, path: str | os.PathLike) -> bool:
    """True when ``path`` is (or would be) one of the files a session owns in ``run_dir``
    (:data:`RUN_DIR_FILES`, the dataset writer's temporary files), symlinks resolved."""
    p, d = Path(path).resolve(), Path(run_dir).resolve()
    return p.parent == d and (p.name in RUN_DIR_FILES
                              or bool(_DATASET_TEMP.fullmatch(p.name)))


_DATASET_TEMP = re.compile(r"\.(?:radiance\.csv|meta\.json)\..*\.tmp")


def _versions() -> dict:
    out = {}
    for dist in ("fabric-optics", "pymodbus", "pyserial", "numpy"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).isoformat(timespec="seconds")


class Engine:
    """Execute ``plan`` with ``head`` and ``motion``, journaling into ``out_dir``.

    Parameters
    ----------
    plan : the validated plan.
    head, motion : the devices (sharing ``retry``).
    retry : the retry policy whose counter goes into the run's meta.
    out_dir : run directory (``journal.jsonl``, ``radiance.csv``, ``meta.json``); the caller
        holds its lock (:class:`gonio.journal.RunDirLock`, taken by :func:`gonio.cli.run_session`)
        for the whole session.
    resume : continue from the journal instead of refusing an existing one.
    seed : the mock's seed, recorded in the meta (None for a real instrument).
    links : URLs of the two links, recorded in the meta.
    progress : show a tqdm bar (default: when stderr is a terminal).
    clock : wall clock (seconds since the epoch), injectable for replay.
    created : the dataset's ``created`` stamp (default: the journal's start time).
    owner_token : this session's claim on the instrument (written into the controller, checked
        at every point; see :meth:`gonio.devices.MotionController.claim`); 0 claims nothing.
    """

    def __init__(self, plan: Plan, head: PhotometerHead, motion: MotionController,
                 retry: RetryPolicy, out_dir: str | Path, *, resume: bool = False,
                 seed: int | None = None, links: dict | None = None, progress: bool | None = None,
                 clock: Callable[[], float] = time.time, created: str | None = None,
                 owner_token: int = 0):
        self.plan, self.head, self.motion, self.retry = plan, head, motion, retry
        self.out_dir = Path(out_dir)
        self.resume = resume
        self.seed = seed
        self.links = dict(links or {})
        self.progress = sys.stderr.isatty() if progress is None else progress
        self.clock = clock
        self.created = created
        self.owner_token = int(owner_token)
        self.settings = plan.acquisition
        self.ladder = self.settings.ladder()
        self.check = plan.check()
        refused = self.check.refusal(plan.name)
        if refused is not None:     # the validation of `gonio check-plan`: never drop points
            raise AcquisitionError(refused)
        base = plan.path.parent if plan.path else None
        self.standard: WhiteStandard = load_white_standard(plan.white_standard, base=base)
        self.standard.at(plan.wavelengths_nm)   # refuse a plan outside the table now
        self.journal: Journal | None = None
        self.identity: str = ""
        self.firmware: str = ""

    # --- helpers ---------------------------------------------------------------------------
    def _append(self, record: dict) -> None:
        assert self.journal is not None
        self.journal.append(record)
        self.records.append(record)

    def _retry_snapshot(self) -> dict[str, int]:
        """This session's cumulative retry counts (non-zero kinds, sorted)."""
        return {k: int(v) for k, v in sorted(self.retry.counts.items()) if v}

    def _reference_axes(self) -> tuple[float, float, float, float]:
        ti, to = self.plan.reference_deg
        return (ti, to, 0.0, 0.0)

    def _move(self, axes_deg) -> None:
        v = self.settings.velocity_deg_s
        attempts = max(_REHOME_ATTEMPTS, self.retry.attempts)
        for attempt in range(attempts + 1):
            try:
                self.motion.move_to(axes_deg, v)
                return
            except AxisFaultError as exc:
                if exc.code not in RECOVERABLE_FAULTS or attempt == attempts:
                    raise
                self.retry.count("axis_fault")
                log.warning("%s; stopping, resetting the fault and re-homing", exc)
                # every axis at rest first (another axis may still be moving and fault after
                # the reset), then reset what is recoverable, then home
                self.motion.clear_faults("re-home")
                self.motion.home()

    def _autorange(self, wavelength_nm: float, *, shutter_open: bool | None = None) -> dict | None:
        s = self.settings
        for step, (itime, gain) in enumerate(self.ladder):
            m = self.head.measure(wavelength_nm, itime, gain, s.readings,
                                  repetitions=s.repetitions, shutter_open=shutter_open)
            if not m.saturated:
                return {"wavelength_nm": float(wavelength_nm), "itime_ms": int(itime),
                        "gain": int(gain), "mean": float(m.mean), "sem": float(m.sem),
                        "n": int(m.n), "ranging": step}
        return None

    # --- calibration -----------------------------------------------------------------------
    def _calibration_reusable(self) -> tuple[dict | None, str]:
        cals = [r for r in self.records if r["type"] == "calibration"]
        if not cals:
            return None, "no calibration in the journal"
        c = cals[-1]
        problem = calibration_problem(c["darks"], c["reference"], self.standard)
        if problem is not None:
            return None, f"the journal's calibration {c['id']} is invalid ({problem})"
        if c["plan_sha256"] != self.plan.sha256:
            return None, "the plan file changed"
        if c["standard_sha256"] != self.standard.sha256:
            return None, "the white standard table changed"
        if c["idn"] != self.identity:
            return None, f"another instrument ({c['idn']})"
        age_min = (self.clock() - c["time"]) / 60.0
        if age_min > self.settings.calibration_max_age_min or age_min < -1.0:
            return None, (f"it is {age_min:.0f} min old (limit "
                          f"{self.settings.calibration_max_age_min:g} min)")
        wl = {float(r["wavelength_nm"]) for r in c["reference"]}
        if not set(map(float, self.plan.wavelengths_nm)) <= wl:
            return None, "it lacks some of the plan's wavelengths"
        return c, ""

    def _calibrate(self) -> dict:
        s = self.settings
        ids = [r["id"] for r in self.records if r["type"] == "calibration"]
        log.info("calibration: dark at %d ranging steps, white standard at %d wavelengths",
                 len(self.ladder), len(self.plan.wavelengths_nm))
        self.motion.set_slot(protocol.SampleSlot.WHITE_REFERENCE)
        self._move(self._reference_axes())
        self.head.forget_settings()
        wl0 = float(self.plan.wavelengths_nm[0])
        darks = []
        for itime, gain in self.ladder:
            m = self.head.measure(wl0, itime, gain, s.readings, repetitions=s.repetitions,
                                  shutter_open=False)
            darks.append({"itime_ms": int(itime), "gain": int(gain), "mean": float(m.mean),
                          "sem": float(m.sem), "n": int(m.n)})
        reference = []
        self.head.query("SHUTTER", "OPEN")
        for wl in self.plan.wavelengths_nm:
            r = self._autorange(float(wl))
            if r is None:
                raise DeviceError("photometer head", f"white standard at {wl:g} nm",
                                  "saturated at every integration time and gain")
            reference.append(r)
        self.head.query("SHUTTER", "CLOSE")
        self.motion.check_owner("calibration")
        problem = calibration_problem(darks, reference, self.standard)
        if problem is not None:
            # never stored: a point measured against it would be wrong (beta = inf or noise)
            self._append({"type": "event", "what": "calibration_invalid", "message": problem,
                          "time": self.clock()})
            raise DeviceError("photometer head", "calibration", problem)
        self.motion.set_slot(protocol.SampleSlot.SAMPLE)
        rec = {"type": "calibration", "id": (max(ids) + 1) if ids else 0, "time": self.clock(),
               "plan_sha256": self.plan.sha256, "standard_sha256": self.standard.sha256,
               "idn": self.identity, "darks": darks, "reference": reference,
               "reference_deg": list(self.plan.reference_deg), "retries": self._retry_snapshot()}
        self._append(rec)
        return rec

    # --- run -------------------------------------------------------------------------------
    def _open_journal(self) -> JournalContent:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        path = self.out_dir / JOURNAL_NAME
        # the caller holds the run directory's lock: no other session writes here, so a
        # temporary file of the dataset writer is a leftover of a killed write
        for stale in remove_stale_temp_files(self.out_dir):
            log.info("removed %s, left by an interrupted dataset write", stale)
        if path.exists() and path.stat().st_size > 0 and not self.resume:
            raise AcquisitionError(f"{self.out_dir}: a journal from an earlier run is there; "
                                   "continue it with --resume or choose a new --out")
        journal, content = Journal.open(path)
        self.journal = journal
        self.records = list(content.records)
        try:
            check_consistency(self.records, str(path))
        except JournalError:
            journal.close()
            raise
        starts = [r for r in self.records if r["type"] == "start"]
        if self.records and not starts:
            journal.close()
            raise AcquisitionError(f"{path}: no start record; not a gonio journal")
        if starts and starts[0]["plan_sha256"] != self.plan.sha256:
            journal.close()
            raise AcquisitionError(f"{path}: the journal was written for plan "
                                   f"'{starts[0]['plan']}' with different contents; resume with "
                                   "the same plan file or choose a new --out")
        try:
            self._check_points_in_plan(str(path))
        except AcquisitionError:
            journal.close()
            raise
        return content

    def _check_points_in_plan(self, name: str) -> None:
        """Every journaled point is a measurable point of the plan (same axes, the plan's
        wavelengths): the journal is not trusted blindly (an edited or foreign point would be
        merged into the dataset and counted as done)."""
        points = {p.key: p for p in self.check.ordered}
        wavelengths = set(map(float, self.plan.wavelengths_nm))
        for line, r in enumerate(self.records, start=1):
            if r["type"] != "point":
                continue
            p = points.get(_key(r))
            if p is None or any(abs(float(a) - b) > 1e-6 for a, b in zip(r["axes_deg"], p.axes_deg)):
                raise AcquisitionError(
                    f"{name}: line {line}: point at geometry "
                    f"({', '.join(f'{float(x):g}' for x in r['geometry'])}) is not a measurable "
                    f"point of plan '{self.plan.name}'; the journal was altered: choose a new --out")
            extra = {float(x["wavelength_nm"]) for x in r["readings"]} - wavelengths
            if extra:
                raise AcquisitionError(
                    f"{name}: line {line}: point measured at {min(extra):g} nm, not a wavelength "
                    f"of plan '{self.plan.name}'; the journal was altered: choose a new --out")

    def run(self) -> RunResult:
        """Run (or resume) the acquisition; always leaves the instrument safe."""
        content = self._open_journal()
        ordered = self.check.ordered
        total = len(ordered)
        done = {_key(r) for r in usable_points(self.records)}
        status, code, message = "complete", EXIT_OK, ""
        failure: Exception | None = None
        bar = None
        start_time = self.clock()
        # the start record comes first, before anything can fail, so that every journal
        # (even of a session that could not reach the instrument) can be resumed
        if not any(r["type"] == "start" for r in self.records):
            self._append({"type": "start", "plan": self.plan.name, "plan_sha256": self.plan.sha256,
                          "standard_sha256": self.standard.sha256, "time": start_time,
                          "seed": self.seed})
        else:
            self._append({"type": "event", "what": "resume", "time": start_time,
                          "torn_last_line": content.torn, "points_done": len(done)})
            if content.torn:
                log.warning("journal: the last line was torn; that point is measured again")
        try:
            ident = self.head.connect()
            self.identity = f"{ident.maker},{ident.model},{ident.serial},{ident.firmware}"
            self.firmware = self.motion.firmware()
            self.motion.check_safe_to_move()
            if self.owner_token:
                self.motion.claim(self.owner_token)
            for p in self.check.blocked:
                log.info("unmeasurable (beam-block zone): theta_i=%g phi_i=%g theta_o=%g phi_o=%g",
                         p.theta_i, p.phi_i, p.theta_o, p.phi_o)
            for p, why in self.check.out_of_limits:
                log.warning("unmeasurable (%s): theta_i=%g theta_o=%g", why, p.theta_i, p.theta_o)
            self.motion.set_lamp(True)
            self.motion.set_shutter(False)
            self.motion.set_slot(protocol.SampleSlot.SAMPLE)
            self.motion.home()
            cal, why = self._calibration_reusable() if self.resume else (None, "")
            if cal is None:
                if self.resume and why != "no calibration in the journal":
                    log.warning("calibration measured again: %s", why)
                cal = self._calibrate()
            else:
                log.info("calibration %d reused from the journal", cal["id"])
                self._append({"type": "event", "what": "calibration_reused", "id": cal["id"]})
            todo = [p for p in ordered if p.key not in done]
            bar = self._progress(total, total - len(todo))
            t_first = time.monotonic()
            for k, p in enumerate(todo):
                self._measure_point(p, cal["id"], len(done) + k)
                self._report(bar, k + 1, len(todo), t_first, len(done) + k + 1, total, p)
        except (KeyboardInterrupt, Interrupted):
            status, code, message = "interrupted", EXIT_INTERRUPTED, "interrupted"
        except DeviceError as exc:
            status, code, message = "stopped", EXIT_STOPPED, f"stopped safely: {exc}"
        except Exception as exc:
            # not an instrument fault (a bug, a replay mismatch, a full disk): keep what was
            # measured, then let the exception through
            status, code, message = "failed", EXIT_STOPPED, f"failed: {exc!r}"
            failure = exc
        finally:
            if bar is not None:
                bar.close()
            self.head.shutdown()
            self.motion.shutdown()
        measured = len({_key(r) for r in usable_points(self.records)})
        if status != "complete":
            # INFO, not ERROR: the command line prints the one final line (what, how many points
            # are kept, how to continue); a library caller reads RunResult
            log.info("%s (%d of %d points measured)", message, measured, total)
        retries = self._retry_snapshot()
        self._append({"type": "event", "what": "session_end", "status": status,
                      "message": message, "retries": retries, "time": self.clock()})
        self.journal.close()
        # the dataset comes from the journal as it is on disk: an interrupt (SIGINT) landing
        # inside an append, after the line was written but before it reached self.records,
        # must not leave a journaled point out of the dataset
        self.records = list(read_journal(self.out_dir / JOURNAL_NAME).records)
        measured = len({_key(r) for r in usable_points(self.records)})
        path = None
        if measured:
            ds = dataset_from_journal(self.records, self.plan, self.standard,
                                      seed=self.seed, links=self.links, firmware=self.firmware,
                                      complete=(status == "complete" and measured == total),
                                      created=self.created)
            write_dataset(ds, self.out_dir)
            path = self.out_dir
        if failure is not None:
            raise failure
        return RunResult(status, code, measured, total, path, message, retries)

    def _measure_point(self, p: PlanPoint, cal_id: int, index: int) -> None:
        what = "point (" + ", ".join(f"{x:g}" for x in p.axes_deg) + ")"
        self.motion.check_owner(what)           # never move another client's instrument
        self._move(p.axes_deg)
        if self.settings.settle_ms > 0:
            self.retry.sleep(self.settings.settle_ms / 1000.0)
        self.head.forget_settings()       # every point starts from the same commands
        self.head.query("SHUTTER", "OPEN")
        readings, saturated = [], []
        for wl in self.plan.wavelengths_nm:
            r = self._autorange(float(wl))
            if r is None:
                saturated.append(float(wl))
                log.warning("saturated at every setting, not stored: %s at %g nm", p.key, wl)
            else:
                readings.append(r)
        self.motion.check_owner(what)           # taken meanwhile: these readings are not ours
        if not self.motion.shutter_is_open(f"{what}: read shutter"):
            # closed under us (another client's safe stop): some readings may be dark
            raise DeviceError("motion controller", what, "the shutter was closed during the "
                                                         "point (by another client?); the point "
                                                         "is not kept")
        self._append({"type": "point", "index": index, "axes_deg": list(p.axes_deg),
                      "geometry": list(p.key), "calibration": cal_id, "readings": readings,
                      "saturated_nm": saturated, "retries": self._retry_snapshot()})

    def _progress(self, total: int, initial: int):
        if not self.progress:
            return None
        from tqdm import tqdm
        return tqdm(total=total, initial=initial, unit="point", desc=self.plan.name,
                    file=sys.stderr, dynamic_ncols=True)

    def _report(self, bar, k: int, n_todo: int, t0: float, done: int, total: int, p) -> None:
        if bar is not None:
            bar.update(1)
            return
        elapsed = time.monotonic() - t0
        eta = elapsed / k * (n_todo - k)
        log.info("point %d/%d theta_i=%g s=%g plane=%g rot=%g (ETA %.0f s)", done, total,
                 p.source_deg, p.detector_deg, p.plane_deg, p.rotation_deg, eta)


def _key(point: dict) -> tuple[float, ...]:
    return tuple(round(float(x), 6) for x in point["geometry"])


def usable_points(records: list[dict]) -> list[dict]:
    """The journal's point records whose calibration is valid
    (:func:`gonio.calibration.calibration_problem`; a journal written before calibrations were
    checked may hold an invalid one: its points are measured again on resume)."""
    invalid = {r["id"] for r in records if r["type"] == "calibration"
               and calibration_problem(r["darks"], r["reference"]) is not None}
    return [r for r in records if r["type"] == "point" and r["calibration"] not in invalid]


def dataset_from_journal(records: list[dict], plan: Plan, standard: WhiteStandard, *,
                         seed: int | None = None, links: dict | None = None,
                         firmware: str = "", complete: bool = False,
                         created: str | None = None):
    """Build the measured dataset from journal records (see the module docstring).

    Each point uses the calibration it was measured with; a geometry journaled twice keeps its
    first record; points of an invalid calibration are left out (:func:`usable_points`).
    Returns a :class:`gonio.data.Dataset`.
    """
    cals = {r["id"]: r for r in records if r["type"] == "calibration"}
    start = next(r for r in records if r["type"] == "start")
    seen, cols = set(), {k: [] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm",
                                         "S", "uS", "D", "uD", "t", "G", "Sr", "uSr", "Dr",
                                         "uDr", "tr", "Gr", "n", "to_ref")}
    saturated = []
    for rec in usable_points(records):
        key = _key(rec)
        if key in seen:
            continue
        seen.add(key)
        cal = cals[rec["calibration"]]
        darks = {(d["itime_ms"], d["gain"]): d for d in cal["darks"]}
        refs = {float(r["wavelength_nm"]): r for r in cal["reference"]}
        to_ref = abs(float(cal.get("reference_deg", plan.reference_deg)[1]))
        for sat in rec.get("saturated_nm", []):
            saturated.append(list(key) + [sat])
        for r in rec["readings"]:
            wl = float(r["wavelength_nm"])
            ref = refs[wl]
            d = darks[(r["itime_ms"], r["gain"])]
            dr = darks[(ref["itime_ms"], ref["gain"])]
            for name, v in zip(("theta_i", "phi_i", "theta_o", "phi_o"), key):
                cols[name].append(v)
            cols["wavelength_nm"].append(wl)
            cols["S"].append(r["mean"]); cols["uS"].append(r["sem"])
            cols["D"].append(d["mean"]); cols["uD"].append(d["sem"])
            cols["t"].append(r["itime_ms"]); cols["G"].append(protocol.GAIN_FACTORS[r["gain"]])
            cols["Sr"].append(ref["mean"]); cols["uSr"].append(ref["sem"])
            cols["Dr"].append(dr["mean"]); cols["uDr"].append(dr["sem"])
            cols["tr"].append(ref["itime_ms"]); cols["Gr"].append(protocol.GAIN_FACTORS[ref["gain"]])
            cols["n"].append(r["n"])
            cols["to_ref"].append(to_ref)
    c = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    beta_ref, u_beta_ref = standard.at(c["wavelength_nm"])
    beta, u_beta = radiance_factor(c["S"], c["uS"], c["D"], c["uD"], c["t"], c["G"], c["theta_o"],
                                   c["Sr"], c["uSr"], c["Dr"], c["uDr"], c["tr"], c["Gr"],
                                   c["to_ref"], beta_ref, u_beta_ref)
    table = pd.DataFrame({"theta_i": c["theta_i"], "phi_i": c["phi_i"], "theta_o": c["theta_o"],
                          "phi_o": c["phi_o"], "wavelength_nm": c["wavelength_nm"], "beta": beta,
                          "u_beta": u_beta, "n": c["n"].astype(int)})
    retries, sessions = retry_totals(records)
    check = plan.check()
    links = links or {}
    meta = new_meta(
        "measured", sample=plan.sample,
        source={"idn": cals[max(cals)]["idn"] if cals else "", "firmware": firmware,
                "modbus": links.get("modbus"), "serial": links.get("serial")},
        provenance={
            "plan": {"name": plan.name, "sha256": plan.sha256, "description": plan.description},
            "seed": seed,
            "white_standard": {"name": standard.name, "sha256": standard.sha256},
            "reference_deg": list(plan.reference_deg),
            "acquisition": {k: getattr(plan.acquisition, k) for k in plan.acquisition.__dataclass_fields__},
            "points_planned": len(check.ordered), "points_measured": len(seen),
            "complete": bool(complete),
            "unmeasurable": [list(p.key) for p in check.blocked]
                            + [list(p.key) for p, _ in check.out_of_limits],
            "saturated": saturated,
            "retries": dict(sorted(retries.items())),
            "sessions": sessions,
            "calibrations": sorted(cals),
            "versions": _versions(),
        },
        created=created or _iso(float(start["time"])))
    return make_dataset(table, meta)


def retry_totals(records: list[dict]) -> tuple[dict[str, int], int]:
    """``(retries summed over the sessions, number of sessions)`` of a journal.

    A ``start`` record or a ``resume`` event opens a session; a session's counts are its last
    snapshot (``retries`` of its ``session_end`` event, or of its last ``calibration`` or
    ``point`` record when it was killed). See the module docstring.
    """
    snapshots: list[dict] = []
    for r in records:
        kind, what = r["type"], r.get("what")
        if kind == "start" or (kind == "event" and what == "resume"):
            snapshots.append({})
            continue
        if not snapshots or not isinstance(r.get("retries"), dict):
            continue
        if kind in ("calibration", "point") or (kind == "event" and what == "session_end"):
            snapshots[-1] = r["retries"]
    totals: dict[str, int] = {}
    for snap in snapshots:
        for k, v in snap.items():
            totals[k] = totals.get(k, 0) + int(v)
    return dict(sorted(totals.items())), len(snapshots)
