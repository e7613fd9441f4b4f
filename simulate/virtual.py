"""The virtual goniophotometer: a fabric model evaluated at a plan's geometries, as a dataset.

``simulate fabric CONFIG --method classic|summation|mc --out DIR [--plan PLAN]`` (docs/physics.md
section 7) evaluates the chosen fabric model (:mod:`simulate.fabric`) at the geometries and
wavelengths of an acquisition plan (:mod:`gonio.acquisition.plan`; default: the shipped ``red-cotton`` plan)
and writes a radiance-coefficient dataset of kind ``"simulated"`` through :mod:`gonio.data.dataset`:

- ``beta`` = the model's radiance coefficient; ``u_beta`` = its Monte Carlo standard error,
  propagated from the fiber's ``u_R`` (summation: the correlated bound of :mod:`simulate.fabric`;
  classic: ``u_rho_d``, the Cook-Torrance term being exact); ``n`` = photons behind the fiber
  estimate (summation) or 1 (classic: one deterministic evaluation of ``rho_d`` + CT; the photons
  of ``rho_d`` are in the metadata when the fiber route reports them).
- Only what the plan needs is computed: the unique fiber-frame pairs its geometries map to (one
  :func:`simulate.fiber.volume_brdf` call) and only its wavelengths (the dye spectrum is sampled
  exactly there).

Beam-blocked geometries. The instrument cannot observe within 5 degrees of its source, so a plan
lists those points and the measurement skips them. A model has no detector in the beam: by
default they are SIMULATED, because the normal/normal value is what ``compare`` normalises by
(docs/physics.md section 8) and the simulation's own value there is better than an interpolated one
(``compare`` uses a dataset's normal/normal point when it has one). ``measurable_only=True``
(``--measurable-only``) skips them exactly as the measurement does.

Provenance in ``meta.json``: the config (name, source, SHA-256 and full text), the plan (name,
SHA-256), the seed, the requested ``target_rel_err`` and the achieved ``rel_err`` (the one
definition, :func:`simulate.montecarlo.accuracy.relative_error` over the geometries and
wavelengths of ``beta``: RMS of ``u_beta`` relative to each geometry's spectral peak), photons,
seconds, the fiber route's own ``info`` and the software versions.

One number, one meaning: ``target_rel_err`` is that relative error for every method. For
``summation`` and ``classic`` it is the target of the fiber Monte Carlo (the per-incidence
control of :func:`simulate.fiber.volume_brdf`, same definition), for ``mc`` the target of the
ray tracer, and for ``auto`` it is also the tolerated MODEL error of a cheaper method against
the Monte Carlo, measured in the same convention (``(model - MC) / max_lambda(MC)``,
:mod:`simulate.fabric.auto`): a geometry gets the cheapest method whose error, as this
definition measures it, is within the target.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gonio.acquisition.plan import Plan
from gonio.data.dataset import COLUMNS, Dataset, make_dataset, new_meta
from simulate.config import SimulationConfig
from simulate.montecarlo.accuracy import REL_ERR_DEFINITION, check_target, relative_error
from simulate.products import MODELS, Geometries, RunSettings, evaluate
from simulate.provenance import software_versions

__all__ = ["FABRIC_METHODS", "GENERATOR", "fabric_dataset", "is_previous_output"]

log = logging.getLogger(__name__)

FABRIC_METHODS = MODELS + ("auto",)
#: ``meta.json["model"]["generator"]`` of every dataset written here (``simulate fabric`` uses it
#: to recognise its own previous output before overwriting it).
GENERATOR = "simulate fabric"


def fabric_dataset(config: SimulationConfig, plan: Plan, method: str, *,
                   target_rel_err: float | None = None, seed: int | None = None,
                   threads: int | None = None, max_photons: int | None = None,
                   measurable_only: bool = False, progress: bool = False, max_seconds: float = 0.0) -> Dataset:
    """Evaluate the fabric model ``method`` at ``plan``'s geometries and wavelengths.

    Parameters
    ----------
    config : SimulationConfig
        The fiber, fabric and method settings (:func:`simulate.config.load_config`).
    plan : gonio.acquisition.plan.Plan
        The geometries and wavelengths to evaluate the model at.
    method : {"summation", "classic", "mc", "auto"}
        ``mc``: Monte Carlo ray tracing of the config's woven micro-element (:mod:`simulate.raytrace`).
        ``auto``: per geometry the cheapest method whose error against the Monte Carlo reference
        (the bench's "where methods fail" study, :mod:`simulate.fabric.auto`) is within the target;
        ``meta.json["model"]["method_per_geometry"]`` records which method produced each geometry.
    target_rel_err, seed, threads, max_photons
        Override the config's method settings (None: the config's). ``threads`` 0 means all that
        numba allows (``NUMBA_NUM_THREADS``), as ``threads = 0`` in a config.
    measurable_only : bool
        Skip the plan's beam-blocked geometries (see the module docstring).
    progress : bool
        Progress bar of the fiber Monte Carlo (tqdm).
    max_seconds : float
        ``mc``: the ray tracer's time budget in seconds (0: none); ``meta.json``'s ``fiber_info`` says
        which budget ended the run.

    Returns
    -------
    gonio.data.dataset.Dataset
        Kind ``"simulated"``, not yet written (:func:`gonio.data.dataset.write_dataset`).
    """
    if method not in FABRIC_METHODS:
        raise ValueError(f"method must be one of {', '.join(FABRIC_METHODS)}, got {method!r}")
    target = check_target(config.target_rel_err if target_rel_err is None else target_rel_err, "target_rel_err")
    seed = config.seed if seed is None else int(seed)
    threads = config.threads if threads is None else (threads or None)   # 0 = all, as in the config
    max_photons = config.max_photons if max_photons is None else max_photons

    geometries = plan.geometries(measurable_only=measurable_only)
    wavelengths = np.asarray(plan.wavelengths_nm, float)
    theta_i = geometries["theta_i"].to_numpy(float)
    phi_i = geometries["phi_i"].to_numpy(float)
    theta_o = geometries["theta_o"].to_numpy(float)
    phi_o = geometries["phi_o"].to_numpy(float)
    fiber = config.fiber(wavelengths)
    started = time.perf_counter()
    model: dict[str, Any] = {"generator": GENERATOR, "name": f"fabric {method}", "method": method,
                             "fiber_route": config.route}
    settings = RunSettings(target=target, seed=seed, threads=threads, max_photons=max_photons, progress=progress,
                           max_seconds=max_seconds)
    photons: int | None      # None: the method counts no photons (classic)
    if method == "auto":
        from simulate.fabric import auto as methods_mod

        chosen, source = methods_mod.choose(theta_i, phi_i, theta_o, phi_o, target,
                                            errors=methods_mod.errors_for(config))
        beta = np.zeros((theta_i.size, wavelengths.size))
        u_beta = np.zeros_like(beta)
        n = np.ones(beta.shape, dtype=np.int64)
        photons = 0
        fiber_seconds = 0.0
        fiber_info = {}
        for m in methods_mod.CHEAPEST_FIRST:
            rows = np.nonzero(chosen == m)[0]
            if rows.size == 0:
                continue
            est = evaluate(m, config, fiber, Geometries(theta_i[rows], phi_i[rows], theta_o[rows], phi_o[rows]),
                           wavelengths, settings)
            beta[rows], u_beta[rows], n[rows] = est.beta, est.u_beta, est.n
            photons += int(est.photons or 0)
            fiber_seconds += est.seconds
            fiber_info[m] = est.info
            model[m] = est.model
        model.update({"method_per_geometry": chosen.tolist(), "method_errors": source,
                      "methods_used": {m: int(np.count_nonzero(chosen == m)) for m in methods_mod.CHEAPEST_FIRST}})
    else:
        est = evaluate(method, config, fiber, Geometries(theta_i, phi_i, theta_o, phi_o), wavelengths, settings)
        beta, u_beta, n, photons, fiber_info, fiber_seconds = (est.beta, est.u_beta, est.n, est.photons, est.info,
                                                               est.seconds)
        model.update(est.model)
    seconds = time.perf_counter() - started

    g = geometries.loc[geometries.index.repeat(wavelengths.size)].reset_index(drop=True)
    table = pd.DataFrame({"theta_i": g["theta_i"], "phi_i": g["phi_i"], "theta_o": g["theta_o"],
                          "phi_o": g["phi_o"], "wavelength_nm": np.tile(wavelengths, len(geometries)),
                          "beta": beta.ravel(), "u_beta": u_beta.ravel(), "n": n.ravel()},
                         columns=list(COLUMNS))
    # The name labels the dataset in reports: say which model and config produced it. A plan made for this
    # config's sample (the same name: red-cotton at red-cotton, green-felt at green-felt) names the sample;
    # any other plan only lends its geometries and wavelengths (`--plan` defaults to red-cotton), so the
    # sample simulated is the config's and a green felt is not labelled "red cotton, woven cotton".
    if plan.name == config.name:
        sample = dict(plan.sample)
        sample["name"] = f"{plan.sample.get('name', plan.name)}: {method} model ({config.name})"
    else:
        sample = {"name": f"{config.name}: {method} model", "material": config.description or config.name,
                  "geometry_from": plan.name}
    sample["simulated_from"] = config.name
    model.update({"config": config.name, "rms_slope": config.rms_slope, "n_host": config.n_host,
                  "radius_um": config.radius_um, "cell_width_deg": config.cell_width_deg,
                  "polarisation": "ignored (unpolarised Fresnel at every interface)"})
    provenance = {
        "command": GENERATOR,
        "config": config.provenance(),
        "plan": {"name": plan.name, "path": str(plan.path), "sha256": plan.sha256},
        "seed": seed,
        "target_rel_err": target,
        "rel_err": relative_error(beta, u_beta),
        "rel_err_definition": REL_ERR_DEFINITION,
        "photons": photons,
        "seconds": seconds,
        "fiber_seconds": fiber_seconds,
        "threads": threads,
        "max_photons": max_photons,
        "geometries": int(len(geometries)),
        "beam_blocked": "skipped" if measurable_only else "simulated",
        "fiber_info": fiber_info,
        "versions": software_versions(),
    }
    meta = new_meta("simulated", sample, model, provenance)
    return make_dataset(table, meta)


def is_previous_output(out: Path) -> bool:
    """True when the folder ``out`` holds a previous ``simulate fabric`` output: its ``meta.json`` says so.

    Also recognised: ``radiance.csv`` beside a ``.meta.json.XXXXXXXX.tmp`` that says so, what an output
    written file by file leaves when its run is killed between the two renames.
    """
    out = Path(out)
    candidates = [out / "meta.json"]
    if not candidates[0].exists() and (out / "radiance.csv").is_file():
        candidates = sorted(out.glob(".meta.json.*.tmp"))
    for path in candidates:
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if (isinstance(meta, dict) and meta.get("kind") == "simulated"
                and isinstance(meta.get("model"), dict) and meta["model"].get("generator") == GENERATOR):
            return True
    return False
