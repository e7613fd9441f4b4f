"""The plan's TOML format: the annotated schema, its limits and the one error of a bad plan.

The leaf of :mod:`gonio.acquisition.plan`: :data:`SCHEMA` (rendered as docs/reference/plans.md by
``docs/scripts/gen_reference.py``), the bounds a plan is held to (:data:`MAX_MEASUREMENTS`,
:data:`WAVELENGTH_STEP_NM`, :data:`PROCEDURE_STEPS`), the retro-reflection rings of a measured-geometry
plan and :class:`PlanError`.
"""

from __future__ import annotations

__all__ = ["SCHEMA", "MEASURED", "RETRO_RING_DEG", "RETRO_RING_AZIMUTHS", "MAX_MEASUREMENTS", "PROCEDURE_STEPS",
           "WAVELENGTH_STEP_NM", "PlanError"]

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


WAVELENGTH_STEP_NM = 0.1
"""Resolution of the head's ``WAVE`` setting (one decimal); plan wavelengths must lie on it."""


class PlanError(ValueError):
    """A plan file is missing, unreadable or has an invalid field (message names file and field)."""
