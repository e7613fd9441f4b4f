"""The virtual goniophotometer: a fabric model evaluated at a plan's geometries, as a dataset.

``simulate fabric CONFIG --method classic|summation|mc --out DIR [--geometry PLAN]`` (docs/physics.md
section 7) evaluates the chosen fabric model (:mod:`simulate.fabric`) at the geometries and
wavelengths of an acquisition plan (:mod:`gonio.plan`; default: the shipped ``red-cotton`` plan)
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
SHA-256), the seed, the requested and achieved relative error, photons, seconds, the fiber
route's own ``info`` and the software versions.
"""

from __future__ import annotations

import logging
import os
import platform
import time
from typing import Any

import numpy as np
import pandas as pd

from gonio.data.dataset import COLUMNS, Dataset, make_dataset, new_meta
from gonio.acquisition.plan import Plan
from simulate import fabric as fab
from simulate.config import SimulationConfig

__all__ = ["FABRIC_METHODS", "GENERATOR", "fabric_dataset", "achieved_rel_err", "jsonable", "software_versions"]

log = logging.getLogger(__name__)

FABRIC_METHODS = ("summation", "classic", "mc", "auto")
#: ``meta.json["model"]["generator"]`` of every dataset written here (``simulate fabric`` uses it
#: to recognise its own previous output before overwriting it).
GENERATOR = "simulate fabric"


def software_versions() -> dict:
    """Versions of the packages a simulation result depends on."""
    import numba
    import scipy

    import gonio

    out = {"fabric-optics": gonio.__version__, "python": platform.python_version(),
           "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba.__version__}
    try:
        import miepython

        out["miepython"] = getattr(miepython, "__version__", "unknown")
    except ImportError:  # pragma: no cover - a declared dependency
        pass
    return out


def jsonable(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, non-finite floats to None, others to str."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if obj is None or isinstance(obj, (str, int, bool)):
        return obj
    return str(obj)


def achieved_rel_err(beta: np.ndarray, u_beta: np.ndarray) -> dict:
    """RMS and largest relative standard error ``u_beta / beta`` over the values with ``beta > 0``."""
    beta = np.asarray(beta, float)
    u = np.asarray(u_beta, float)
    ok = beta > 0
    if not ok.any():
        return {"rms": None, "max": None}
    rel = u[ok] / beta[ok]
    return {"rms": float(np.sqrt(np.mean(rel ** 2))), "max": float(rel.max())}


def _fiber_photons(info: dict) -> int | None:
    for key in ("photons", "photons_total"):
        if isinstance(info.get(key), (int, np.integer)):
            return int(info[key])
    return None


def _evaluate(method: str, config: SimulationConfig, fiber: Any, theta_i: np.ndarray, phi_i: np.ndarray,
              theta_o: np.ndarray, phi_o: np.ndarray, wavelengths: np.ndarray, *, target: float, seed: int,
              threads: Any, max_photons: Any, progress: bool, max_seconds: float):
    """One fabric model at G geometries: ``beta, u_beta, n [G, L]``, photons, info, seconds, model fields."""
    from simulate import fiber as fiber_mod

    started = time.perf_counter()
    # --- issue 19: a config with [structure] sums over the fabric's visible fibers (simulate.structure)
    if method == "summation" and getattr(config, "structure", None) is not None:
        return _structured(config, fiber, theta_i, phi_i, theta_o, phi_o, wavelengths, target=target, seed=seed,
                           threads=threads, max_photons=max_photons)
    # --- end issue 19
    if method == "summation":
        pairs = fab.FiberPairs.from_angles(theta_i, phi_i, theta_o, phi_o)
        log.info("summation: %d geometries -> %d unique fiber-frame pairs x %d wavelengths",
                 theta_i.size, pairs.n_unique, wavelengths.size)
        est = fiber_mod.volume_brdf(fiber, pairs.w_in, pairs.w_out, wavelengths, method=config.method,
                                    target_rel_err=target, max_photons=max_photons, seed=seed,
                                    threads=threads, progress=progress)
        r_surf = np.asarray(fiber_mod.surface_brdf(fiber, pairs.w_in, pairs.w_out), float)
        R_B = np.asarray(est.R, float) + r_surf[:, None]
        beta, u_beta = fab.summation_from_table(pairs, R_B, est.u_R)
        n = np.full(beta.shape, max(int(est.photons), 1))
        return (beta, u_beta, n, int(est.photons), jsonable(dict(est.info)), float(est.seconds),
                {"unique_fiber_pairs": pairs.n_unique, "symmetry_reduced": True})
    w_i = fab.directions_deg(theta_i, phi_i)
    w_o = fab.directions_deg(theta_o, phi_o)
    if method == "mc":
        from simulate import weave as weave_mod
        from simulate import woven

        wv = weave_mod.weave_from_config(config)
        mesh = weave_mod.mesh(wv)
        beta, u_beta, mc_info = woven.fabric_beta(
            mesh, fiber, w_i, w_o, wavelengths, target_rel_err=target, max_rays=max_photons or 0,
            seed=seed, threads=threads or (os.cpu_count() or 1), progress=progress, max_seconds=max_seconds)
        n = np.full(beta.shape, max(int(mc_info["rays"]), 1))
        extra = {"weave": {"matrix": wv.matrix.tolist(), "spacing_um": wv.spacing_um, "width_um": wv.width_um,
                           "height_um": wv.height_um, "crimp": wv.crimp},
                 "triangles": int(mesh.faces.shape[0]), "ray_engine": "embree (embreex)",
                 "estimator": "next-event towards each detector direction"}
        return (beta, u_beta, n, int(mc_info["table"]["photons"]), jsonable(mc_info),
                float(mc_info["table"]["seconds"]), extra)
    rho, u_rho = fiber_mod.normal_albedo(fiber, wavelengths, target_rel_err=target, seed=seed, threads=threads)
    rho = np.asarray(rho, float)
    beta = fab.classic_beta(rho, w_i, w_o, config.rms_slope, config.n_host)
    u_beta = np.broadcast_to(np.asarray(u_rho, float)[None, :], beta.shape).copy()
    n = np.ones(beta.shape, dtype=np.int64)
    return (beta, u_beta, n, None, {}, time.perf_counter() - started,
            {"rho_d": rho.tolist(), "u_rho_d": np.asarray(u_rho, float).tolist()})


def _structured(config: SimulationConfig, fiber: Any, theta_i, phi_i, theta_o, phi_o, wavelengths, *, target: float,
                seed: int, threads: Any, max_photons: Any):
    """The structured summation (issue 19, :func:`simulate.structure.structured_beta`), as :func:`_evaluate` returns."""
    from simulate import structure as st
    from simulate import weave as weave_mod

    spec = config.structure
    fab.FiberPairs.from_angles(theta_i, phi_i, theta_o, phi_o)   # the same checks (and warnings) as the summation
    weave = weave_mod.weave_from_config(config) if spec.kind == "woven" else None
    beta, u_beta, info = st.structured_beta(spec, fiber, weave, fab.directions_deg(theta_i, phi_i),
                                            fab.directions_deg(theta_o, phi_o), wavelengths, target_rel_err=target,
                                            seed=seed, threads=threads, max_photons=max_photons, method=config.method)
    n = np.full(beta.shape, max(int(info["photons"]), 1))
    return (beta, u_beta, n, int(info["photons"]), jsonable(info), float(info["seconds"]),
            {"structure": jsonable(info["structure"]), "facets": jsonable(info["facets"])})


def fabric_dataset(config: SimulationConfig, plan: Plan, method: str, *,
                   target_rel_err: float | None = None, seed: int | None = None,
                   threads: int | None = None, max_photons: int | None = None,
                   measurable_only: bool = False, progress: bool = False, max_seconds: float = 0.0) -> Dataset:
    """Evaluate the fabric model ``method`` at ``plan``'s geometries and wavelengths.

    Parameters
    ----------
    config : SimulationConfig
    plan : gonio.acquisition.plan.Plan
    method : {"summation", "classic", "mc", "auto"}
        ``mc``: Monte Carlo ray tracing of the config's woven micro-element (:mod:`simulate.woven`).
        ``auto``: per geometry the cheapest method whose error against the Monte Carlo reference
        (the bench's "where methods fail" study, :mod:`simulate.methods`) is within the target;
        ``meta.json["model"]["method_per_geometry"]`` records which method produced each geometry.
    target_rel_err, seed, threads, max_photons
        Override the config's method settings (None: the config's).
    measurable_only : bool
        Skip the plan's beam-blocked geometries (see the module docstring).
    progress : bool
        Progress bar of the fiber Monte Carlo (tqdm).

    Returns
    -------
    gonio.data.dataset.Dataset
        Kind ``"simulated"``, not yet written (:func:`gonio.data.dataset.write_dataset`).
    """
    if method not in FABRIC_METHODS:
        raise ValueError(f"method must be one of {', '.join(FABRIC_METHODS)}, got {method!r}")
    target = config.target_rel_err if target_rel_err is None else float(target_rel_err)
    seed = config.seed if seed is None else int(seed)
    threads = config.threads if threads is None else threads
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
                             "fiber_route": config.method}
    settings: dict[str, Any] = dict(target=target, seed=seed, threads=threads, max_photons=max_photons, progress=progress,
                    max_seconds=max_seconds)
    if method == "auto":
        from simulate import methods as methods_mod

        chosen, source = methods_mod.choose(theta_i, phi_i, theta_o, phi_o, target)
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
            b, u, nn, ph, info, sec, extra = _evaluate(m, config, fiber, theta_i[rows], phi_i[rows], theta_o[rows],
                                                       phi_o[rows], wavelengths, **settings)
            beta[rows], u_beta[rows], n[rows] = b, u, nn
            photons += int(ph or 0)
            fiber_seconds += sec
            fiber_info[m] = info
            model[m] = extra
        model.update({"method_per_geometry": chosen.tolist(), "method_errors": source,
                      "methods_used": {m: int(np.count_nonzero(chosen == m)) for m in methods_mod.CHEAPEST_FIRST}})
    else:
        beta, u_beta, n, photons, fiber_info, fiber_seconds, extra = _evaluate(
            method, config, fiber, theta_i, phi_i, theta_o, phi_o, wavelengths, **settings)
        model.update(extra)
    seconds = time.perf_counter() - started

    g = geometries.loc[geometries.index.repeat(wavelengths.size)].reset_index(drop=True)
    table = pd.DataFrame({"theta_i": g["theta_i"], "phi_i": g["phi_i"], "theta_o": g["theta_o"],
                          "phi_o": g["phi_o"], "wavelength_nm": np.tile(wavelengths, len(geometries)),
                          "beta": beta.ravel(), "u_beta": u_beta.ravel(), "n": n.ravel()},
                         columns=list(COLUMNS))
    sample = dict(plan.sample)
    # the name labels the dataset in reports: say which model and config produced it
    sample["name"] = f"{plan.sample.get('name', plan.name)}: {method} model ({config.name})"
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
        "achieved_rel_err": achieved_rel_err(beta, u_beta),
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
