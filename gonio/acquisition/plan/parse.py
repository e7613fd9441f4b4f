"""The plan parser: TOML text to a validated :class:`~gonio.acquisition.plan.model.Plan`.

:func:`parse_plan` reads the tables of :data:`~gonio.acquisition.plan.schema.SCHEMA` through a typed
field reader whose every error is one :class:`~gonio.acquisition.plan.schema.PlanError` naming the
file and the field, and applies the rules across fields (the monochromator's grid, the size limit,
the procedure's order).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from gonio.acquisition.plan.model import AcquisitionSettings, Plan, Procedure
from gonio.acquisition.plan.schema import (
    MAX_MEASUREMENTS,
    PROCEDURE_STEPS,
    RETRO_RING_AZIMUTHS,
    WAVELENGTH_STEP_NM,
    PlanError,
)
from gonio.data import toml_text

__all__ = ["parse_plan"]

_DEFAULT_WAVELENGTHS = np.arange(390.0, 710.0 + 1e-9, 10.0)


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

    def fail(self, key: str, msg: str) -> NoReturn:
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

    def numbers(self, key: str, default: list | None = None, required: bool = False) -> list[float]:
        """The list of finite numbers at ``key``; an absent key gives ``default`` (no default: an empty list)."""
        v = self.get(key, default, required)
        if v is None:
            return []
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
