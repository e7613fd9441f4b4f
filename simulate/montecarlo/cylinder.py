"""The Monte Carlo cylinder: photon transport in one infinite circular fiber.

:func:`run_cylinder` lights the cylinder (axis ``+x``) with a parallel beam or at one point, with an
optional ring or core dye profile and scatterers in a skin or a core, and returns a :class:`CylinderResult`: the exited fraction, its
standard error, the energy balance and optional direction bins. The fiber models build on the same
machinery (:mod:`simulate.montecarlo.transport`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.results import CylinderAngular, CylinderResult, bins_stderr, energy_balance, stderr
from simulate.montecarlo.transport import (
    DEFAULT_BATCH_SIZE,
    DEFAULT_MAX_EVENTS,
    DEFAULT_SURVIVAL,
    DEFAULT_WEIGHT_THRESHOLD,
    ParameterError,
    SpectralTargets,
    execute,
    finite_pos,
    log_cap,
    make_control,
    make_inputs,
    medium_row,
    positive_int,
)

__all__ = ["run_cylinder"]


def _place_scatterers(medium: np.ndarray, profile: Any, radius: float) -> None:
    """Write ``run_cylinder``'s ``scatterer_profile`` into the medium row, or a ParameterError naming it."""
    kind, a = profile if isinstance(profile, tuple) and len(profile) == 2 else (None, None)
    if kind not in ("skin", "core") or not (isinstance(a, (int, float)) and 0.0 < a < radius):
        raise ParameterError(f"scatterer_profile must be ('skin' or 'core', inner radius in (0, radius)), got {profile!r}")
    medium[K.M_SCAT_PROFILE] = K.SCAT_SKIN if kind == "skin" else K.SCAT_CORE
    medium[K.M_SCAT_RADIUS] = float(a)


def run_cylinder(
    mu_a: float,
    mu_s: float,
    g: float | None = None,
    phase_table: Any = None,
    n: float = 1.0,
    radius: float = 1.0,
    photons: int = 100_000,
    seed: int = 0,
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0),
    source: str = "beam",
    threads: int | None = None,
    angular_bins: tuple[int, int, int] | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    max_events: int = DEFAULT_MAX_EVENTS,
    weight_threshold: float = DEFAULT_WEIGHT_THRESHOLD,
    survival: float = DEFAULT_SURVIVAL,
    dye_profile: tuple[str, float] | None = None,
    scatterer_profile: tuple[str, float] | None = None,
) -> CylinderResult:
    r"""Photon transport in an infinite circular cylinder (a fiber) with axis ``t = +x``.

    Parameters
    ----------
    mu_a, mu_s, g, phase_table, n
        As in :func:`run_slab`.
    radius : float
        Cylinder radius ``R`` (length).
    photons, seed, threads, batch_size, max_events, weight_threshold, survival
        As in :func:`run_slab`.
    direction : (float, float, float)
        Unit vector ``w_i`` towards the light, in the fiber frame (x = axis, z = normal at
        ``psi = 0``); photons travel along ``-w_i``. Normalised here.
    source : {"beam", "point"}
        ``"beam"``: parallel beam, impact parameter uniform over the projected width
        ``[-R, R]`` (direct beam estimator); ``w_i`` must not be parallel to the axis.
        ``"point"``: all photons enter at ``psi = 0, v = 0``; requires ``w_i . z > 0``.
    angular_bins : (int, int, int), optional
        ``(n_psi, n_mu, n_phi)``: tally exits per ``psi`` x local direction bin
        (:class:`CylinderAngular`).
    dye_profile : (str, float), optional
        ``("ring", a)``: ``mu_a`` absorbs only beyond the radius ``a`` of the axis (a ring-dyed fiber);
        ``("core", a)``: only within it. The photons then walk white (``mu_a = 0``) and carry the absorption
        of their path's dyed length as a weight (:mod:`.kernel`, "Dye profile"); ``exited`` is read from the
        exit bins (``angular_bins``, default one bin), the walk's own bookkeeping (``absorbed``, ``energy``)
        is the white walk's.
    scatterer_profile : (str, float), optional
        ``("skin", a)``: ``mu_s`` scatters only beyond the radius ``a`` of the axis (scatterers in a skin, a
        clear core); ``("core", a)``: only within it (a clear skin). The rest of the fiber is clear (same
        index, same absorption). Walked with null collisions (:mod:`.kernel`, "Scatterer profile"); with
        or without a dye profile.

    Returns
    -------
    CylinderResult
        Exited fraction (without the specular reflection) with standard error, unscattered
        part, timing, events per photon, capped count, energy balance and optional bins.

    Raises
    ------
    ParameterError
        (a ``ValueError``) on invalid parameters; the message names the parameter.
    """
    medium, walk_phase = medium_row(mu_a, mu_s, g, phase_table, n)
    r = finite_pos("radius", radius)
    photons = positive_int("photons", photons)
    batch_size = positive_int("batch_size", batch_size)
    if isinstance(seed, bool) or int(seed) != seed or not 0 <= int(seed) < 2**63:
        raise ParameterError(f"seed must be an integer in [0, 2^63), got {seed!r}")
    w = np.asarray(direction, dtype=float)
    if w.shape != (3,) or not np.all(np.isfinite(w)) or np.linalg.norm(w) == 0.0:
        raise ParameterError(f"direction must be a finite non-zero 3-vector, got {direction!r}")
    w = w / np.linalg.norm(w)
    if source == "beam":
        if math.hypot(w[1], w[2]) < 1e-12:
            raise ParameterError("direction is parallel to the cylinder axis: a beam along the axis never enters")
        mode_code = G.BEAM
    elif source == "point":
        if not w[2] > 0.0:
            raise ParameterError(
                "direction must point above the tangent plane at psi = 0 (w_z > 0) for source='point'; "
                "w_z = 0 is grazing incidence"
            )
        mode_code = G.POINT
    else:
        raise ParameterError(f"source must be 'beam' or 'point', got {source!r}")
    control = make_control(max_events, weight_threshold, survival)
    src = np.array([float(mode_code), w[0], w[1], w[2]])
    if angular_bins is None:
        mode, params = T.NONE, np.zeros(1)
    else:
        n_psi, n_mu, n_phi = (positive_int("angular_bins", int(v), 100_000) for v in angular_bins)
        mode, params = T.CYLINDER_DIRECTIONS, np.array([float(n_psi), float(n_mu), float(n_phi), 1.0, 1.0])
    targets = None
    if scatterer_profile is not None:
        _place_scatterers(medium, scatterer_profile, r)
        if mode == T.NONE:
            mode, params = T.CYLINDER_DIRECTIONS, np.array([1.0, 1.0, 1.0, 1.0, 1.0])
    if dye_profile is not None:
        kind, a = dye_profile if isinstance(dye_profile, tuple) and len(dye_profile) == 2 else (None, None)
        if kind not in ("ring", "core") or not (isinstance(a, (int, float)) and 0.0 < a < r):
            raise ParameterError(f"dye_profile must be ('ring' or 'core', inner radius in (0, radius)), got {dye_profile!r}")
        mu_a_t = float(medium[K.M_MU_A])
        medium[K.M_MU_A] = 0.0
        medium[K.M_DYE_PROFILE] = K.DYE_RING if kind == "ring" else K.DYE_CORE
        medium[K.M_DYE_RADIUS] = float(a)
        targets = SpectralTargets(mu_a=np.array([mu_a_t]), mu_s=np.array([float(medium[K.M_MU_S])]),
                                  phases=[walk_phase], same_phase=np.array([True]), mu_a_dye=np.array([mu_a_t]))
        if mode == T.NONE:
            mode, params = T.CYLINDER_DIRECTIONS, np.array([1.0, 1.0, 1.0, 1.0, 1.0])
    inp = make_inputs(G.CYLINDER, np.array([r]), src, medium, walk_phase, control, mode, params, targets=targets)
    scal, bins, seconds = execute(inp, photons, int(seed), threads, batch_size)
    capped = log_cap(scal, int(control[K.C_MAX_EVENTS]))
    angular = None
    if mode == T.CYLINDER_DIRECTIONS:
        shape = (int(params[0]), int(params[1]), int(params[2]))
        s = bins[:, 0].reshape(shape)
        s2 = bins[:, 1].reshape(shape)
        angular = CylinderAngular(
            psi_centers=2.0 * math.pi * np.arange(shape[0]) / shape[0],
            mu_edges=np.linspace(0.0, 1.0, shape[1] + 1),
            phi_edges=np.linspace(-math.pi, math.pi, shape[2] + 1),
            exits=s / photons,
            u_exits=bins_stderr(s, s2, photons),
        )
    exited, u_exited = scal[T.S_EXIT0] / photons, stderr(scal[T.S_EXIT0], scal[T.S_EXIT0_SQ], photons)
    if targets is not None:      # the profile's absorption is in the bins' weights (a photon exits in one bin)
        exited, u_exited = float(bins[:, 0].sum()) / photons, stderr(float(bins[:, 0].sum()), float(bins[:, 1].sum()), photons)
    return CylinderResult(
        exited=exited,
        u_exited=u_exited,
        unscattered=scal[T.S_UNSCATTERED0] / photons,
        specular=scal[T.S_SPECULAR] / photons,
        absorbed=scal[T.S_ABSORBED] / photons,
        photons=photons,
        seconds=seconds,
        events_per_photon=scal[T.S_EVENTS] / photons,
        scatterings_per_photon=scal[T.S_SCATTERINGS] / photons,
        capped=capped,
        energy=energy_balance(scal, 1),
        direction=(float(w[0]), float(w[1]), float(w[2])),
        source=source,
        seed=int(seed),
        angular=angular,
    )
