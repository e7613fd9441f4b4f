r"""Fiber BRDF (docs/physics.md sections 4-5): volume term by Monte Carlo, surface term by Cook-Torrance.

A fiber is a smooth dielectric cylinder of radius ``R`` and host index ``n`` filled with a
scattering medium (:mod:`simulate.medium`). Frames: the fiber frame has x = the fiber axis
``t`` and z = the outward normal of the cell B at the top of the fiber (``psi = 0``); a fiber
lying in the fabric plane along the warp has the fabric frame. Directions point away from the
surface (``w_in`` towards the light, ``w_out`` towards the detector). Lengths in um.

What a cell's BRDF means (every route estimates exactly this)
--------------------------------------------------------------
Under a parallel beam of irradiance ``E_perp`` (on a plane normal to the beam) from ``w_in``
(anywhere on the sphere: light that entered elsewhere crosses the fiber), the radiance that
leaves the surface cell ``B = {|psi| < dpsi / 2}`` -- per unit area, per unit solid angle
around ``w_out`` measured in the local frame ``(n(psi), t, b = n x t)`` of the point where it
leaves (the cylinder's invariance makes every point's frame equivalent) -- averaged over the
cell, per unit ``E_perp``::

    R_vol,B(w_in, w_out) = <L_o> / E_perp             f = R / cos(theta_in)  (w_in above B)

For a direction RANGE (``mu = cos theta_out`` in [mu_lo, mu_hi], local azimuth
``phi = atan2(w.b, w.t)`` in [phi_lo, phi_hi]) the average is weighted by the projected solid
angle ``cos theta dOmega`` (the binned estimate of radiance). A beam photon stands for the
power ``E_perp 2 R |w_perp| l / N`` over a fiber length ``l`` and ``|B| = R dpsi l``.

Routes
------
``nee`` (next-event, the fast path)
    Parallel beam over the projected width; at every scattering vertex the photon scores the
    light that would leave B in ``w_out`` directly or after any number of internal
    reflections (:func:`simulate.montecarlo.tallies.score_vertex` derives the vertex-to-cell
    geometry through the curved interface and its Jacobian)::

        R = (2 |w_perp| / dpsi) x mean score per photon

    Light that never scatters (the bare-cylinder refraction, a delta on the cone
    ``w_out . t = w_in . t``) has no density at a point direction: it is binned for ranged
    outputs and left out for point outputs (say so where it matters: weakly scattering fibers).
``beam`` (binned)
    The same beam; exits tallied in the cell and the direction range::

        R = (2 |w_perp| / dpsi) x mean exit weight / Omega_proj,   Omega_proj = (mu_hi^2 - mu_lo^2)/2 (phi_hi - phi_lo)

``bssrdf`` (the original method)
    Photons enter ONE cell A under a parallel beam, uniformly over the cell with launch weight
    ``max(w . n, 0)`` (the irradiance on the surface element), exits registered by cell offset
    and local direction: the BSSRDF table, stored by offset (the cylinder's invariance). Then
    the summation of docs/physics.md section 5 over all cells A_i with the illumination indicator::

        R_vol,B(w_in) = sum_i T(w_in^(A_i), B - A_i, bin) / Omega_proj

    ``T`` = mean exit weight per photon (``|A| = |B|``); ``w_in^(A_i)`` is the beam in A_i's
    frame. The incident grid is the beam rotated by multiples of the cell width, so beams whose
    azimuth about the axis is a multiple of ``dpsi`` use no interpolation; other azimuths are
    interpolated linearly between the two neighbouring multiples (the original interpolated
    its incident grid too).

Spectral ("white") Monte Carlo
------------------------------
Absorption is never walked: photons walk without absorption and every score carries the
likelihood ratio of its path for each wavelength (:mod:`simulate.montecarlo.kernel`): with a
wavelength-independent scattering medium that is exactly ``exp(-mu_a(lambda) L)``. Where the
scattering spectrum changes (Mie particles) the ratio also corrects ``mu_s`` and the phase
function exactly; its variance grows with the mismatch, so wavelengths are grouped so that
``|ln(mu_s / mu_s^ref)| <= 0.25`` and ``|g - g^ref| <= 0.03`` within a group, one walk per group
(the reference is the group's middle wavelength). Re-weighting is unbiased; separate walks
would be too, but cost one walk per wavelength -- one walk per group serves the dye spectrum
for free.

Accuracy control: ``target_rel_err`` is the RMS over outputs and wavelengths of the standard
error relative to the PEAK of that output's spectrum (a 1 % target means 1 % of the brightest
wavelength of each curve: what a colour or a normalised curve is sensitive to; the dark,
dye-absorbed wavelengths of a red fabric would otherwise decide the cost alone). Outputs whose
peak is below 1e-3 of the largest are ignored. Photons are added in rounds, each sized from
the error reached, until the target or ``max_photons`` is met; the achieved value is reported.

Polarisation is ignored (unpolarised Fresnel): for a bare or weakly scattering fiber this
misstates the first internal-reflection order by about 8 % (n = 1.5); for scattering fibers the
effect is washed out.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simulate import microfacet
from simulate.medium import HGMedium, MieMedium
from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.scatter import PhaseArrays, phase_arrays
from simulate.montecarlo.transport import (
    ParameterError,
    SpectralTargets,
    _control,
    execute,
    make_inputs,
)

__all__ = [
    "Fiber",
    "BRDFEstimate",
    "volume_brdf",
    "surface_brdf",
    "fiber_brdf",
    "normal_albedo",
    "bssrdf_table",
    "point_outputs",
    "range_outputs",
    "METHODS",
]

log = logging.getLogger(__name__)

METHODS = ("nee", "beam", "bssrdf")
_BATCH = 2_000
_FIRST_ROUND = 50_000
_GROUP_LOG_MU_S = 0.25
_GROUP_G = 0.03


@dataclass(frozen=True)
class Fiber:
    """One fiber: a smooth dielectric cylinder filled with a scattering medium.

    Attributes
    ----------
    radius_um : float
        Fiber radius R (um).
    n_host : float
        Real refractive index of the host (cotton: 1.557).
    medium : MieMedium or HGMedium
        The scattering medium inside (coefficients in 1/um).
    roughness : float
        Beckmann RMS slope ``m`` of the fiber surface (Cook-Torrance term).
    cell_width_deg : float
        Angular width of the surface cell B about the top of the fiber (the cell whose BRDF
        the fabric summation uses); 360 / cell_width_deg should be an integer for the
        ``bssrdf`` route.
    """

    radius_um: float
    n_host: float
    medium: MieMedium | HGMedium
    roughness: float
    cell_width_deg: float = 10.0

    def __post_init__(self) -> None:
        for name in ("radius_um", "n_host", "roughness", "cell_width_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ParameterError(f"Fiber: {name} must be a finite number > 0, got {v!r}")
        if not self.cell_width_deg <= 180.0:
            raise ParameterError(f"Fiber: cell_width_deg must be <= 180, got {self.cell_width_deg!r}")

    @property
    def half_width(self) -> float:
        """Half the cell width in radians."""
        return math.radians(self.cell_width_deg) / 2.0


@dataclass(frozen=True)
class BRDFEstimate:
    """Monte Carlo estimate of ``R`` for P direction pairs and L wavelengths.

    Attributes
    ----------
    R, u_R : numpy.ndarray
        ``[P, L]`` estimate and its standard error.
    photons : int
        Photons used in total.
    seconds : float
        Wall time.
    info : dict
        Method, seed, groups, achieved relative error, energy balance, ...
    """

    R: np.ndarray
    u_R: np.ndarray
    photons: int
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------
# outputs and media
# ------------------------------------------------------------------------------------------


def point_outputs(w_out: np.ndarray, half_width: float, psi_c: float = 0.0) -> np.ndarray:
    """Output rows (``tallies.OUTPUT_COLUMNS``) for point directions ``w_out[P, 3]`` at the cell ``psi_c``.

    The local frame of the top cell is the fiber frame: ``mu = w_z``, ``phi = atan2(w_y, w_x)``.
    """
    w = np.atleast_2d(np.asarray(w_out, dtype=float))
    mu = w[:, 2]
    phi = np.arctan2(w[:, 1], w[:, 0])
    return range_outputs(mu, mu, phi, phi, half_width, psi_c)


def range_outputs(mu_lo, mu_hi, phi_lo, phi_hi, half_width: float, psi_c: float = 0.0) -> np.ndarray:
    """Output rows for direction ranges (arrays of equal length) at the cell centred on ``psi_c``."""
    mu_lo, mu_hi, phi_lo, phi_hi = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (mu_lo, mu_hi, phi_lo, phi_hi))
    out = np.zeros((mu_lo.size, 8))
    centres = np.broadcast_to(np.asarray(psi_c, dtype=float), mu_lo.shape)
    out[:, 0] = np.cos(centres)
    out[:, 1] = np.sin(centres)
    out[:, 2] = math.cos(half_width)
    out[:, 3] = mu_lo
    out[:, 4] = mu_hi
    out[:, 5] = phi_lo
    out[:, 6] = phi_hi
    return out


@dataclass(frozen=True)
class _Optics:
    mu_s: np.ndarray
    mu_a: np.ndarray
    g: np.ndarray
    phases: list[PhaseArrays]


def _optics(fiber: Fiber, wavelengths_nm: np.ndarray) -> _Optics:
    mu_s, mu_a, g, phases = [], [], [], []
    cache: dict[Any, PhaseArrays] = {}
    for wl in wavelengths_nm:
        op = fiber.medium.optical_properties(float(wl))
        mu_s.append(op.mu_s)
        mu_a.append(op.mu_a)
        g.append(op.g)
        key = op.phase.cos_table.tobytes()
        if key not in cache:
            cache[key] = phase_arrays(cos_table=op.phase.cos_table)
        phases.append(cache[key])
    return _Optics(np.array(mu_s), np.array(mu_a), np.array(g), phases)


def _groups(optics: _Optics) -> list[np.ndarray]:
    """Consecutive wavelengths whose scattering is close enough to share one walk."""
    n = optics.mu_s.size
    groups: list[list[int]] = []
    current: list[int] = []
    for i in range(n):
        trial = current + [i]
        ref = trial[len(trial) // 2]
        ok = all(
            (optics.mu_s[j] == optics.mu_s[ref] or (optics.mu_s[j] > 0 and optics.mu_s[ref] > 0
             and abs(math.log(optics.mu_s[j] / optics.mu_s[ref])) <= _GROUP_LOG_MU_S))
            and abs(optics.g[j] - optics.g[ref]) <= _GROUP_G
            for j in trial
        )
        if ok:
            current = trial
        else:
            groups.append(current)
            current = [i]
    if current:
        groups.append(current)
    return [np.array(gr) for gr in groups]


def _walk(fiber: Fiber, optics: _Optics, group: np.ndarray, white: bool):
    """Walk medium and spectral targets of one wavelength group."""
    ref = int(group[len(group) // 2])
    walk_phase = optics.phases[ref]
    medium = np.zeros(K.N_MEDIUM)
    medium[K.M_MU_A] = 0.0 if white else optics.mu_a[ref]
    medium[K.M_MU_S] = optics.mu_s[ref]
    medium[K.M_G] = walk_phase.g
    medium[K.M_N] = fiber.n_host
    medium[K.M_PHASE] = walk_phase.kind
    targets = SpectralTargets(
        mu_a=optics.mu_a[group].astype(float),
        mu_s=optics.mu_s[group].astype(float),
        phases=[optics.phases[int(j)] for j in group],
        same_phase=np.array([optics.phases[int(j)] is walk_phase for j in group]),
    )
    return medium, walk_phase, targets


def _as_directions(name: str, w: Any) -> np.ndarray:
    a = np.atleast_2d(np.asarray(w, dtype=float))
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be an array of finite 3-vectors, shape [P, 3]")
    norm = np.linalg.norm(a, axis=1)
    if np.any(norm == 0):
        raise ParameterError(f"{name} contains a zero vector")
    return a / norm[:, None]


def _wavelengths(wavelengths_nm: Any) -> np.ndarray:
    wl = np.atleast_1d(np.asarray(wavelengths_nm, dtype=float))
    if wl.ndim != 1 or wl.size == 0 or not np.all(np.isfinite(wl)) or np.any(wl <= 0):
        raise ParameterError("wavelengths_nm must be a non-empty 1-D array of finite wavelengths > 0")
    return wl


# ------------------------------------------------------------------------------------------
# accuracy-controlled execution
# ------------------------------------------------------------------------------------------


@dataclass
class _Run:
    scal: np.ndarray
    bins: np.ndarray
    photons: int
    seconds: float


def _run_controlled(inp: K.KernelInputs, estimate, target_rel_err: float, max_photons: int, seed: int,
                    threads: int | None, min_photons: int = _FIRST_ROUND, progress: Any = None) -> _Run:
    """Run batches until ``estimate(bins, photons)`` -> (value, u) reaches the target RMS relative error."""
    scal = np.zeros(T.N_SCALARS)
    bins = None
    photons = 0
    seconds = 0.0
    want = min(min_photons, max_photons)
    while True:
        want = int(math.ceil(want / _BATCH) * _BATCH)
        s, b, sec = execute(inp, want, seed, threads, _BATCH, first_batch=photons // _BATCH)
        scal += s
        bins = b if bins is None else bins + b
        photons += want
        seconds += sec
        value, u = estimate(bins, photons)
        rel = _rms_rel(value, u)
        if progress is not None:
            progress(photons, rel)
        if rel <= target_rel_err or photons >= max_photons:
            break
        need = photons * (rel / target_rel_err) ** 2 * 1.1
        want = int(min(max(need - photons, photons * 0.25), max_photons - photons, photons * 8))
        if want <= 0:
            break
    return _Run(scal, bins, photons, seconds)


def _rms_rel(value: np.ndarray, u: np.ndarray) -> float:
    """RMS of ``u`` relative to the peak of each output's spectrum (rows: outputs, columns: wavelengths)."""
    v = np.abs(np.atleast_2d(np.asarray(value, dtype=float)))
    uu = np.atleast_2d(np.asarray(u, dtype=float))
    peak = v.max(axis=1)
    if peak.size == 0 or not np.any(peak > 0):
        return 0.0
    keep = peak > 1e-3 * peak.max()
    return float(np.sqrt(np.mean((uu[keep] / peak[keep, None]) ** 2)))


def _mean_and_error(bins: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    mean = bins[:, 0] / n
    u = np.sqrt(np.maximum(bins[:, 1] / n - mean * mean, 0.0) / max(n - 1, 1))
    return mean, u


# ------------------------------------------------------------------------------------------
# the routes for one incident direction and one wavelength group
# ------------------------------------------------------------------------------------------


def _beam_source(w_in: np.ndarray) -> tuple[np.ndarray, float]:
    d_perp = math.hypot(w_in[1], w_in[2])
    if d_perp < 1e-9:
        raise ParameterError("w_in is parallel to the fiber axis: a beam along the axis never enters")
    return np.array([float(G.BEAM), w_in[0], w_in[1], w_in[2], 0.0]), d_perp


def _projected_solid_angle(outputs: np.ndarray) -> np.ndarray:
    return 0.5 * (outputs[:, 4] ** 2 - outputs[:, 3] ** 2) * (outputs[:, 6] - outputs[:, 5])


def _route_beam_like(fiber, w_in, outputs, medium, walk_phase, targets, method, control, target, max_photons,
                     seed, threads, progress):
    """NEE or binned beam route for one incident direction: returns (R, u) as [n_out, n_spec] and run."""
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
        mean, u = _mean_and_error(bins, n)
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

    run = _run_controlled(inp, estimate, target, max_photons, seed, threads, progress=progress)
    value, u = estimate(run.bins, run.photons)
    return value, u, run


def _bssrdf_rows(fiber, w_t, ks, grid, medium, walk_phase, targets, control, photons, seed, threads):
    """BSSRDF table rows: CELL-source runs for the local incidences ``(w_t, azimuth k dpsi)``.

    Returns ``T[len(ks), n_psi, n_v, n_mu, n_phi, n_spec]`` (mean exit weight per photon, launch
    weight ``max(w . n, 0)``) and its standard error.
    """
    n_psi, n_v, v_max, n_mu, n_phi = grid
    params = np.array([float(n_psi), float(n_mu), float(n_phi), float(n_v), float(v_max)])
    dpsi = 2.0 * math.pi / n_psi
    rho = math.sqrt(max(1.0 - w_t * w_t, 0.0))
    n_spec = targets.mu_a.size
    out = np.zeros((len(ks), n_psi, n_v, n_mu, n_phi, n_spec))
    err = np.zeros_like(out)
    total = 0
    seconds = 0.0
    for r, k in enumerate(ks):
        # local incidence of the beam at a cell whose normal makes the angle k dpsi with w_perp:
        # w . n = rho cos(k dpsi), w . b = -rho sin(k dpsi)  (b = n x t at the top cell is +y)
        a = k * dpsi
        src = np.array([float(G.CELL), w_t, -rho * math.sin(a), rho * math.cos(a), dpsi / 2.0])
        inp = make_inputs(G.CYLINDER, np.array([fiber.radius_um]), src, medium, walk_phase, control,
                          T.CYLINDER_DIRECTIONS, params, T.V_NONE, None, targets)
        s, b, sec = execute(inp, photons, seed + 7919 * r, threads, _BATCH)
        mean, u = _mean_and_error(b, photons)
        out[r] = mean.reshape(n_psi, n_v, n_mu, n_phi, n_spec)
        err[r] = u.reshape(n_psi, n_v, n_mu, n_phi, n_spec)
        total += photons
        seconds += sec
    return out, err, total, seconds


def bssrdf_table(
    fiber: Fiber,
    w_t: float,
    wavelengths_nm: Any,
    *,
    n_mu: int = 9,
    n_phi: int = 18,
    n_v: int = 1,
    v_max_um: float | None = None,
    photons_per_row: int = 100_000,
    seed: int = 0,
    threads: int | None = None,
) -> dict[str, Any]:
    """The fiber BSSRDF stored by offset, for one axial incidence component ``w_t``.

    Rows: local incident azimuths ``k dpsi`` (``|k dpsi| < 90 deg + dpsi/2``, every row lit on part
    of its cell), i.e. incident directions ``(w_t, -rho sin(k dpsi), rho cos(k dpsi))`` in A's
    frame, ``rho = sqrt(1 - w_t^2)``. Columns: exit cell offset (``n_psi = 360 / cell width``
    cells, 0 = A itself), axial offset ``v`` (``n_v`` bins on ``[-v_max, v_max]``; 1 = summed
    out), local exit direction (``n_mu`` x ``n_phi`` uniform bins in ``cos theta`` and azimuth),
    wavelength. Values: mean exit weight per photon entering A uniformly with launch weight
    ``max(w . n, 0)`` -- i.e. ``F_out / (E |A|)``; the docs/physics.md BSSRDF is
    ``T / (cos theta_in |B| dOmega cos theta_out)`` with ``F_in = E |A| cos theta_in``.

    Returns
    -------
    dict
        ``T``, ``u_T`` (``[k, psi, v, mu, phi, lambda]``), ``k``, grid edges, photons, seconds.
    """
    wl = _wavelengths(wavelengths_nm)
    n_psi = int(round(360.0 / fiber.cell_width_deg))
    if abs(n_psi * fiber.cell_width_deg - 360.0) > 1e-9:
        raise ParameterError(f"bssrdf route: 360 / cell_width_deg must be an integer, got {fiber.cell_width_deg}")
    if not -1.0 < w_t < 1.0:
        raise ParameterError(f"w_t must be in (-1, 1), got {w_t!r}")
    dpsi = 2.0 * math.pi / n_psi
    k_max = int(math.floor((math.pi / 2 + dpsi / 2) / dpsi - 1e-12))
    ks = list(range(-k_max, k_max + 1))
    v_max = 10.0 * fiber.radius_um if v_max_um is None else float(v_max_um)
    optics = _optics(fiber, wl)
    control = _control(K_DEFAULT_MAX_EVENTS, 1e-4, 0.1)
    rows = np.zeros((len(ks), n_psi, n_v, n_mu, n_phi, wl.size))
    errs = np.zeros_like(rows)
    photons = 0
    seconds = 0.0
    for group in _groups(optics):
        medium, walk_phase, targets = _walk(fiber, optics, group, white=True)
        t, u, p, s = _bssrdf_rows(fiber, w_t, ks, (n_psi, n_v, v_max, n_mu, n_phi), medium, walk_phase, targets,
                                  control, photons_per_row, seed, threads)
        rows[..., group] = t
        errs[..., group] = u
        photons += p
        seconds += s
    return {
        "T": rows, "u_T": errs, "k": np.array(ks), "cell_width_rad": dpsi, "w_t": float(w_t),
        "v_edges_um": np.linspace(-v_max, v_max, n_v + 1), "mu_edges": np.linspace(0, 1, n_mu + 1),
        "phi_edges": np.linspace(-math.pi, math.pi, n_phi + 1), "wavelengths_nm": wl,
        "photons": photons, "seconds": seconds,
    }


K_DEFAULT_MAX_EVENTS = 1_000_000


def _route_bssrdf(fiber, w_in, outputs_grid_bins, table, omega):
    """Summation of the BSSRDF rows for one beam (aligned azimuths exact, others interpolated)."""
    rows, errs, ks, dpsi = table["T"], table["u_T"], table["k"], table["cell_width_rad"]
    n_psi = rows.shape[1]
    beta = math.atan2(-w_in[1], w_in[2])  # w_perp along n(beta)
    x = beta / dpsi
    j0 = math.floor(x)
    frac = x - j0
    total = 0.0
    total_u2 = 0.0
    for j, weight in ((j0, 1.0 - frac), (j0 + 1, frac)):
        if weight == 0.0:
            continue
        acc = 0.0
        acc_u2 = 0.0
        for r, k in enumerate(ks):
            # cell A_i = beta_j - k dpsi, i = j - k; B (offset 0) relative to A_i is offset k - j
            offset = (k - j) % n_psi
            mu_i, phi_i = outputs_grid_bins
            acc = acc + rows[r, offset][:, mu_i, phi_i, :].sum(axis=0)  # v offsets summed out
            acc_u2 = acc_u2 + (errs[r, offset][:, mu_i, phi_i, :] ** 2).sum(axis=0)
        total = total + weight * acc
        total_u2 = total_u2 + (weight ** 2) * acc_u2
    return total / omega, np.sqrt(total_u2) / omega


# ------------------------------------------------------------------------------------------
# public API
# ------------------------------------------------------------------------------------------


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
    wl = _wavelengths(wavelengths_nm)
    w_in = _as_directions("w_in", w_in)
    if outputs is None:
        if w_out is None:
            raise ParameterError("give w_out (point directions) or outputs (direction ranges)")
        w_out = _as_directions("w_out", w_out)
        if w_out.shape != w_in.shape:
            raise ParameterError("w_in and w_out must pair up: both of shape [P, 3]")
        if np.any(w_out[:, 2] <= 0):
            raise ParameterError("w_out must lie above the cell's tangent plane (w_out_z > 0)")
        outputs = point_outputs(w_out, fiber.half_width)
    else:
        outputs = np.atleast_2d(np.asarray(outputs, dtype=float))
        if outputs.shape != (w_in.shape[0], 8):
            raise ParameterError("outputs must have one row of 8 columns per w_in")
    if not (isinstance(target_rel_err, (int, float)) and 0 < target_rel_err < 1):
        raise ParameterError(f"target_rel_err must be in (0, 1), got {target_rel_err!r}")
    if max_photons is None:
        max_photons = max(int(100.0 / target_rel_err ** 2), 1_000_000)
    optics = _optics(fiber, wl)
    groups = _groups(optics)
    control = _control(K_DEFAULT_MAX_EVENTS, 1e-4, 0.1)
    P = w_in.shape[0]
    R = np.zeros((P, wl.size))
    u_R = np.zeros((P, wl.size))
    photons = 0
    capped = 0
    energy = []
    keys: dict[tuple[float, ...], list[int]] = {}
    for p in range(P):
        keys.setdefault(tuple(np.round(w_in[p], 12)), []).append(p)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(keys) * len(groups), desc=f"fiber {method}", unit="run")
    for d, (key, rows) in enumerate(keys.items()):
        win = np.array(key)
        out_rows = outputs[rows]
        for gi, group in enumerate(groups):
            medium, walk_phase, targets = _walk(fiber, optics, group, white=white)
            run_seed = int(seed) * 1_000_003 + d * 1009 + gi
            if method == "bssrdf":
                n_mu, n_phi = bssrdf_bins
                mu_i, phi_i, omega = _grid_cells(out_rows, n_mu, n_phi)
                table = _bssrdf_for_beam(fiber, win, medium, walk_phase, targets, control, n_mu, n_phi,
                                         target_rel_err, max_photons, run_seed, threads)
                value, u = _route_bssrdf(fiber, win, (mu_i, phi_i), table, omega[:, None])
                photons += table["photons"]
            else:
                value, u, run = _route_beam_like(fiber, win, out_rows, medium, walk_phase, targets, method, control,
                                                 target_rel_err, max_photons, run_seed, threads, None)
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
                bar.set_postfix(rel_err=f"{_rms_rel(R, u_R):.4f}")
    if bar is not None:
        bar.close()
    if capped:
        log.warning("%d photons reached the event cap (%d events) and were stopped", capped, K_DEFAULT_MAX_EVENTS)
    seconds = time.perf_counter() - t0
    info = {
        "method": method, "seed": int(seed), "groups": [wl[g].tolist() for g in groups],
        "achieved_rel_err": _rms_rel(R, u_R), "target_rel_err": float(target_rel_err),
        "incident_directions": len(keys), "capped_photons": capped, "energy": energy[:8],
        "cell_width_deg": fiber.cell_width_deg,
    }
    return BRDFEstimate(R, u_R, photons, seconds, info)


def _grid_cells(outputs: np.ndarray, n_mu: int, n_phi: int):
    """Map ranged outputs onto the cells of a (mu, phi) grid; refuse ranges that are not grid cells."""
    mu_edges = np.linspace(0, 1, n_mu + 1)
    phi_edges = np.linspace(-math.pi, math.pi, n_phi + 1)
    mu_i = np.clip(np.searchsorted(mu_edges, 0.5 * (outputs[:, 3] + outputs[:, 4])) - 1, 0, n_mu - 1)
    phi_i = np.clip(np.searchsorted(phi_edges, 0.5 * (outputs[:, 5] + outputs[:, 6])) - 1, 0, n_phi - 1)
    exact = np.isclose(outputs[:, 3], mu_edges[mu_i]) & np.isclose(outputs[:, 4], mu_edges[mu_i + 1]) & \
        np.isclose(outputs[:, 5], phi_edges[phi_i]) & np.isclose(outputs[:, 6], phi_edges[phi_i + 1])
    if not np.all(exact):
        raise ParameterError("bssrdf route: outputs must be cells of the BSSRDF direction grid (bssrdf_bins)")
    omega = 0.5 * (mu_edges[mu_i + 1] ** 2 - mu_edges[mu_i] ** 2) * (phi_edges[phi_i + 1] - phi_edges[phi_i])
    return mu_i, phi_i, omega


def _bssrdf_for_beam(fiber, w_in, medium, walk_phase, targets, control, n_mu, n_phi, target, max_photons, seed,
                     threads):
    n_psi = int(round(360.0 / fiber.cell_width_deg))
    if abs(n_psi * fiber.cell_width_deg - 360.0) > 1e-9:
        raise ParameterError(f"bssrdf route: 360 / cell_width_deg must be an integer, got {fiber.cell_width_deg}")
    dpsi = 2.0 * math.pi / n_psi
    k_max = int(math.floor((math.pi / 2 + dpsi / 2) / dpsi - 1e-12))
    ks = list(range(-k_max, k_max + 1))
    # photons per row: the table's error on one bin is what the summation adds up; a fixed
    # budget per row from the target (rows add in quadrature over ~pi/dpsi lit cells)
    per_row = int(min(max(_FIRST_ROUND, 4.0 / target ** 2 / len(ks)), max_photons))
    per_row = int(math.ceil(per_row / _BATCH) * _BATCH)
    t, u, photons, seconds = _bssrdf_rows(fiber, float(w_in[0]), ks, (n_psi, 1, 1.0, n_mu, n_phi), medium,
                                          walk_phase, targets, control, per_row, seed, threads)
    return {"T": t, "u_T": u, "k": ks, "cell_width_rad": dpsi, "photons": photons, "seconds": seconds}


def surface_brdf(fiber: Fiber, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
    """Surface term at B, ``R_surf = f_CT(w_in, w_out) cos(theta_in)`` (0 below B's tangent plane), ``[P]``.

    Cook-Torrance with the host index and the fiber's Beckmann RMS slope (docs/physics.md section 5);
    wavelength-independent because the host index is real and constant.
    """
    w_in = _as_directions("w_in", w_in)
    w_out = _as_directions("w_out", w_out)
    f = microfacet.cook_torrance(w_in, w_out, fiber.roughness, fiber.n_host)
    return np.where((w_in[:, 2] > 0) & (w_out[:, 2] > 0), f * w_in[:, 2], 0.0)


def fiber_brdf(fiber: Fiber, w_in: np.ndarray, w_out: np.ndarray, wavelengths_nm: np.ndarray,
               **kwargs: Any) -> BRDFEstimate:
    """``R_B = R_surf + R_vol`` (surface term exact, volume term by :func:`volume_brdf`)."""
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
    """
    out = range_outputs([0.0], [1.0], [-math.pi], [math.pi], fiber.half_width)
    est = volume_brdf(fiber, np.array([[0.0, 0.0, 1.0]]), None, wavelengths_nm, method="beam", outputs=out,
                      target_rel_err=target_rel_err, seed=seed, threads=threads)
    return est.R[0] * math.pi, est.u_R[0] * math.pi
