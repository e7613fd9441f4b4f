"""The ``nee`` and ``beam`` routes and the volume term of a fiber (package docstring of :mod:`simulate.fiber`)."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from simulate.fiber.bssrdf import bssrdf_for_beam, bssrdf_route, grid_cells
from simulate.fiber.model import (
    METHODS,
    BRDFEstimate,
    Fiber,
    as_directions,
    as_wavelengths,
    point_outputs,
    range_outputs,
    surface_brdf,
)
from simulate.fiber.spectral import direction_keys, group_walk, run_seed, spectral_optics, wavelength_groups
from simulate.montecarlo import geometry as G
from simulate.montecarlo import tallies as T
from simulate.montecarlo.accuracy import (
    check_budget,
    mean_and_error,
    relative_error,
    run_controlled,
)
from simulate.montecarlo.transport import DEFAULT_MAX_EVENTS, ParameterError, make_control, make_inputs

__all__ = ["beam_route", "volume_brdf", "fiber_brdf", "normal_albedo"]

log = logging.getLogger(__name__)


def _beam_source(w_in: np.ndarray) -> tuple[np.ndarray, float]:
    """The BEAM source row for ``w_in`` and ``|w_perp|`` (refused along the axis)."""
    d_perp = math.hypot(w_in[1], w_in[2])
    if d_perp < 1e-9:
        raise ParameterError("w_in is parallel to the fiber axis: a beam along the axis never enters")
    return np.array([float(G.BEAM), w_in[0], w_in[1], w_in[2], 0.0]), d_perp


def _projected_solid_angle(outputs: np.ndarray) -> np.ndarray:
    return 0.5 * (outputs[:, 4] ** 2 - outputs[:, 3] ** 2) * (outputs[:, 6] - outputs[:, 5])


def beam_route(fiber, w_in, outputs, medium, walk_phase, targets, method, control, target, max_photons,
               seed, threads, progress):
    """NEE or binned beam route for one incident direction and one wavelength group.

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_in : numpy.ndarray
        ``[3]`` incident direction in the fiber frame.
    outputs : numpy.ndarray
        ``[n_out, 8]`` output rows (:func:`range_outputs`).
    medium : numpy.ndarray
        The kernel's medium row of the walk (:func:`simulate.fiber.spectral.group_walk`, or targets of
        one's own: :mod:`simulate.fiber.absorption`).
    walk_phase : PhaseArrays
        The phase function walked.
    targets : SpectralTargets
        The scored wavelengths' optics.
    control : numpy.ndarray
        The kernel's control row (:func:`simulate.montecarlo.transport.make_control`).
    method : {"nee", "beam"}
        Next-event estimates or binned exits.
    target : float
        Target relative standard error.
    max_photons : int
        Photon budget.
    seed : int
        Random seed.
    threads : int or None
        Threads (results do not depend on it).
    progress : callable or None
        Called with ``(photons, rel_err)`` after each round.

    Returns
    -------
    R, u : numpy.ndarray
        ``[n_out, n_spec]`` volume BRDF of cell B and its standard error.
    run : Run
        The controlled run (:class:`simulate.montecarlo.accuracy.Run`).
    """
    source, d_perp = _beam_source(w_in)
    n_out = outputs.shape[0]
    ranged = bool(np.any(outputs[:, 4] > outputs[:, 3]) or np.any(outputs[:, 6] > outputs[:, 5]))
    omega = _projected_solid_angle(outputs)
    if method == "beam" and not np.all(omega > 0):
        raise ParameterError("the binned beam route needs direction ranges of non-zero size")
    n_spec = targets.mu_a.size
    scale = 2.0 * d_perp / (2.0 * fiber.half_width)
    if method == "nee":
        tally, params = (T.CYLINDER_OUTPUTS, np.array([float(T.FILTER_UNSCATTERED), float(n_out)])) if ranged else (
            T.NONE, None)
        vertex = T.V_CYLINDER_NEE
    else:
        tally, params = T.CYLINDER_OUTPUTS, np.array([float(T.FILTER_ALL), float(n_out)])
        vertex = T.V_NONE
    inp = make_inputs(G.CYLINDER, np.array([fiber.radius_um]), source, medium, walk_phase, control,
                      tally, params, vertex, outputs, targets)
    n_exit = inp.n_exit_bins

    def estimate(bins, n):
        mean, u = mean_and_error(bins, n)
        mean = mean.reshape(-1, n_spec)
        u = u.reshape(-1, n_spec)
        if method == "nee":
            value = mean[n_exit:] * scale
            err2 = (u[n_exit:] * scale) ** 2
            if n_exit:
                value = value + mean[:n_exit] * scale / omega[:, None]
                err2 = err2 + (u[:n_exit] * scale / omega[:, None]) ** 2
            return value, np.sqrt(err2)
        return mean * scale / omega[:, None], u * scale / omega[:, None]

    run = run_controlled(inp, estimate, target, max_photons, seed, threads, progress=progress)
    value, u = estimate(run.bins, run.photons)
    return value, u, run



def volume_brdf(
    fiber: Fiber,
    w_in: np.ndarray,
    w_out: np.ndarray | None = None,
    wavelengths_nm: Any = None,
    *,
    method: str = "nee",
    outputs: np.ndarray | None = None,
    target_rel_err: float = 0.01,
    max_photons: int | None = None,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = False,
    bssrdf_bins: tuple[int, int] = (9, 18),
    white: bool = True,
) -> BRDFEstimate:
    """Volume term ``R_vol,B(w_in, w_out)`` of the top cell B, per wavelength (module docstring).

    Parameters
    ----------
    fiber : Fiber
        The fiber (radius, medium, dye, refractive index).
    w_in : numpy.ndarray
        ``[P, 3]`` unit vectors towards the light in the fiber frame (anywhere but along the axis).
    w_out : numpy.ndarray, optional
        ``[P, 3]`` point directions (``w_out[:, 2] > 0``), paired with ``w_in``.
    wavelengths_nm : numpy.ndarray
        ``[L]`` vacuum wavelengths.
    method : {"nee", "beam", "bssrdf"}
        Estimator (module docstring).
    outputs : numpy.ndarray, optional
        ``[P, 8]`` output rows (:func:`range_outputs`) instead of ``w_out``: direction ranges, for
        the binned routes and for comparing routes on exactly the same average. For ``bssrdf``
        the ranges must be cells of its ``bssrdf_bins`` grid.
    target_rel_err : float
        Target RMS relative standard error per incident direction and wavelength group.
    max_photons : int, optional
        Photon budget per incident direction and group (default 100 / target^2, at least 10^6).
    seed : int
        Seed (each incident direction and group gets its own streams).
    threads : int, optional
        Threads (results do not depend on it).
    progress : bool
        Show a progress bar (tqdm) with the achieved error.
    bssrdf_bins : (int, int)
        ``(n_mu, n_phi)`` direction grid of the BSSRDF table (route ``bssrdf``).
    white : bool
        Walk without absorption and apply it by re-weighting (default). False walks the
        absorbing medium of each group's reference wavelength (for validation: give one
        wavelength per call).

    Returns
    -------
    BRDFEstimate
        ``R``, ``u_R`` as ``[P, L]``.
    """
    t0 = time.perf_counter()
    if method not in METHODS:
        raise ParameterError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    wl = as_wavelengths(wavelengths_nm)
    w_in = as_directions("w_in", w_in)
    if outputs is None:
        if w_out is None:
            raise ParameterError("give w_out (point directions) or outputs (direction ranges)")
        w_out = as_directions("w_out", w_out)
        if w_out.shape != w_in.shape:
            raise ParameterError("w_in and w_out must pair up: both of shape [P, 3]")
        if np.any(w_out[:, 2] <= 0):
            raise ParameterError("w_out must lie above the cell's tangent plane (w_out_z > 0)")
        outputs = point_outputs(w_out, fiber.half_width)
    else:
        outputs = np.atleast_2d(np.asarray(outputs, dtype=float))
        if outputs.shape != (w_in.shape[0], 8):
            raise ParameterError("outputs must have one row of 8 columns per w_in")
    target_rel_err, max_photons = check_budget(target_rel_err, max_photons)
    optics = spectral_optics(fiber, wl)
    groups = wavelength_groups(optics)
    control = make_control()
    P = w_in.shape[0]
    R = np.zeros((P, wl.size))
    u_R = np.zeros((P, wl.size))
    photons = 0
    capped = 0
    energy = []
    keys = direction_keys(w_in)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(keys) * len(groups), desc=f"fiber {method}", unit="run")
    for d, (key, rows) in enumerate(keys.items()):
        win = np.array(key)
        out_rows = outputs[rows]
        for gi, group in enumerate(groups):
            medium, walk_phase, targets = group_walk(fiber, optics, group, white=white)
            stream = run_seed(seed, d, gi)
            if method == "bssrdf":
                n_mu, n_phi = bssrdf_bins
                mu_i, phi_i, omega = grid_cells(out_rows, n_mu, n_phi)
                table = bssrdf_for_beam(fiber, win, medium, walk_phase, targets, control, n_mu, n_phi,
                                         target_rel_err, max_photons, stream, threads)
                value, u = bssrdf_route(fiber, win, (mu_i, phi_i), table, omega[:, None])
                photons += table["photons"]
            else:
                value, u, run = beam_route(fiber, win, out_rows, medium, walk_phase, targets, method, control,
                                                 target_rel_err, max_photons, stream, threads, None)
                photons += run.photons
                capped += int(run.scal[T.S_CAPPED])
                n = run.scal[T.S_LAUNCHED]
                energy.append({
                    "entered": run.scal[T.S_ENTERED] / n, "exited": run.scal[T.S_EXIT0] / n,
                    "specular": run.scal[T.S_SPECULAR] / n,
                })
            R[np.ix_(np.asarray(rows), group)] = value
            u_R[np.ix_(np.asarray(rows), group)] = u
            if bar is not None:
                bar.update(1)
                bar.set_postfix(rel_err=f"{relative_error(R, u_R):.4f}")
    if bar is not None:
        bar.close()
    if capped:
        log.warning("%d photons reached the event cap (%d events) and were stopped", capped, DEFAULT_MAX_EVENTS)
    seconds = time.perf_counter() - t0
    info = {
        "method": method, "seed": int(seed), "groups": [wl[g].tolist() for g in groups],
        "rel_err": relative_error(R, u_R), "target_rel_err": float(target_rel_err),
        "incident_directions": len(keys), "capped_photons": capped, "energy": energy[:8],
        "cell_width_deg": fiber.cell_width_deg,
    }
    return BRDFEstimate(R, u_R, photons, seconds, info)


def fiber_brdf(fiber: Fiber, w_in: np.ndarray, w_out: np.ndarray, wavelengths_nm: np.ndarray,
               **kwargs: Any) -> BRDFEstimate:
    """``R_B = R_surf + R_vol`` (surface term exact, volume term by :func:`volume_brdf`).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_in, w_out : numpy.ndarray
        ``[P, 3]`` paired incident and exit directions in the fiber frame.
    wavelengths_nm : numpy.ndarray
        Vacuum wavelengths (nm).
    **kwargs
        Passed to :func:`volume_brdf`.

    Returns
    -------
    BRDFEstimate
        The sum and the volume term's standard error.
    """
    vol = volume_brdf(fiber, w_in, w_out, wavelengths_nm, **kwargs)
    surf = surface_brdf(fiber, w_in, w_out)
    return BRDFEstimate(vol.R + surf[:, None], vol.u_R, vol.photons, vol.seconds, {**vol.info, "surface": True})


def normal_albedo(
    fiber: Fiber, wavelengths_nm: np.ndarray, *, target_rel_err: float = 0.01, seed: int = 0,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Volume albedo of cell B under normal incidence ``rho(lambda)`` and its standard error.

    ``rho = int R_vol,B(z, w_o) cos(theta_o) dOmega_o``: the fraction of the irradiance on B that
    leaves B through its volume (the classic model's Lambertian albedo), from the binned beam
    route with one output range covering B's whole hemisphere (``Omega_proj = pi``).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    wavelengths_nm : numpy.ndarray
        Vacuum wavelengths (nm).
    target_rel_err : float
        Target relative standard error.
    seed : int
        Random seed.
    threads : int, optional
        Threads (results do not depend on it).

    Returns
    -------
    rho, u_rho : numpy.ndarray
        ``[L]`` albedo and its standard error.
    """
    out = range_outputs([0.0], [1.0], [-math.pi], [math.pi], fiber.half_width)
    est = volume_brdf(fiber, np.array([[0.0, 0.0, 1.0]]), None, wavelengths_nm, method="beam", outputs=out,
                      target_rel_err=target_rel_err, seed=seed, threads=threads)
    return est.R[0] * math.pi, est.u_R[0] * math.pi
