"""The acquisition engine: executes a plan on the devices, checkpointing every point.

bluesky habit: the plan (:mod:`gonio.acquisition.plan`) is data; this engine executes it and
emits documents to its subscribers (:mod:`gonio.acquisition.subscribers`): the journal records
``start``, ``calibration``, one ``point`` per geometry (every wavelength), ``event`` (resume, safe
stop, session end with its retry counts), and ``todo`` / ``stop``. Storage (the journal), the
progress display and the dataset writer are subscribers; the engine resumes from what storage
holds. The dataset (kind ``"measured"``) is reduced from the journal alone
(:mod:`gonio.acquisition.reduce`), so a resumed run and an uninterrupted run with the same mock
seed write identical ``radiance.csv``.

Sequence
--------
0. refuse a plan that ``gonio check-plan`` refuses
   (:meth:`gonio.acquisition.plan.PlanCheck.refusal`), and
   on ``--resume`` a journal holding a point that is not a measurable point of the plan;
1. connect (checksum mode on, ``*IDN?``, firmware), refuse an open interlock or a pressed
   emergency stop, lamp on, shutter closed, sample slot;

then the plan's procedure steps (:class:`gonio.acquisition.plan.Procedure`; by default home,
calibrate, measure):

1. ``home``: home every axis;
2. ``calibrate``: calibration at the reference geometry (default 0/45): dark ``D`` at every step of the
   auto-ranging ladder (shutter closed), then the white standard ``S_ref`` per wavelength
   (auto-ranged) with the reference slot in the beam - or, on ``--resume``, the journal's last
   calibration when still valid (a valid calibration, same plan and standard files, same
   instrument, younger than ``calibration_max_age_min``; otherwise it is measured again and the
   reason logged). A calibration is valid when the white standard stands above the dark by
   :data:`gonio.acquisition.calibration.MIN_REFERENCE_Z` standard errors at every wavelength
   (:func:`gonio.acquisition.calibration.calibration_problem`); an invalid one is never journaled (a
   ``calibration_invalid`` event says why and the session stops safely, exit 1);
3. ``measure``: every measurable point in motion order (with ``recalibrate_every = N``, a new
   calibration after every N points): move (axis commands ordered around the beam-block
   zone; after a following error or a lost homing every axis is stopped and brought to rest,
   the recoverable faults are reset and the axes re-homed, and the move repeated),
   settle, shutter open, and per wavelength auto-range from the same initial integration time
   and gain (:meth:`gonio.acquisition.plan.AcquisitionSettings.ladder`; a saturated reading is never
   stored), then append the point to the journal and fsync;
4. always: shutter closed and drives stopped (``shutdown``), a ``session_end`` event with the
   retry counts, then ``stop`` (the dataset writer writes the dataset atomically from the
   journal: what was measured).

Retry counts: see :mod:`gonio.acquisition.reduce`.

Exit status (:class:`RunResult.exit_code`): 0 complete; 1 stopped safely by an instrument
fault that retries did not clear (the measured points are kept; continue with ``--resume``);
any other exception (a bug, a full disk) also stops safely and keeps the points, then propagates;
2 usage or input error (plan, journal of another plan, unreachable device); 130 interrupted by
SIGINT or SIGTERM (the measured points are kept).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from gonio.acquisition.calibration import WhiteStandard, calibration_problem, load_white_standard
from gonio.acquisition.journal import JournalContent, JournalError, check_consistency, read_journal
from gonio.acquisition.plan import Plan, PlanPoint
from gonio.acquisition.reduce import point_key, usable_points
from gonio.acquisition.rundir import JOURNAL_NAME
from gonio.acquisition.subscribers import JournalWriter, Subscriber
from gonio.data import remove_stale_temp_files
from gonio.instrument import (
    RECOVERABLE_FAULTS,
    AxisFaultError,
    DeviceError,
    MotionController,
    PhotometerHead,
    RetryPolicy,
    SampleSlot,
)

__all__ = ["Engine", "RunResult", "AcquisitionError", "Interrupted", "EXIT_OK", "EXIT_STOPPED",
           "EXIT_USAGE", "EXIT_INTERRUPTED"]

log = logging.getLogger(__name__)

EXIT_OK = 0
EXIT_STOPPED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
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
    dataset_path: Path | None        # set by the session from its dataset writer
    message: str = ""
    retries: dict = field(default_factory=dict)


class Engine:
    """Execute ``plan`` with ``head`` and ``motion``, journaling into ``out_dir``.

    Parameters
    ----------
    plan : the validated plan.
    head, motion : the devices (sharing ``retry``).
    retry : the retry policy whose counter goes into the run's meta.
    out_dir : run directory (``journal.jsonl``, ``radiance.csv``, ``meta.json``); the caller
        holds its lock (:class:`gonio.acquisition.rundir.RunDirLock`, taken by
        :func:`gonio.acquisition.session.run_session`) for the whole session.
    resume : continue from the journal instead of refusing an existing one.
    seed : the mock's seed, recorded in the start record (None for a real instrument).
    subscribers : receive every document after the journal (progress, dataset writer, ...).
    clock : wall clock (seconds since the epoch), injectable for replay.
    owner_token : this session's claim on the instrument (written into the controller, checked
        at every point; see :meth:`gonio.instrument.motion.MotionController.claim`); 0 claims
        nothing.
    """

    def __init__(self, plan: Plan, head: PhotometerHead, motion: MotionController,
                 retry: RetryPolicy, out_dir: str | Path, *, resume: bool = False,
                 seed: int | None = None, subscribers: Sequence[Subscriber] = (),
                 clock: Callable[[], float] = time.time, owner_token: int = 0):
        self.plan, self.head, self.motion, self.retry = plan, head, motion, retry
        self.out_dir = Path(out_dir)
        self.resume = resume
        self.seed = seed
        self.clock = clock
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
        self.journal = JournalWriter(self.out_dir / JOURNAL_NAME)
        self.subscribers: list[Subscriber] = [self.journal, *subscribers]
        self.records: list[dict] = []
        self.identity: str = ""
        self.firmware: str = ""
        self.calibration: dict | None = None

    # --- documents -------------------------------------------------------------------------
    def _emit(self, name: str, doc: dict) -> None:
        """Hand a document to every subscriber, the journal first (the checkpoint)."""
        for subscriber in self.subscribers:
            subscriber(name, doc)

    def _append(self, record: dict) -> None:
        """Emit a journal record; it counts as done only once every subscriber took it."""
        self._emit(record["type"], record)
        self.records.append(record)

    def _retry_snapshot(self) -> dict[str, int]:
        """The session's cumulative retry counts (non-zero kinds, sorted)."""
        return {k: int(v) for k, v in sorted(self.retry.counts.items()) if v}

    def _reference_axes(self) -> tuple[float, float, float, float]:
        ti, to = self.plan.reference_deg
        return (ti, to, 0.0, 0.0)

    def _move(self, axes_deg) -> None:
        v = self.settings.velocity_deg_s
        # axis faults have a budget of their own, adapted like a link's (gonio.instrument.retry)
        axes = self.retry.link("axes")
        attempt = 0
        while True:
            try:
                self.motion.move_to(axes_deg, v)
                axes.record(ok=True)
                return
            except AxisFaultError as exc:
                axes.record(ok=False)
                attempt += 1
                if (exc.code not in RECOVERABLE_FAULTS
                        or attempt > max(_REHOME_ATTEMPTS, self.retry.attempts_for("axes"))):
                    raise
                log.warning("%s; stopping, resetting the fault and re-homing", exc)
                # every axis at rest first (another axis may still be moving and fault after
                # the reset), then reset what is recoverable, then home; one retry counted per
                # faulted axis (several axes of one move may fault together)
                faulted = self.motion.clear_faults("re-home")
                for _ in range(max(1, len(faulted))):
                    self.retry.count("axis_fault")
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
        self.motion.set_slot(SampleSlot.WHITE_REFERENCE)
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
        self.head.shutter_open = True
        for wl in self.plan.wavelengths_nm:
            r = self._autorange(float(wl))
            if r is None:
                raise DeviceError("photometer head", f"white standard at {wl:g} nm",
                                  "saturated at every integration time and gain")
            reference.append(r)
        self.head.shutter_open = False
        self.motion.check_owner("calibration")
        problem = calibration_problem(darks, reference, self.standard)
        if problem is not None:
            # never stored: a point measured against it would be wrong (beta = inf or noise)
            self._append({"type": "event", "what": "calibration_invalid", "message": problem,
                          "time": self.clock()})
            raise DeviceError("photometer head", "calibration", problem)
        self.motion.set_slot(SampleSlot.SAMPLE)
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
        content = self.journal.open()
        journal = self.journal
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
        """Check that every journaled point is a measurable point of the plan.

        Same axes, the plan's wavelengths: the journal is not trusted blindly (an edited or foreign point would be
        merged into the dataset and counted as done).
        """
        points: dict[tuple[float, ...], PlanPoint] = {p.key: p for p in self.check.ordered}
        wavelengths = set(map(float, self.plan.wavelengths_nm))
        for line, r in enumerate(self.records, start=1):
            if r["type"] != "point":
                continue
            p = points.get(point_key(r))
            if p is None or any(abs(float(a) - b) > 1e-6 for a, b in zip(r["axes_deg"], p.axes_deg, strict=False)):
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
        done = {point_key(r) for r in usable_points(self.records)}
        status, code, message = "complete", EXIT_OK, ""
        failure: Exception | None = None
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
            if content.unchained_lines:
                log.warning("journal: its first %d records were written without an integrity "
                            "chain (an older gonio): read unchecked; the records appended now "
                            "chain them", content.unchained_lines)
        steps: dict[str, Callable[[], None]] = {
            "home": self.motion.home, "calibrate": self._step_calibrate,
            "measure": lambda: self._step_measure(done, total)}
        try:
            self._connect()
            for step in self.plan.procedure.steps:
                steps[step]()
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
            self._make_safe()
        measured = len({point_key(r) for r in usable_points(self.records)})
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
        measured = len({point_key(r) for r in usable_points(self.records)})
        self._emit("stop", {"status": status, "measured": measured, "records": self.records,
                            "complete": status == "complete" and measured == total,
                            "firmware": self.firmware})
        if failure is not None:
            raise failure
        # where the dataset went is the dataset writer's business (a subscriber): the session
        # fills dataset_path in from it
        return RunResult(status, code, measured, total, None, message, retries)

    # --- procedure steps -------------------------------------------------------------------
    def _connect(self) -> None:
        """Identify both devices, refuse an unsafe controller, claim it, lamp on, shutter shut."""
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
        self.head.shutter_open = False          # the head owns the shutter (_make_safe)
        self.motion.set_slot(SampleSlot.SAMPLE)

    def _make_safe(self) -> None:
        """Shutter closed, drives stopped, claim released: never raises.

        One owner of the shutter: the photometer head closes it; only when that failed (the
        head's link is gone) is the controller's shutter coil written instead, and said so.
        """
        if not self.head.shutdown():
            log.warning("shutter: closing it through the motion controller's coil instead")
            try:
                self.motion.set_shutter(False)
            except Exception as exc:  # noqa: BLE001 - a safe stop must not raise
                log.warning("motion controller: closing the shutter failed too: %s", exc)
        self.motion.shutdown()

    def _step_calibrate(self) -> None:
        """The journal's calibration when reusable (on resume), else a new one."""
        cal, why = self._calibration_reusable() if self.resume else (None, "")
        if cal is None:
            if self.resume and why != "no calibration in the journal":
                log.warning("calibration measured again: %s", why)
            cal = self._calibrate()
        else:
            log.info("calibration %d reused from the journal", cal["id"])
            self._append({"type": "event", "what": "calibration_reused", "id": cal["id"]})
        self.calibration = cal

    def _step_measure(self, done: set, total: int) -> None:
        """Every measurable point not yet done, in motion order."""
        todo = [p for p in self.check.ordered if p.key not in done]
        every = self.plan.procedure.recalibrate_every
        self._emit("todo", {"total": total, "done": total - len(todo)})
        for k, p in enumerate(todo):
            if every and k and k % every == 0:
                self.calibration = self._calibrate()
            assert self.calibration is not None
            self._measure_point(p, self.calibration["id"], len(done) + k)

    def _measure_point(self, p: PlanPoint, cal_id: int, index: int) -> None:
        what = "point (" + ", ".join(f"{x:g}" for x in p.axes_deg) + ")"
        self.retry.begin_point()
        self.motion.check_owner(what)           # never move another client's instrument
        self._move(p.axes_deg)
        if self.settings.settle_ms > 0:
            self.retry.sleep(self.settings.settle_ms / 1000.0)
        self.head.forget_settings()       # every point starts from the same commands
        self.head.shutter_open = True
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
