"""Finding and loading plans: shipped presets, plan files, and the plan of a .bsdf file's incidences.

:func:`load_plan` takes a path, a preset name (:func:`preset_names`, resolved by
:func:`resolve_plan_path`) or an RGL ``.bsdf`` file, whose measured incidences make the plan
(:func:`measured_plan`); the text is validated by :func:`gonio.acquisition.plan.parse.parse_plan`.
"""

from __future__ import annotations

import dataclasses
import hashlib
from importlib import resources
from pathlib import Path

from gonio.acquisition.plan.model import Plan
from gonio.acquisition.plan.parse import parse_plan
from gonio.acquisition.plan.schema import MEASURED, RETRO_RING_AZIMUTHS, RETRO_RING_DEG, PlanError

__all__ = ["preset_names", "resolve_plan_path", "load_plan", "measured_plan"]

_PRESET_PACKAGE = "gonio.presets"


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
