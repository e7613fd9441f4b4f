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

Modules: :mod:`~gonio.acquisition.plan.schema` (the format and its limits, :class:`PlanError`),
:mod:`~gonio.acquisition.plan.model` (the plan, its points and its check),
:mod:`~gonio.acquisition.plan.parse` (TOML text to a plan) and :mod:`~gonio.acquisition.plan.load`
(presets, files, the measured-geometry plan); every public name is importable from here.

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

from gonio.acquisition.plan.load import load_plan, measured_plan, preset_names, resolve_plan_path
from gonio.acquisition.plan.model import (
    AcquisitionSettings,
    Plan,
    PlanCheck,
    PlanPoint,
    Procedure,
    estimate_duration_s,
    order_points,
    retro_ring,
)
from gonio.acquisition.plan.parse import parse_plan
from gonio.acquisition.plan.schema import (
    MAX_MEASUREMENTS,
    MEASURED,
    PROCEDURE_STEPS,
    RETRO_RING_AZIMUTHS,
    RETRO_RING_DEG,
    SCHEMA,
    WAVELENGTH_STEP_NM,
    PlanError,
)

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
