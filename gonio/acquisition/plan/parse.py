"""Acquisition plans: what to measure, read from TOML (``tomllib``).

A plan is data (bluesky habit): the sample, the wavelengths, the geometries and the acquisition
policy. The engine (:mod:`gonio.acquisition.engine`) executes it; ``simulate`` evaluates its models at the
same geometries through :meth:`Plan.geometries`.

Public objects
--------------
- :func:`load_plan`, :func:`parse_plan`: a path, preset name or TOML text to a validated :class:`Plan`
  (with its :class:`AcquisitionSettings` and :class:`Procedure`); :func:`preset_names`,
  :func:`resolve_plan_path`.
- :meth:`Plan.check`, :class:`PlanCheck`: the rules ``gonio check-plan`` and ``gonio acquire`` apply
  before any acquisition (:meth:`PlanCheck.refusal`).
- :func:`measured_plan`: the plan of a file's own measured incidences; :func:`retro_ring`.
- :func:`order_points`, :func:`estimate_duration_s`: the order of the points and the time they take.
- :class:`PlanError`: the one error of a bad plan.
- :data:`SCHEMA`: every table and field and the rules across them.

Notes
-----
Geometry: the instrument's axes and the fabric frame are related by
:func:`gonio.data.geometry.axes_to_fabric` (docs/physics.md section 1, docs/instrument.md). Out-of-plane
directions are given as ``(theta_o, phi_o - phi_i)``: a relative azimuth ``a`` in [180, 360) is
reached with the signed detector zenith ``s = +theta_o`` and the detector-plane azimuth
``p = a - 180``, in [0, 180) with ``s = -theta_o, p = a``.

A plan asks for at most :data:`MAX_MEASUREMENTS` measurements; its wavelengths lie on the
monochromator's grid (:data:`WAVELENGTH_STEP_NM`); its steps are :data:`PROCEDURE_STEPS`. The schema
is :data:`SCHEMA`; ``docs/scripts/gen_reference.py`` renders it as docs/reference/plans.md.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gonio.data import toml_text
from gonio.data.geometry import axes_to_fabric, beam_blocked
from gonio.instrument.modbus_map import AXES, deg_to_mdeg

__all__ = [
    "SCHEMA",
    "WAVELENGTH_STEP_NM",
    "PlanError",
    "AcquisitionSettings",
    "PlanPoint",
    "PlanCheck",
    "Plan",
    "load_plan",
    "parse_plan",
    "resolve_plan_path",
    "preset_names",
    "order_points",
    "estimate_duration_s",
    "MAX_MEASUREMENTS",
    "PROCEDURE_STEPS",
    "Procedure",
    "RETRO_RING_DEG",
    "RETRO_RING_AZIMUTHS",
    "MEASURED",
    "measured_plan",
    "retro_ring",
]

#: The plan schema: an annotated example of every table and field (defaults and bounds in the comments)
#: and the rules across them. Rendered as docs/reference/plans.md by ``docs/scripts/gen_reference.py``
#: (an RST literal block after ``::``).
SCHEMA = """\
::

    name = "red-cotton"                 # optional, default: the file's stem
    description = "..."                 # optional

    [sample]                            # required; free-form keys kept in the dataset's meta
    name = "red cotton"                 # required

    [wavelengths]                       # optional, default 390..710 step 10
    start_nm = 390
    stop_nm = 710                       # inclusive
    step_nm = 10
    # or: list_nm = [450, 550, 650]

    [geometry]
    incidence_deg = [0, 30, 45, 60]     # required, source zenith angles
    sample_rotation_deg = [0]           # optional, default [0]
    in_plane_deg = [-60, -50, 70]       # signed observation angles (+ = mirror side), or
    in_plane = {start = -60, stop = 70, step = 10}
    directions_deg = [[45, 90]]         # optional (theta_o, phi_o - phi_i) pairs out of the plane
    retro_ring_deg = [6, 30]            # optional: at every oblique incidence, rings this far from the
    retro_ring_azimuths = 4             #   retro-reflection (source) direction, at 4 azimuths around it
    skip_blocked = false                # true: beam-block points are expected (listed, not fatal)

    [acquisition]                       # optional, defaults shown
    itime_ms = 100                      # integration time (whole ms) every point starts from
    gain = 0                            # gain step every point starts from (0..3 = x1, x4, x16, x64)
    min_itime_ms = 1                    # auto-ranging floor
    readings = 8                        # n of READ? n
    repetitions = 1                     # READ? calls pooled per point
    settle_ms = 20                      # wait after a move (real-speed milliseconds)
    velocity_deg_s = 20                 # axis velocity
    calibration_max_age_min = 120       # a journal's calibration older than this is re-measured

    [calibration]                       # optional
    white_standard = "spectralon"       # preset name or CSV file (relative to the plan's folder)
    reference_deg = [0, 45]             # reference geometry (theta_i, theta_o), in plane

    [procedure]                         # optional, defaults shown
    steps = ["home", "calibrate", "measure"]   # the session's steps, in order
    recalibrate_every = 0               # > 0: dark + white standard again after every N points

The procedure names the steps the engine runs after connecting: ``home`` (home every axis),
``calibrate`` (dark and white standard at the reference geometry, or on ``--resume`` the journal's
calibration when still valid) and ``measure`` (every measurable point); ``measure`` comes once, after
a ``calibrate``. With ``recalibrate_every = N`` the calibration is measured again after every N points
measured in a session, and each point uses the calibration it was measured with. The default is the
usual order.

Size limit: a plan asks for at most one million measurements, geometries (``incidence x rotations x
(in-plane + out-of-plane directions)``) times wavelengths - about a month at real speed. A larger plan
is refused at load time with one line; split it into several plans (each its own run directory).

Wavelengths must lie on the monochromator's 0.1 nm grid (the resolution of ``WAVE``): a finer value
(``500.01``) is refused with the field and value named, not rounded, so that a dataset never labels a
reading with a wavelength other than the one the head was set to (two plan wavelengths rounding to one
setting would otherwise be two rows of the same measurement). Values within 1e-6 nm of the grid
(floating-point steps) are snapped to it.

Before any acquisition the plan is checked (the rules ``gonio check-plan`` applies): ``gonio acquire``
refuses a plan with points out of the soft limits or in the beam-block zone without
``skip_blocked = true``, instead of dropping those points and reporting the run complete.
"""

#: ``--plan measured``: the plan of the sample file's own measured incidences (:func:`measured_plan`)
MEASURED = "measured"
#: angular distances (deg) from the retro-reflection direction of a measured-geometry plan's rings: 6 deg, the
#: nearest the detector may come to the source (5 deg) with a margin, and 30 deg, outside the opposition peak
RETRO_RING_DEG = (6.0, 30.0)
#: points on each ring, evenly spaced in azimuth around the retro direction (0: towards the normal)
RETRO_RING_AZIMUTHS = 4

MAX_MEASUREMENTS = 1_000_000
"""Largest plan accepted: geometries x wavelengths (before duplicates are removed)."""

PROCEDURE_STEPS = ("home", "calibrate", "measure")
"""The steps a plan's ``[procedure]`` may name (the default order)."""

_DEFAULT_WAVELENGTHS = np.arange(390.0, 710.0 + 1e-9, 10.0)
_PRESET_PACKAGE = "gonio.presets"


WAVELENGTH_STEP_NM = 0.1
"""Resolution of the head's ``WAVE`` setting (one decimal); plan wavelengths must lie on it."""


@dataclass(frozen=True)
class Procedure:
    """The session's steps after connecting (see the module docstring).

    Names of :data:`PROCEDURE_STEPS` in order, and ``recalibrate_every`` points (0 = never).
    """

    steps: tuple[str, ...] = PROCEDURE_STEPS
    recalibrate_every: int = 0


class PlanError(ValueError):
    """A plan file is missing, unreadable or has an invalid field (message names file and field)."""


@dataclass(frozen=True)
class AcquisitionSettings:
    """Integration time / gain policy and timing of one plan.

    Auto-ranging starts every reading at ``(itime_ms, gain)`` and steps down
    (:meth:`AcquisitionSettings.ladder`) while the head reports saturation. The default gain is x1:
    the shot-noise-limited relative error ``1/sqrt(K t beta cos theta_o)`` does not depend on the
    gain (it only lifts the signal above the read noise), so a higher starting gain mostly costs
    saturated readings.
    """

    itime_ms: int = 100
    gain: int = 0
    min_itime_ms: int = 1
    readings: int = 8
    repetitions: int = 1
    settle_ms: float = 20.0
    velocity_deg_s: float = 20.0
    calibration_max_age_min: float = 120.0

    def ladder(self) -> list[tuple[int, int]]:
        """Auto-ranging ladder ``[(itime_ms, gain), ...]`` from the most sensitive setting down.

        Every point starts at step 0; a saturated reading moves one step down: the gain first
        (a factor 4 each), then the integration time (halved, whole milliseconds, down to
        ``min_itime_ms``).
        """
        steps = [(self.itime_ms, g) for g in range(self.gain, -1, -1)]
        itime = self.itime_ms
        while itime // 2 >= self.min_itime_ms:
            itime //= 2
            steps.append((itime, 0))
        if steps[-1][0] > self.min_itime_ms:
            steps.append((self.min_itime_ms, 0))
        return steps


@dataclass(frozen=True)
class PlanPoint:
    """One geometry of a plan: axis positions (deg) and the fabric-frame angles (deg)."""

    source_deg: float
    detector_deg: float
    plane_deg: float
    rotation_deg: float
    theta_i: float
    phi_i: float
    theta_o: float
    phi_o: float

    @property
    def axes_deg(self) -> tuple[float, float, float, float]:
        """Axis targets (source zenith, detector zenith, detector plane, sample rotation)."""
        return (self.source_deg, self.detector_deg, self.plane_deg, self.rotation_deg)

    @property
    def key(self) -> tuple[float, float, float, float]:
        """Fabric-frame geometry ``(theta_i, phi_i, theta_o, phi_o)``, rounded to 1e-6 deg."""
        return (round(self.theta_i, 6), round(self.phi_i, 6), round(self.theta_o, 6), round(self.phi_o, 6))


@dataclass
class PlanCheck:
    """Result of :meth:`Plan.check`: measurable points in motion order and the refused ones."""

    ordered: list[PlanPoint]
    blocked: list[PlanPoint]
    out_of_limits: list[tuple[PlanPoint, str]]
    estimated_s: float
    blocked_expected: bool = False

    @property
    def ok(self) -> bool:
        """True when nothing is out of limits and no beam-block point is unexpected."""
        return not self.out_of_limits and (self.blocked_expected or not self.blocked)

    def refusal(self, plan_name: str) -> str | None:
        """Why the plan cannot be acquired, in one line (None when :attr:`ok`).

        The one validation shared by ``gonio check-plan`` (which lists the points) and
        ``gonio acquire`` (which refuses to start).
        """
        if self.ok:
            return None
        parts = []
        if self.out_of_limits:
            _, why = self.out_of_limits[0]
            parts.append(f"{len(self.out_of_limits)} out of the soft limits (first: {why})")
        if self.blocked and not self.blocked_expected:
            parts.append(f"{len(self.blocked)} in the beam-block zone and skip_blocked = false")
        return (f"plan {plan_name}: {'; '.join(parts)}; `gonio check-plan` lists them: fix the "
                "plan (or set skip_blocked = true for expected beam-block points)")


def preset_names() -> list[str]:
    """Names of the plans shipped in :mod:`gonio.presets`."""
    folder = resources.files(_PRESET_PACKAGE)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def resolve_plan_path(path_or_name: str | Path) -> Path:
    """A plan file path from a path or the name of a shipped preset (``red-cotton``, ``quick``)."""
    p = Path(path_or_name)
    if p.is_file():
        return p
    if p.is_dir():
        raise PlanError(f"{p}: is a directory, not a plan file (give the plan's .toml file, or a "
                        f"preset: {', '.join(preset_names())})")
    name = str(path_or_name)
    name = name[:-5] if name.endswith(".toml") else name
    if "/" not in name and name in preset_names():
        return Path(str(resources.files(_PRESET_PACKAGE) / f"{name}.toml"))
    raise PlanError(f"{path_or_name}: no such plan file and no preset of that name "
                    f"(presets: {', '.join(preset_names())})")


def load_plan(path_or_name: str | Path) -> Plan:
    """Read and validate a plan file or a preset name; raises :class:`PlanError`.

    An RGL ``.bsdf`` file gives the plan of its measured incidences (:func:`measured_plan`).
    """
    p = Path(path_or_name)
    if p.suffix == ".bsdf" and p.is_file():
        return measured_plan(p)
    path = resolve_plan_path(path_or_name)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise PlanError(f"{path}: cannot read the plan ({exc.strerror})") from None
    return parse_plan(raw, path)


def _finite_number(x: Any) -> bool:
    """A real number usable as an angle, time or count (no NaN/inf, no 400-digit integers)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    if isinstance(x, int):
        return abs(x) < 10**15
    return math.isfinite(x) and abs(x) < 1e15


class _Fields:
    """Typed access to a TOML table with errors naming the file and the field."""

    def __init__(self, table: dict, where: str, file: str):
        self.table, self.where, self.file = table, where, file
        self.used: set[str] = set()

    def _name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def fail(self, key: str, msg: str):
        raise PlanError(f"{self.file}: field '{self._name(key)}': {msg}")

    def get(self, key: str, default: Any = None, required: bool = False) -> Any:
        self.used.add(key)
        if key not in self.table:
            if required:
                self.fail(key, "is required")
            return default
        return self.table[key]

    def number(self, key: str, default: float | None = None, *, lo: float | None = None,
               hi: float | None = None, required: bool = False, integer: bool = False) -> Any:
        v = self.get(key, default, required)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"must be a number, got {type(v).__name__}")
        if not _finite_number(v):
            self.fail(key, f"must be a finite number of sensible size, got {v!r:.40}")
        if integer and not (isinstance(v, int) or float(v).is_integer()):
            self.fail(key, f"must be an integer, got {v}")
        if lo is not None and v < lo:
            self.fail(key, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            self.fail(key, f"must be <= {hi}, got {v}")
        return int(v) if integer else float(v)

    def numbers(self, key: str, default: list | None = None, required: bool = False) -> list[float] | None:
        v = self.get(key, default, required)
        if v is None:
            return None
        if not isinstance(v, list):
            self.fail(key, f"must be a list of numbers, got {type(v).__name__}")
        out = []
        for k, x in enumerate(v):
            if isinstance(x, bool) or not _finite_number(x):
                self.fail(key, f"item {k} must be a finite number, got {x!r:.40}")
            out.append(float(x))
        return out

    def table_(self, key: str, required: bool = False) -> dict:
        v = self.get(key, {} if not required else None, required)
        if not isinstance(v, dict):
            self.fail(key, f"must be a table, got {type(v).__name__}")
        return v

    def unknown(self):
        extra = sorted(set(self.table) - self.used)
        if extra:
            self.fail(extra[0], "unknown field (check the spelling; see `gonio check-plan --help`)")


def _range(f: _Fields, start: str, stop: str, step: str, what: str) -> list[float]:
    a = f.number(start, required=True)
    b = f.number(stop, required=True)
    d = f.number(step, required=True)
    if d <= 0:
        f.fail(step, "must be > 0")
    if b < a:
        f.fail(stop, f"must be >= {start}")
    span = (b - a) / d
    if not math.isfinite(span) or span > 100000:
        f.fail(step, f"gives too many {what} (at most 100000)")
    n = int(math.floor(span + 1e-9)) + 1
    return [round(a + k * d, 9) for k in range(n)]


def _procedure(f: _Fields) -> Procedure:
    steps = f.get("steps", list(PROCEDURE_STEPS))
    if not isinstance(steps, list) or not steps or not all(isinstance(x, str) for x in steps):
        f.fail("steps", f"must be a non-empty list of step names ({', '.join(PROCEDURE_STEPS)})")
    unknown = [x for x in steps if x not in PROCEDURE_STEPS]
    if unknown:
        f.fail("steps", f"unknown step {unknown[0]!r} (steps: {', '.join(PROCEDURE_STEPS)})")
    if steps.count("measure") != 1:
        f.fail("steps", "must name 'measure' exactly once")
    if "calibrate" not in steps[:steps.index("measure")]:
        f.fail("steps", "'measure' needs a 'calibrate' before it (every point is measured "
                        "against a calibration)")
    every = f.number("recalibrate_every", 0, lo=0, hi=10**9, integer=True)
    f.unknown()
    return Procedure(tuple(steps), every)


def parse_plan(raw: bytes | str, path: str | Path = "<plan>") -> Plan:  # noqa: C901
    """Validate plan TOML text (bytes or str) and build a :class:`Plan`; raises :class:`PlanError`."""
    file = str(path)
    if isinstance(raw, str):
        raw = raw.encode("utf-8", errors="surrogatepass")
    data = toml_text.loads(raw, file, PlanError, "plan", 3)
    top = _Fields(data, "", file)
    name = top.get("name", Path(file).stem)
    if not isinstance(name, str) or not name.strip():
        top.fail("name", "must be a non-empty string")
    description = top.get("description", "")
    if not isinstance(description, str):
        top.fail("description", "must be a string")

    sample = top.table_("sample", required=True)
    if not isinstance(sample.get("name"), str) or not sample["name"].strip():
        _Fields(sample, "sample", file).fail("name", "is required (a non-empty string)")

    wl = _Fields(top.table_("wavelengths"), "wavelengths", file)
    if "list_nm" in wl.table:
        wavelengths = wl.numbers("list_nm")
        if not wavelengths:
            wl.fail("list_nm", "must not be empty")
    elif any(k in wl.table for k in ("start_nm", "stop_nm", "step_nm")):
        wavelengths = _range(wl, "start_nm", "stop_nm", "step_nm", "wavelengths")
    else:
        wavelengths = list(_DEFAULT_WAVELENGTHS)
    wl.unknown()
    field_name = "list_nm" if "list_nm" in wl.table else "start_nm"
    for w in wavelengths:
        if not 380.0 <= w <= 780.0:
            wl.fail(field_name, f"wavelength {w} nm outside the monochromator range 380..780 nm")
        if abs(w * 10.0 - round(w * 10.0)) > 1e-6:
            if field_name == "start_nm" and abs(wavelengths[0] * 10.0 - round(wavelengths[0] * 10.0)) <= 1e-6:
                field_name = "step_nm"
            wl.fail(field_name, f"wavelength {w:.10g} nm is finer than the monochromator's "
                                f"{WAVELENGTH_STEP_NM:g} nm step (it would be measured at "
                                f"{round(w, 1):g} nm); give wavelengths in steps of "
                                f"{WAVELENGTH_STEP_NM:g} nm")
    # on the head's grid now: the plan's wavelengths are exactly what WAVE sets
    wavelengths = [round(w, 1) for w in wavelengths]
    if len(set(wavelengths)) != len(wavelengths):
        wl.fail("list_nm", "has duplicate wavelengths")

    geo = _Fields(top.table_("geometry", required=True), "geometry", file)
    incidence = geo.numbers("incidence_deg", required=True)
    if not incidence:
        geo.fail("incidence_deg", "must not be empty")
    rotations = geo.numbers("sample_rotation_deg", [0.0])
    if not rotations:
        geo.fail("sample_rotation_deg", "must not be empty")
    in_plane: list[float] = []
    if "in_plane_deg" in geo.table and "in_plane" in geo.table:
        geo.fail("in_plane", "give either in_plane_deg (a list) or in_plane (a range), not both")
    if "in_plane_deg" in geo.table:
        in_plane = geo.numbers("in_plane_deg")
    elif "in_plane" in geo.table:
        rng = _Fields(geo.table_("in_plane"), "geometry.in_plane", file)
        in_plane = _range(rng, "start", "stop", "step", "observation angles")
        rng.unknown()
    directions_raw = geo.get("directions_deg", [])
    directions: list[tuple[float, float]] = []
    if not isinstance(directions_raw, list):
        geo.fail("directions_deg", "must be a list of [theta_o, phi_o - phi_i] pairs")
    for k, d in enumerate(directions_raw):
        if not isinstance(d, list) or len(d) != 2 or not all(_finite_number(x) for x in d):
            geo.fail("directions_deg", f"item {k} must be a pair of numbers [theta_o, phi_o - phi_i]")
        if not 0.0 <= d[0] <= 90.0:
            geo.fail("directions_deg", f"item {k}: theta_o must be in 0..90, got {d[0]}")
        directions.append((float(d[0]), float(d[1])))
    ring = geo.numbers("retro_ring_deg", [])
    for k, r in enumerate(ring or []):
        if not 0.0 < r < 90.0:
            geo.fail("retro_ring_deg", f"item {k}: a ring's distance from the retro direction must be in (0, 90) deg, "
                                       f"got {r:g}")
    ring_azimuths = geo.number("retro_ring_azimuths", RETRO_RING_AZIMUTHS, lo=1, hi=360, integer=True)
    if not in_plane and not directions:
        geo.fail("in_plane_deg", "no observation angles: give in_plane_deg, in_plane or directions_deg")
    skip_blocked = geo.get("skip_blocked", False)
    if not isinstance(skip_blocked, bool):
        geo.fail("skip_blocked", "must be true or false")
    geo.unknown()

    acq = _Fields(top.table_("acquisition"), "acquisition", file)
    d = AcquisitionSettings()
    settings = AcquisitionSettings(
        itime_ms=acq.number("itime_ms", d.itime_ms, lo=1, hi=10000, integer=True),
        gain=acq.number("gain", d.gain, lo=0, hi=3, integer=True),
        min_itime_ms=acq.number("min_itime_ms", d.min_itime_ms, lo=1, hi=10000, integer=True),
        readings=acq.number("readings", d.readings, lo=1, hi=10000, integer=True),
        repetitions=acq.number("repetitions", d.repetitions, lo=1, hi=1000, integer=True),
        settle_ms=acq.number("settle_ms", d.settle_ms, lo=0, hi=600000),
        velocity_deg_s=acq.number("velocity_deg_s", d.velocity_deg_s, lo=0.01, hi=655.35),
        calibration_max_age_min=acq.number("calibration_max_age_min", d.calibration_max_age_min,
                                           lo=0, hi=1e6),
    )
    if settings.min_itime_ms > settings.itime_ms:
        acq.fail("min_itime_ms", "must not exceed itime_ms")
    acq.unknown()

    cal = _Fields(top.table_("calibration"), "calibration", file)
    standard = cal.get("white_standard", "spectralon")
    if not isinstance(standard, str) or not standard.strip():
        cal.fail("white_standard", "must be a preset name or a CSV file path")
    ref = cal.numbers("reference_deg", [0.0, 45.0])
    if len(ref) != 2:
        cal.fail("reference_deg", "must be [theta_i, theta_o]")
    if not 0.0 <= ref[0] <= 85.0 or not -85.0 <= ref[1] <= 85.0 or abs(ref[1]) >= 89.0:
        cal.fail("reference_deg", f"outside the axis limits: {ref}")
    cal.unknown()
    procedure = _procedure(_Fields(top.table_("procedure"), "procedure", file))
    top.unknown()

    n_ring = len(ring or []) * ring_azimuths * sum(1 for t in incidence if t > 0)
    n_geometries = len(incidence) * len(rotations) * (len(in_plane) + len(directions)) + len(rotations) * n_ring
    n_measurements = n_geometries * len(wavelengths)
    if n_measurements > MAX_MEASUREMENTS:
        raise PlanError(f"{file}: the plan asks for {n_measurements:,} measurements ({n_geometries:,} "
                        f"geometries x {len(wavelengths)} wavelengths); at most {MAX_MEASUREMENTS:,} "
                        "per plan: split it into several plans")
    sha = hashlib.sha256(raw).hexdigest()
    plan = Plan(name=name.strip(), description=description, path=Path(file), sha256=sha,
                sample=dict(sample), wavelengths_nm=np.asarray(wavelengths, dtype=float),
                incidence_deg=incidence, rotation_deg=rotations, in_plane_deg=in_plane,
                directions_deg=directions, skip_blocked=skip_blocked, acquisition=settings,
                white_standard=standard.strip(), reference_deg=(ref[0], ref[1]),
                procedure=procedure, retro_ring_deg=list(ring or []), retro_ring_azimuths=ring_azimuths)
    plan.points()  # validates the geometry now, so errors name the file at load time
    return plan


@dataclass
class Plan:
    """A validated acquisition plan (see the module docstring for the TOML schema)."""

    name: str
    description: str
    path: Path
    sha256: str
    sample: dict
    wavelengths_nm: np.ndarray
    incidence_deg: list[float]
    rotation_deg: list[float]
    in_plane_deg: list[float]
    directions_deg: list[tuple[float, float]]
    skip_blocked: bool
    acquisition: AcquisitionSettings
    white_standard: str
    reference_deg: tuple[float, float]
    procedure: Procedure = field(default_factory=Procedure)
    retro_ring_deg: list[float] = field(default_factory=list)
    retro_ring_azimuths: int = RETRO_RING_AZIMUTHS
    _points: list[PlanPoint] | None = field(default=None, repr=False)

    def points(self) -> list[PlanPoint]:
        """Every requested geometry, in plan order, duplicates (same fabric geometry) removed."""
        if self._points is not None:
            return self._points
        axes = []
        for rho in self.rotation_deg:
            for ti in self.incidence_deg:
                for s in self.in_plane_deg:
                    axes.append((ti, s, 0.0, rho))
                ring = [d for r in self.retro_ring_deg for d in retro_ring(ti, r, self.retro_ring_azimuths)] \
                    if ti > 0 else []
                for to, dphi in list(self.directions_deg) + ring:
                    rel = np.mod(dphi, 360.0)
                    if rel >= 180.0:
                        axes.append((ti, to, rel - 180.0, rho))
                    else:
                        axes.append((ti, -to if to > 0 else 0.0, rel if to > 0 else 0.0, rho))
        out, seen = [], set()
        for a in axes:
            g = axes_to_fabric(*a)
            p = PlanPoint(float(a[0]), float(a[1]), float(a[2]), float(a[3]), *g)
            if p.key not in seen:
                seen.add(p.key)
                out.append(p)
        self._points = out
        return out

    def geometries(self, measurable_only: bool = False) -> pd.DataFrame:
        """Requested geometries: DataFrame ``theta_i, phi_i, theta_o, phi_o`` (deg, fabric frame).

        Every geometry the plan asks for, in plan order (a model can be evaluated where the
        instrument cannot measure); ``measurable_only`` keeps only those :meth:`check` accepts,
        in motion order.
        """
        pts = self.check().ordered if measurable_only else self.points()
        return pd.DataFrame({
            "theta_i": [p.theta_i for p in pts], "phi_i": [p.phi_i for p in pts],
            "theta_o": [p.theta_o for p in pts], "phi_o": [p.phi_o for p in pts]})

    @property
    def n_measurements(self) -> int:
        """Number of (geometry, wavelength) pairs requested."""
        return len(self.points()) * len(self.wavelengths_nm)

    def check(self, *, move_overhead_s: float = 0.05, read_overhead_s: float = 0.004) -> PlanCheck:
        """Refuse points out of the soft limits or in the beam-block zone, order the rest.

        The rules are the controller's (soft limits of
        :data:`~gonio.instrument.modbus_map.AXES` in whole millidegrees,
        :func:`~gonio.data.geometry.beam_blocked`).

        Parameters
        ----------
        move_overhead_s, read_overhead_s
            Per-move and per-command overheads for the duration estimate.

        Returns
        -------
        PlanCheck
            Measurable points ordered to minimise motion (by rotation, incidence and detector
            plane, serpentine over the detector angle), refused points, and the estimated
            duration in seconds at real speed.
        """
        ok, blocked, bad = [], [], []
        for p in self.points():
            reason = None
            for axis, v in zip(AXES, p.axes_deg, strict=True):
                if not axis.within_limits(deg_to_mdeg(v)):
                    reason = (f"{axis.name} at {v:g} deg outside the soft limits "
                              f"{axis.min_mdeg / 1000:g}..{axis.max_mdeg / 1000:g} deg")
                    break
            if reason:
                bad.append((p, reason))
                continue
            if beam_blocked(p.source_deg, p.detector_deg, p.plane_deg):
                blocked.append(p)
            else:
                ok.append(p)
        ordered = order_points(ok)
        est = estimate_duration_s(self, ordered, move_overhead_s, read_overhead_s)
        return PlanCheck(ordered=ordered, blocked=blocked, out_of_limits=bad, estimated_s=est,
                         blocked_expected=self.skip_blocked)


def retro_ring(theta_i_deg: float, radius_deg: float, azimuths: int = RETRO_RING_AZIMUTHS
               ) -> list[tuple[float, float]]:
    """``(theta_o, phi_o - phi_i)`` (deg) of a ring of directions about the retro-reflection direction.

    ``azimuths`` directions ``radius_deg`` from the retro-reflection (source) direction at incidence
    ``theta_i_deg``, evenly spaced around it starting towards the normal; directions below 85 deg of
    zenith only (the detector's reach).

    >>> [(round(t, 3), round(p, 3)) for t, p in retro_ring(40.0, 6.0, 2)]
    [(34.0, 0.0), (46.0, 0.0)]
    """
    ti = math.radians(theta_i_deg)
    w = np.array([math.sin(ti), 0.0, math.cos(ti)])          # towards the source, phi_i = 0
    e1 = np.array([-math.cos(ti), 0.0, math.sin(ti)])        # in the plane of incidence, towards the normal
    e2 = np.array([0.0, 1.0, 0.0])
    r = math.radians(radius_deg)
    out = []
    for k in range(azimuths):
        a = 2.0 * math.pi * k / azimuths
        d = math.cos(r) * w + math.sin(r) * (math.cos(a) * e1 + math.sin(a) * e2)
        theta_o = math.degrees(math.acos(max(-1.0, min(1.0, float(d[2])))))
        if theta_o >= 85.0:
            continue
        phi = math.degrees(math.atan2(float(d[1]), float(d[0]))) if theta_o > 1e-9 else 0.0
        out.append((round(theta_o, 6), round(phi % 360.0, 6)))
    return out


def measured_plan(bsdf_path: str | Path, base: str | Path = "green-felt") -> Plan:
    """The plan of an RGL ``.bsdf`` file's own measured incidences.

    Its ``theta_i`` below the grazing limit rounded to the millidegree, ``phi_i`` 0 (isotropic
    files), the retro-reflection ring at every oblique incidence, the rest from ``base``.

    :func:`measured_plan` builds the plan that follows an RGL ``.bsdf`` file's own measured incidences
    (the green felt: ``theta_i`` = 0, 27.76, 40.03, 50.16, 59.52, 68.77, 78.56 deg; the file's 89.99 deg
    table is its extrapolation and is left out, :data:`gonio.data.formats.GRAZING_DEG`), rounded to the
    controller's millidegree, with the in-plane curves, wavelengths and settings of a base plan
    (``green-felt``) and the retro-reflection ring (:data:`RETRO_RING_DEG` at :data:`RETRO_RING_AZIMUTHS`
    azimuths around the source direction at every oblique incidence), so that the opposition ratio can be
    measured. A file evaluated at such a plan is read at its measured incidences; at any other incidence
    the file is interpolated between its tables (the datasets say which, ``incidences`` in meta.json:
    :func:`gonio.data.formats.rgl_bsdf.incidence_meta`). ``gonio demo --plan measured``, ``gonio truth FILE --plan measured`` and ``gonio
    import rgl-bsdf FILE --plan measured`` build it from the sample file; a ``.bsdf`` path given as the
    plan does too (:func:`load_plan`).

    Raises :class:`PlanError` (naming the file) when the file cannot be read.
    """
    from gonio.data.formats import GRAZING_DEG
    from gonio.data.formats.errors import FormatError
    from gonio.data.formats.rgl_bsdf import read_rgl_bsdf

    path = Path(bsdf_path)
    try:
        bsdf = read_rgl_bsdf(path)
    except (FormatError, OSError) as exc:
        raise PlanError(f"{path}: cannot build the measured-geometry plan from it ({exc})") from None
    incidences = sorted({round(float(t), 3) for t in bsdf.theta_i_deg if t < GRAZING_DEG})
    if not incidences or incidences[0] != 0.0:
        raise PlanError(f"{path}: the file has no normal incidence (theta_i = 0) table, which the comparison's "
                        "normalisation needs; give a plan with --plan")
    plan = load_plan(base)
    sha = hashlib.sha256(path.read_bytes() + plan.sha256.encode()).hexdigest()
    sample = dict(plan.sample)
    sample["name"] = path.stem
    sample["material"] = f"{bsdf.description.strip() or path.stem} (RGL .bsdf file {path.name})"
    out = dataclasses.replace(
        plan, name=f"{MEASURED}-{path.stem}", sha256=sha, sample=sample, incidence_deg=incidences,
        retro_ring_deg=list(RETRO_RING_DEG), retro_ring_azimuths=RETRO_RING_AZIMUTHS, skip_blocked=True,
        description=(f"the measured incidences of {path.name} ({', '.join(f'{t:g}' for t in incidences)} deg), "
                     f"{plan.name}'s in-plane curves and wavelengths, the retro-reflection rings "
                     f"{', '.join(f'{r:g}' for r in RETRO_RING_DEG)} deg"), _points=None)
    out.points()
    return out


def order_points(points: list[PlanPoint]) -> list[PlanPoint]:
    """Order points to minimise motion: rotation, incidence, detector plane, serpentine detector."""
    groups: dict[tuple[float, float, float], list[PlanPoint]] = {}
    for p in points:
        groups.setdefault((p.rotation_deg, p.source_deg, p.plane_deg), []).append(p)
    out: list[PlanPoint] = []
    forward = True
    for key in sorted(groups):
        g = sorted(groups[key], key=lambda p: p.detector_deg, reverse=not forward)
        out.extend(g)
        forward = not forward
    return out


def estimate_duration_s(plan: Plan, ordered: list[PlanPoint], move_overhead_s: float = 0.05,
                        read_overhead_s: float = 0.004) -> float:
    """Estimated duration (s, real speed): homing, calibration, moves, settling and readings."""
    a = plan.acquisition
    v = a.velocity_deg_s
    read_s = a.repetitions * (a.readings * a.itime_ms / 1000.0 + read_overhead_s)
    per_wavelength = read_s + 2 * read_overhead_s
    n_wl = len(plan.wavelengths_nm)
    # homing (all axes from up to 180 deg) and the calibration: darks per ladder step, reference
    total = 180.0 / v + a.readings * sum(t for t, _ in a.ladder()) / 1000.0
    total += n_wl * per_wavelength + 90.0 / v
    pos = np.array([plan.reference_deg[0], plan.reference_deg[1], 0.0, 0.0])
    for p in ordered:
        target = np.array(p.axes_deg)
        total += float(np.max(np.abs(target - pos))) / v + a.settle_ms / 1000.0 + move_overhead_s
        total += n_wl * per_wavelength
        pos = target
    return total
