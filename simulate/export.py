"""A fabric model as a BRDF callable, evaluated on demand, and its export as an RGL ``.bsdf`` file.

``simulate export CONFIG --method classic|summation|mc --out FILE.bsdf`` tabulates the model with
:func:`gonio.data.bsdf_export.export_bsdf`: the model is asked only for the direction pairs the
tensor needs (the retro-reflection curve for the NDF and the warped grid per incidence node),
in one batch each, at the accuracy asked for (``target_rel_err``: the fiber Monte Carlo of the
classic model's albedo, the summation's fiber BRDF, the woven Monte Carlo).

Every import of a ``simulate`` module is inside :func:`_model_functions` (one place to re-point
when the package layout changes). The summation and Monte Carlo models are anisotropic (warp
along x, weft along y); the default isotropic export averages them over the incidence azimuths
:data:`ANISOTROPIC_AZIMUTHS_DEG` (0, 45 deg: the summation is symmetric under 90 deg rotations,
so these two span its azimuthal variation at first order) and says so in the file.
``reduction=4`` (``--anisotropic``) keeps the anisotropy instead: the summation is symmetric
under ``x -> -x`` and ``y -> -y`` (the fiber cylinder's mirror symmetries, docs/physics.md), so
incidence azimuths over 90 deg suffice; the woven Monte Carlo of a plain weave is so up to its
noise; a twill is not (use ``reduction=1``, every azimuth).

Monte Carlo noise: a model value with standard error ``u`` enters the table as is; the exported
file's error against the *exact* model is the tabulation error plus that noise.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["ANISOTROPIC_AZIMUTHS_DEG", "EXPORT_METHODS", "export_model", "model_brdf"]

EXPORT_METHODS = ("classic", "summation", "mc")
ANISOTROPIC_AZIMUTHS_DEG = (0.0, 45.0)
#: Retro-reflection directions asked of a Monte Carlo model for the NDF (each is one run).
RETRO_SAMPLES_MC = 8


def _model_functions() -> dict[str, Any]:
    """The public entry points of the fabric models this module uses (the ONE import site)."""
    from simulate import fabric, fiber, raytrace
    from simulate.config import weave_from_config
    from simulate.geometry.mesh import mesh
    from simulate.optics.fresnel import OpticsDomainWarning

    return {"domain_warning": OpticsDomainWarning, "classic_beta": fabric.classic_beta, "summation_beta": fabric.summation_beta,
            "normal_albedo": fiber.normal_albedo, "volume_brdf": fiber.volume_brdf,
            "surface_brdf": fiber.surface_brdf, "weave_from_config": weave_from_config,
            "weave_mesh": mesh, "woven_fabric_beta": raytrace.fabric_beta}


def model_brdf(config: Any, method: str, wavelengths_nm: Any, *, target_rel_err: float | None = None,
               seed: int | None = None, threads: int | None = None, max_photons: int | None = None,
               progress: bool = False) -> tuple[Callable[[np.ndarray, np.ndarray], np.ndarray], dict]:
    """``beta(w_i, w_o) -> (N, L)`` of the fabric model ``method`` of ``config`` at ``wavelengths_nm``.

    The classic model's albedo ``rho_d`` is computed once (fiber Monte Carlo at
    ``target_rel_err``); the summation and Monte Carlo models run per call on exactly the pairs
    given. Returns the callable and a dict of what it used (for the file's provenance).
    """
    if method not in EXPORT_METHODS:
        raise ValueError(f"method must be one of {', '.join(EXPORT_METHODS)}, got {method!r}")
    fn = _model_functions()
    wl = np.asarray(wavelengths_nm, float)
    target = config.target_rel_err if target_rel_err is None else float(target_rel_err)
    seed = config.seed if seed is None else int(seed)
    threads = config.threads if threads is None else threads
    max_photons = config.max_photons if max_photons is None else max_photons
    from simulate.config import require_single_population

    require_single_population(config, "simulate export")
    fib = config.fiber(wl)
    info: dict[str, Any] = {"method": method, "config": config.name, "target_rel_err": target,
                            "seed": seed, "wavelengths_nm": wl.tolist()}
    if method == "classic":
        rho, u_rho = fn["normal_albedo"](fib, wl, target_rel_err=target, seed=seed, threads=threads)
        rho = np.asarray(rho, float)
        info["rho_d"] = rho.tolist()

        def classic(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
            return fn["classic_beta"](rho, wi, wo, config.rms_slope, config.n_host)
        return classic, info
    if method == "summation":
        def r_b(a_in: np.ndarray, a_out: np.ndarray) -> np.ndarray:
            est = fn["volume_brdf"](fib, a_in, a_out, wl, method=config.route, target_rel_err=target,
                                    max_photons=max_photons, seed=seed, threads=threads, progress=progress)
            return np.asarray(est.R, float) + np.asarray(fn["surface_brdf"](fib, a_in, a_out), float)[:, None]

        def summation(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
            return fn["summation_beta"](r_b, wi, wo)
        return summation, info
    wv = fn["weave_from_config"](config)
    mesh = fn["weave_mesh"](wv)

    def mc(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        beta, _u, _run = fn["woven_fabric_beta"](mesh, fib, wi, wo, wl, target_rel_err=target,
                                                 max_rays=max_photons or 0, seed=seed,
                                                 threads=threads or (os.cpu_count() or 1), progress=progress)
        return beta
    return mc, info


def export_model(config: Any, method: str, out: str | os.PathLike, *, wavelengths_nm: Any = None,
                 rgb: bool = False, res: int = 64, incidences: int = 16,
                 target_rel_err: float | None = None, seed: int | None = None, threads: int | None = None,
                 max_photons: int | None = None, check_pairs: int = 0, reduction: int = 0, n_phi_i: int = 5,
                 progress: bool = False):
    """Tabulate and write the model (spectral at ``wavelengths_nm``, or linear sRGB if ``rgb``).

    Returns :class:`gonio.data.bsdf_export.ExportResult`.
    """
    import warnings

    from gonio.data.bsdf_export import ExportError, export_bsdf, incidence_nodes
    from gonio.data.colour import spectrum_to_rgb

    wl = np.asarray(config.wavelengths_nm if wavelengths_nm is None else wavelengths_nm, float)
    beta, info = model_brdf(config, method, wl, target_rel_err=target_rel_err, seed=seed,
                            threads=threads, max_photons=max_photons, progress=progress)
    source = beta
    if rgb:
        # linear sRGB (D65) of a spectrum is linear in it: one 3 x L matrix, built on a 5 nm grid
        # (colour-science's ASTM E308 integration needs 1/5/10/20 nm steps) from the spectrum
        # interpolated linearly between the model's wavelengths
        fine = np.arange(np.ceil(wl[0] / 5) * 5, wl[-1] + 1e-9, 5.0)
        if wl.size < 2 or fine.size < 3:
            raise ExportError(f"an RGB export needs wavelengths spanning at least 10 nm, not {wl.tolist()}")
        mat = np.stack([spectrum_to_rgb(fine, np.interp(fine, wl, e)) for e in np.eye(wl.size)], axis=1)

        def source(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
            return np.asarray(beta(wi, wo), float) @ mat.T
    azimuths = (0.0,) if method == "classic" or reduction else ANISOTROPIC_AZIMUTHS_DEG
    symmetry = (f"anisotropic, {n_phi_i} incidence azimuths, mirror symmetry {reduction}" if reduction else
                "isotropic" + ("" if method == "classic" else ", averaged over incidence azimuths 0 and 45 deg"))
    description = (f"{config.name}: {method} fabric model (fabric-optics simulate export; "
                   f"{'linear sRGB D65' if rgb else f'{wl.size} wavelengths'}; {symmetry})")
    # the grazing node is evaluated at 89.5 deg on purpose: the model's near-horizon warning
    # (Cook-Torrance shadowing unreliable there) is known and stated in the module docstring
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=_model_functions()["domain_warning"])
        return export_bsdf(source, out, wavelengths_nm=None if rgb else wl,
                           theta_i_deg=incidence_nodes(incidences), res=res, azimuths_deg=azimuths,
                           description=description,
                           provenance={"model": info, "config": config.provenance()},
                           check_pairs=check_pairs, seed=0 if seed is None else seed,
                           n_retro=32 if method == "classic" else RETRO_SAMPLES_MC,
                           reduction=reduction, n_phi_i=n_phi_i)
