"""The Monte Carlo slab: diffuse reflectance and total transmittance (MCML's conventions).

:func:`run_slab` validates its inputs, packs them for the compiled kernel
(:mod:`simulate.montecarlo.transport`), runs the batches and returns a :class:`SlabResult`; the
slab ``-d <= z <= 0`` is lit at its top face by a collimated beam. ``Rd`` excludes the specular
surface reflection ``Rsp`` (docs/physics.md section 3).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.results import SlabAngular, SlabResult, bins_stderr, energy_balance, stderr
from simulate.montecarlo.transport import (
    DEFAULT_BATCH_SIZE,
    DEFAULT_MAX_EVENTS,
    DEFAULT_SURVIVAL,
    DEFAULT_WEIGHT_THRESHOLD,
    ParameterError,
    execute,
    finite_pos,
    log_cap,
    make_control,
    make_inputs,
    medium_row,
    positive_int,
)

__all__ = ["run_slab"]


def run_slab(
    mu_a: float,
    mu_s: float,
    g: float | None = None,
    phase_table: Any = None,
    n: float = 1.0,
    thickness: float = 1.0,
    photons: int = 100_000,
    seed: int = 0,
    theta_i_deg: float = 0.0,
    threads: int | None = None,
    angular_bins: tuple[int, int] | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    max_events: int = DEFAULT_MAX_EVENTS,
    weight_threshold: float = DEFAULT_WEIGHT_THRESHOLD,
    survival: float = DEFAULT_SURVIVAL,
) -> SlabResult:
    r"""Diffuse reflectance and total transmittance of a slab in air (docs/physics.md section 3).

    The slab ``-d <= z <= 0`` (index ``n``, outside index 1) is lit at its top face by a
    collimated beam at polar angle ``theta_i`` in the x-z plane. Each photon refracts in with
    weight ``1 - F(theta_i)``, walks with exponential free paths (mean ``1 / mu_t``), implicit
    capture ``w *= mu_s / mu_t`` and Russian roulette, and leaves with Fresnel/Snell at the faces.

    Parameters
    ----------
    mu_a, mu_s : float
        Absorption and scattering coefficients (1/length, >= 0).
    g : float, optional
        Henyey-Greenstein asymmetry in (-1, 1); isotropic when neither ``g`` nor
        ``phase_table`` is given.
    phase_table : PhaseTable or array_like, optional
        Inverse-CDF table ``cos_table`` (``simulate.optics.phase.PhaseTable`` or the array itself).
    n : float
        Refractive index of the slab (outside: 1).
    thickness : float
        Slab thickness ``d`` (length, same unit as ``1/mu``).
    photons : int
        Photons launched.
    seed : int
        Seed of the random streams (>= 0).
    theta_i_deg : float
        Incidence angle in degrees, in [0, 90); 90 (grazing) is an error: no light enters.
    threads : int, optional
        Threads for this run (default: numba's current setting). Results do not depend on it.
    angular_bins : (int, int), optional
        ``(n_mu, n_phi)``: also tally exits per direction bin (:class:`SlabAngular`).
    batch_size : int
        Photons per batch (part of the definition of the random streams).
    max_events : int
        Cap on free-path steps per photon (a guard; capped photons are counted).
    weight_threshold, survival : float
        Russian roulette below ``weight_threshold``: survive with probability ``survival``.

    Returns
    -------
    SlabResult
        ``Rd`` (without the specular ``Rsp``), ``Tt`` (= unscattered ``Tu`` + diffuse),
        standard errors ``u_Rd``, ``u_Tt``, timing, events per photon, capped count and the
        energy balance.

    Raises
    ------
    ParameterError
        (a ``ValueError``) on invalid parameters; the message names the parameter.

    Examples
    --------
    >>> r = run_slab(10.0, 90.0, g=0.75, n=1.0, thickness=0.02, photons=20_000, seed=1)
    >>> abs(r.Rd - 0.09739) < 5 * r.u_Rd and abs(r.Tt - 0.66096) < 5 * r.u_Tt
    True
    """
    medium, walk_phase = medium_row(mu_a, mu_s, g, phase_table, n)
    d = finite_pos("thickness", thickness)
    photons = positive_int("photons", photons)
    batch_size = positive_int("batch_size", batch_size)
    if isinstance(seed, bool) or int(seed) != seed or not 0 <= int(seed) < 2**63:
        raise ParameterError(f"seed must be an integer in [0, 2^63), got {seed!r}")
    theta = float(theta_i_deg)
    if not math.isfinite(theta) or not 0.0 <= theta <= 90.0:
        raise ParameterError(f"theta_i_deg must be in [0, 90) degrees, got {theta_i_deg!r}")
    if theta == 90.0:
        raise ParameterError(
            "theta_i_deg = 90 is grazing incidence: no light crosses the surface; use an angle below 90"
        )
    control = make_control(max_events, weight_threshold, survival)
    t = math.radians(theta)
    source = np.array([0.0, math.sin(t), 0.0, math.cos(t)])
    if angular_bins is None:
        mode, params = T.NONE, np.zeros(1)
    else:
        n_mu, n_phi = (positive_int("angular_bins", int(v), 100_000) for v in angular_bins)
        mode, params = T.SLAB_DIRECTIONS, np.array([float(n_mu), float(n_phi)])
    inp = make_inputs(G.SLAB, np.array([d]), source, medium, walk_phase, control, mode, params)
    scal, bins, seconds = execute(inp, photons, int(seed), threads, batch_size)
    capped = log_cap(scal, int(control[K.C_MAX_EVENTS]))
    angular = None
    if mode == T.SLAB_DIRECTIONS:
        n_mu, n_phi = int(params[0]), int(params[1])
        s = bins[:, 0].reshape(2, n_mu, n_phi)
        s2 = bins[:, 1].reshape(2, n_mu, n_phi)
        u = bins_stderr(s, s2, photons)
        angular = SlabAngular(
            mu_edges=np.linspace(0.0, 1.0, n_mu + 1),
            phi_edges=np.linspace(-math.pi, math.pi, n_phi + 1),
            reflected=s[0] / photons,
            u_reflected=u[0],
            transmitted=s[1] / photons,
            u_transmitted=u[1],
        )
    return SlabResult(
        Rd=scal[T.S_EXIT0] / photons,
        Tt=scal[T.S_EXIT1] / photons,
        u_Rd=stderr(scal[T.S_EXIT0], scal[T.S_EXIT0_SQ], photons),
        u_Tt=stderr(scal[T.S_EXIT1], scal[T.S_EXIT1_SQ], photons),
        Tu=scal[T.S_UNSCATTERED1] / photons,
        Rsp=scal[T.S_SPECULAR] / photons,
        absorbed=scal[T.S_ABSORBED] / photons,
        photons=photons,
        seconds=seconds,
        events_per_photon=scal[T.S_EVENTS] / photons,
        scatterings_per_photon=scal[T.S_SCATTERINGS] / photons,
        capped=capped,
        energy=energy_balance(scal, 2),
        theta_i_deg=theta,
        seed=int(seed),
        angular=angular,
    )
