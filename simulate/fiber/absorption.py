r"""Absorption tables: one white Monte Carlo walk, the volume BRDF for ANY dye (fitting support).

The fiber's volume term is estimated by white Monte Carlo (:mod:`simulate.fiber`): photons walk
the scattering medium without absorption and every score carries ``exp(-mu_a L)`` for its path
length ``L`` in the host. For a fixed set of photons the estimate of one output at one
wavelength is therefore a sum over scores ``j`` of fixed weights and path lengths::

    R(mu_a_host) = sum_j w_j exp(-(mu_a_part + mu_a_host) l_j)                              (1)

-- the Laplace transform of the scores' path-length distribution. A change of the dye alone
(the host absorption spectrum) changes nothing but ``mu_a_host`` in (1): no photon needs to be
walked again.

How (1) is stored. Storing every score's ``(w_j, l_j)`` would need a change to the compiled
kernel's tallies (and its numba cache and speed contract). Instead the kernel's own spectral
re-weighting is used as it is: each wavelength of a group becomes ``K`` targets with host
absorptions ``nu_0 = 0 < nu_1 < ... < nu_{K-1} = nu_max`` (the "nodes"), so ONE walk returns
(1) at every node, from the same photons (common random numbers). Between nodes ``log R`` is
interpolated by a monotone cubic (PCHIP) in ``x = log(nu + NU_0)``: ``log R`` is convex and
decreasing in ``nu`` (the log of a Laplace transform) and varies over decades of ``nu``
(the baseline 10^-3 /um to band peaks of 1 /um), so the nodes are uniform in ``x``.
:data:`DEFAULT_NODES` (16) keep the interpolation error at or below about 10^-3 relative on
red cotton from 10^-3 to 1.3 /um (uniform in ``sqrt(nu)`` it was 4 % at small ``nu``; tested
against a table with the asked value as a node, from the same photons). Above ``nu_max``
nothing is extrapolated: the caller sizes ``nu_max`` from the largest host absorption the
fit's bounds allow.

A dye where it sits (:attr:`simulate.fiber.Fiber.dye_profile` ``"ring"`` or ``"core"``): the dye absorbs only
along the part ``d_j`` of each path that lies in the dyed region, so (1) becomes
``R(mu_dye) = sum_j w_j exp(-mu_a_part l_j - mu_dye d_j)`` -- the same Laplace transform, of the dyed
lengths' distribution instead of the whole paths'. The walk is unchanged; the nodes are the dye's
absorption in the dyed region (:func:`absorption_targets` names them the targets' dye,
``SpectralTargets.mu_a_dye``), and the kernel takes each free path's dyed chord (:mod:`simulate.montecarlo.kernel`,
"Dye profile"), as the fiber Monte Carlo absorbs a placed dye. A table is walked at one placement (the fiber's
profile and depth): another depth is another walk. The kernel scores a placed dye with exit tallies only, so
such a table takes the binned ``beam`` route (the next-event ``nee`` route is refused).

Cost: the walk is shared, the re-weighting costs ``K`` times the targets. The photons of each
(incident direction, wavelength group) are fixed at the first evaluation (accuracy-controlled
there) and reused, with the same seeds, by every later walk of the fit: a scattering change
re-walks the same random streams (common random numbers), so the objective does not jump with
Monte Carlo noise between nearby parameter values.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from simulate.fiber.model import Fiber, as_directions, as_wavelengths
from simulate.fiber.routes import beam_route
from simulate.fiber.spectral import direction_keys, group_walk, run_seed, spectral_optics, wavelength_groups
from simulate.montecarlo.accuracy import check_budget
from simulate.montecarlo.tallies import S_LAUNCHED, S_SCATTERINGS
from simulate.montecarlo.transport import ParameterError, SpectralTargets, make_control

__all__ = ["AbsorptionTable", "RunCache", "DEFAULT_NODES", "absorption_nodes", "absorption_table", "absorption_targets",
           "check_placement"]

#: Host-absorption nodes per wavelength (see the module docstring).
DEFAULT_NODES = 16
_FLOOR = 1e-300
#: Offset of the interpolation variable ``log(nu + NU_0)`` (1/um): absorptions well below
#: ``NU_0`` change a fiber's paths (tens of um) by < 1 %, so the nodes need not resolve them.
NU_0 = 1e-4


def _x(nu: Any) -> np.ndarray:
    """The interpolation variable ``x = log(nu + NU_0)``."""
    return np.log(np.asarray(nu, float) + NU_0)


def absorption_nodes(nu_max: float, count: int = DEFAULT_NODES) -> np.ndarray:
    """``count`` host absorptions (1/um) from 0 to ``nu_max``, uniform in ``log(nu + NU_0)``.

    Parameters
    ----------
    nu_max : float
        The largest host absorption (1/um), ``> 0``.
    count : int
        Number of nodes, at least 3.

    Returns
    -------
    numpy.ndarray
        ``[count]`` nodes, the first one 0.

    Raises
    ------
    ParameterError
        For a ``nu_max`` that is not a finite number > 0 or fewer than 3 nodes.
    """
    if not (math.isfinite(nu_max) and nu_max > 0):
        raise ParameterError(f"absorption table: nu_max must be a finite number > 0, got {nu_max!r}")
    if count < 3:
        raise ParameterError(f"absorption table: at least 3 nodes are needed, got {count}")
    nodes = np.exp(np.linspace(math.log(NU_0), math.log(nu_max + NU_0), count)) - NU_0
    nodes[0] = 0.0
    return nodes


class RunCache(Protocol):
    """Finished (direction, group) runs of a table by key ``"d:gi"`` (:func:`absorption_table`)."""

    def get(self, key: str) -> tuple[np.ndarray, np.ndarray, int, float] | None:
        """The run stored under ``key``: ``(value, u, photons, scatterings)``, or None when it is not stored."""
        ...

    def put(self, key: str, value: np.ndarray, u: np.ndarray, photons: int, scatterings: float) -> None:
        """Store the finished run ``key``: its estimate, standard error, photons and mean scatterings."""
        ...


@dataclass
class AbsorptionTable:
    """Volume BRDF ``R[P, L, K]`` at the host-absorption ``nodes[K]`` (module docstring).

    Attributes
    ----------
    R, u_R : numpy.ndarray
        ``[P, L, K]`` estimate and standard error at each node.
    nodes : numpy.ndarray
        ``[K]`` host absorptions (1/um), ``nodes[0] = 0``.
    wavelengths_nm : numpy.ndarray
        ``[L]``.
    photons : dict
        Photons used per (incident direction index, group index): pass it back to
        :func:`absorption_table` to walk the same streams again.
    seconds : float
        Wall time of the walks.
    """

    R: np.ndarray
    u_R: np.ndarray
    nodes: np.ndarray
    wavelengths_nm: np.ndarray
    photons: dict = field(default_factory=dict)
    seconds: float = 0.0
    #: mean scatterings per walked photon of each run ``"d:gi"`` (the re-weighting bound's ``N``)
    scatterings: dict = field(default_factory=dict)
    #: the wavelength groups of the walk and the optics scored (for :func:`reweight_exponent`)
    groups: list = field(default_factory=list)
    optics: Any = None

    def group_scatterings(self) -> np.ndarray:
        """Per group, the largest mean number of scatterings over the directions."""
        out = np.zeros(len(self.groups))
        for key, n in self.scatterings.items():
            gi = int(key.split(":")[1])
            out[gi] = max(out[gi], n)
        return out

    @property
    def nu_max(self) -> float:
        """The largest host absorption of the table (1/um), beyond which it is not read."""
        return float(self.nodes[-1])

    def __call__(self, mu_a_host: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(R, u_R)`` ``[P, L]`` for the host absorption ``mu_a_host[L]`` (1/um).

        Raises
        ------
        ParameterError
            When an absorption lies outside ``[0, nu_max]`` (no extrapolation).
        """
        mu = np.broadcast_to(np.asarray(mu_a_host, float), self.wavelengths_nm.shape)
        if np.any(mu < 0) or np.any(mu > self.nu_max * (1 + 1e-9)) or not np.all(np.isfinite(mu)):
            raise ParameterError(f"absorption table: host absorption outside [0, {self.nu_max:g}] /um "
                                 f"(largest asked {float(np.max(mu)):g}); build the table with a larger nu_max")
        x_nodes = _x(self.nodes)
        x = _x(np.minimum(mu, self.nu_max))
        vals = self.R
        positive = np.all(vals > 0, axis=2)                       # [P, L]
        log_r = np.exp(pchip_at(x_nodes, np.log(np.maximum(vals, _FLOOR)), x))
        # outputs with a zero at some node (no scores): linear in R
        R = np.where(positive, log_r, _linear_at(x_nodes, vals, x))
        # the relative error varies slowly with nu: interpolate it, apply to the value
        rel = np.where(vals > 0, self.u_R / np.where(vals > 0, vals, 1.0), 0.0)
        return R, R * _linear_at(x_nodes, rel, x)


def _interval(x_nodes: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per query ``x[L]`` its node interval ``i`` (``x_i <= x <= x_i+1``, the last one at the end) and ``s = x - x_i``."""
    i = np.clip(np.searchsorted(x_nodes, x, side="right") - 1, 0, x_nodes.size - 2)
    return i, x - x_nodes[i]


def _linear_at(x_nodes: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``y[P, L, K]`` over ``x_nodes[K]`` read linearly at ``x[L]`` (one query per wavelength): ``[P, L]``.

    ``np.interp`` per row, without the loop.
    """
    i, s = _interval(x_nodes, x)
    cols = np.arange(x.size)
    y0, y1 = y[:, cols, i], y[:, cols, i + 1]
    return y0 + (y1 - y0) * (s / (x_nodes[i + 1] - x_nodes[i]))


def pchip_at(x_nodes: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The monotone cubic (PCHIP, Fritsch & Carlson 1980) of ``y[P, L, K]`` over ``x_nodes[K]`` at ``x[L]``: ``[P, L]``.

    The interpolant of :class:`scipy.interpolate.PchipInterpolator` (its derivative rule, the
    weighted harmonic mean, and its one-sided three-point ends, after ``scipy.interpolate._cubic``),
    for all outputs and wavelengths at once: the fit reads a table at one absorption per wavelength
    at every evaluation, and one ``PchipInterpolator`` per wavelength cost 35 ms of a 40 ms evaluation
    on the felt (33 wavelengths). Equal to scipy's to rounding (test).

    Parameters
    ----------
    x_nodes : numpy.ndarray
        ``[K]`` increasing nodes, ``K >= 2``.
    y : numpy.ndarray
        ``[P, L, K]`` values at the nodes.
    x : numpy.ndarray
        ``[L]`` one query per wavelength.

    Returns
    -------
    numpy.ndarray
        ``[P, L]`` the interpolant's values.
    """
    h = np.diff(x_nodes)                                     # [K-1]
    m = np.diff(y, axis=2) / h                               # [P, L, K-1] slopes
    d = np.zeros_like(y)
    if y.shape[2] == 2:
        d[..., 0] = d[..., 1] = m[..., 0]
    else:
        w1 = 2.0 * h[1:] + h[:-1]
        w2 = h[1:] + 2.0 * h[:-1]
        sm = np.sign(m)
        flat = (sm[..., 1:] != sm[..., :-1]) | (m[..., 1:] == 0) | (m[..., :-1] == 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            whmean = (w1 / m[..., :-1] + w2 / m[..., 1:]) / (w1 + w2)
            d[..., 1:-1] = np.where(flat, 0.0, 1.0 / whmean)
        d[..., 0] = _pchip_end(h[0], h[1], m[..., 0], m[..., 1])
        d[..., -1] = _pchip_end(h[-1], h[-2], m[..., -1], m[..., -2])
    i, s = _interval(x_nodes, x)
    cols = np.arange(x.size)
    hi = h[i]
    y0, y1 = y[:, cols, i], y[:, cols, i + 1]
    d0, d1 = d[:, cols, i], d[:, cols, i + 1]
    slope = (y1 - y0) / hi
    t = (d0 + d1 - 2.0 * slope) / hi
    c0, c1 = t / hi, (slope - d0) / hi - t                   # scipy's CubicHermiteSpline coefficients
    return ((c0 * s + c1) * s + d0) * s + y0


def _pchip_end(h0: float, h1: float, m0: np.ndarray, m1: np.ndarray) -> np.ndarray:
    """PCHIP's end derivative: the one-sided three-point estimate, kept monotone (scipy's ``_edge_case``)."""
    d = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    d = np.where(np.sign(d) != np.sign(m0), 0.0, d)
    return np.where((np.sign(m0) != np.sign(m1)) & (np.abs(d) > 3.0 * np.abs(m0)), 3.0 * m0, d)


def absorption_targets(optics: Any, group: np.ndarray, nodes: np.ndarray, walk_phase: Any) -> SpectralTargets:
    """The walk's spectral targets of one wavelength group at every host-absorption node.

    Target ``(wavelength j, node k)`` sits at index ``j_local * K + k``: the node is host absorption added to
    the wavelength's own; for a placed dye (``optics.mu_a_dye``, a ring or core) it is the dye's, which absorbs
    in the dyed region only (module docstring).

    Parameters
    ----------
    optics : FiberOptics
        The fiber's optics per wavelength (``mu_a``, ``mu_s``, ``phases``, optionally ``mu_a_dye``).
    group : numpy.ndarray
        Wavelength indices of the group.
    nodes : numpy.ndarray
        ``[K]`` host absorptions added (1/um).
    walk_phase : object
        The phase function the walk samples; a target with the same phase needs no phase re-weighting.

    Returns
    -------
    SpectralTargets
        ``len(group) * K`` targets.
    """
    k = nodes.size
    idx = np.repeat(group, k)
    added = np.tile(nodes, group.size)
    dye = getattr(optics, "mu_a_dye", None)
    return SpectralTargets(
        mu_a=(optics.mu_a[idx] + added).astype(float),
        mu_s=optics.mu_s[idx].astype(float),
        phases=[optics.phases[int(j)] for j in idx],
        same_phase=np.array([optics.phases[int(j)] is walk_phase for j in idx]),
        mu_a_dye=None if dye is None else (np.asarray(dye, float)[idx] + added).astype(float),
    )


def check_placement(fiber: Fiber, method: str, reference: Fiber | None = None) -> None:
    """Check that a table of a placed dye (or placed scatterers) can be walked as asked (module docstring).

    A placed dye or placed scatterers need the ``beam`` route, and a reference walk at the same placement
    (its dyed region and its scatterers are the walk's).

    Parameters
    ----------
    fiber : Fiber
        The fiber whose table is built.
    method : str
        The fiber route (``nee``, ``beam`` or ``bssrdf``).
    reference : Fiber, optional
        The fiber whose walk is re-weighted, when it is not ``fiber`` itself.

    Raises
    ------
    ParameterError
        Naming what to change when the route or the reference's placement does not fit.
    """
    profile = getattr(fiber, "dye_profile", "uniform")
    if reference is not None and (getattr(reference, "dye_profile", "uniform"), getattr(reference, "dye_depth_um", 0.0)) \
            != (profile, getattr(fiber, "dye_depth_um", 0.0)):
        raise ParameterError("absorption table: the reference fiber's dye_profile and dye_depth_um must be the "
                             "fiber's (the dyed region is walked with the reference's)")
    placed = (getattr(fiber, "scatterer_profile", "uniform"), getattr(fiber, "scatterer_depth_um", 0.0))
    if reference is not None and (getattr(reference, "scatterer_profile", "uniform"),
                                  getattr(reference, "scatterer_depth_um", 0.0)) != placed:
        raise ParameterError("absorption table: the reference fiber's scatterer_profile and scatterer_depth_um must "
                             "be the fiber's (the scatterers sit where the reference's walk puts them)")
    if placed[0] != "uniform" and method != "beam":
        raise ParameterError(f"absorption table: scatterers in a {placed[0]} (scatterer_profile) are scored with exit "
                             f"tallies only; the {method} route's next-event estimates assume scatterers through the "
                             "fiber: use the beam route")
    if profile != "uniform" and method != "beam":
        raise ParameterError(f"absorption table: a {profile} dye (dye_profile) is scored with exit tallies only; "
                             f"the {method} route's next-event estimates assume a dye through the fiber: use the beam "
                             "route")


def absorption_table(
    fiber: Fiber,
    w_in: np.ndarray,
    outputs: np.ndarray,
    wavelengths_nm: Any,
    nodes: np.ndarray,
    *,
    method: str = "nee",
    target_rel_err: float = 0.02,
    max_photons: int | None = None,
    photons: dict | None = None,
    seed: int = 0,
    threads: int | None = None,
    progress: Callable[[int, int, int], None] | None = None,
    cache: RunCache | None = None,
    reference: Fiber | None = None,
) -> AbsorptionTable:
    """White Monte Carlo of the volume term with the host absorption tabulated at ``nodes``.

    Parameters
    ----------
    fiber : simulate.fiber.Fiber
        The fiber WITHOUT its dye (host absorption 0; particle absorption is kept). A placed dye's profile and
        depth are kept: the nodes are then the dye's absorption in its region (module docstring; ``beam`` route).
    w_in : numpy.ndarray
        ``[P, 3]`` incident directions (fiber frame), paired with ``outputs``.
    outputs : numpy.ndarray
        ``[P, 8]`` output rows (:func:`simulate.fiber.point_outputs` / ``range_outputs``).
    wavelengths_nm : array_like
        ``[L]``.
    nodes : numpy.ndarray
        Host absorptions (:func:`absorption_nodes`), first node 0.
    method : {"nee", "beam"}
        Fiber route (the BSSRDF route is not supported here).
    target_rel_err, max_photons
        Accuracy control of a first table (relative to each output's peak, over all nodes).
    photons : dict, optional
        Fixed photons per (direction, group) from a previous table (``AbsorptionTable.photons``):
        the same streams are walked again, no accuracy control (common random numbers).
    seed, threads
        As :func:`simulate.fiber.volume_brdf` (the same seeds per direction and group).
    progress : callable, optional
        ``progress(photons, run, runs)`` after every batch round of every (direction, group) run
        (``photons`` walked so far in this table, ``run`` the runs finished, of ``runs``), and once
        with 0 photons before the first: a display moves from the first photons on.
    reference : simulate.fiber.Fiber, optional
        Walk the photons in THIS fiber's scattering (its groups, walk media, seeds) and score them
        for ``fiber``'s by the likelihood ratio (``mu_s`` and phase per target): other particle
        volume fractions or sizes from the same paths (:func:`simulate.fiber.spectral.reweight_exponent`
        bounds the variance; the caller decides). Both without dye, same geometry.
    cache : RunCache, optional
        Finished runs by key ``"d:gi"``: a run found there is not walked again, every walked run is
        put there (the fit's walk checkpoint: an interrupted walk resumes at its next run).
    """
    if method not in ("nee", "beam"):
        raise ParameterError(f"absorption table: method must be nee or beam, got {method!r}")
    check_placement(fiber, method, reference)
    wl = as_wavelengths(wavelengths_nm)
    nodes = np.asarray(nodes, float)
    if nodes[0] != 0.0 or np.any(np.diff(nodes) <= 0):
        raise ParameterError("absorption table: nodes must start at 0 and increase")
    w_in = as_directions("w_in", w_in)
    outputs = np.atleast_2d(np.asarray(outputs, float))
    target_rel_err, max_photons = check_budget(target_rel_err, max_photons)
    optics = spectral_optics(fiber, wl)
    walk_fiber = fiber if reference is None else reference
    walk_optics = optics if reference is None else spectral_optics(reference, wl)
    groups = wavelength_groups(walk_optics)
    control = make_control()
    K = nodes.size
    P = w_in.shape[0]
    R = np.zeros((P, wl.size, K))
    u_R = np.zeros((P, wl.size, K))
    keys = direction_keys(w_in)
    used: dict = {}
    scatterings: dict = {}
    seconds = 0.0
    runs = len(keys) * len(groups)
    walked = [0]
    if progress is not None:
        progress(0, 0, runs)
    for d, (key, rows) in enumerate(keys.items()):
        win = np.array(key)
        for gi, group in enumerate(groups):
            run_key = f"{d}:{gi}"
            found = None if cache is None else cache.get(run_key)
            if found is not None:
                value, u, used[run_key] = found[0], found[1], int(found[2])
                scatterings[run_key] = float(found[3])
            else:
                medium, walk_phase, _ = group_walk(walk_fiber, walk_optics, group, white=True)
                targets = absorption_targets(optics, group, nodes, walk_phase)
                stream = run_seed(seed, d, gi)  # the rule of volume_brdf: the same streams
                fixed = None if photons is None else photons.get(run_key)
                if fixed is None:
                    target, cap = target_rel_err, max_photons
                else:  # a target never met and a cap of exactly the recorded photons: the same batches
                    target, cap = 1e-12, int(fixed)
                done = d * len(groups) + gi
                report = None if progress is None else (
                    lambda n, rel, done=done: progress(walked[0] + n, done, runs))  # type: ignore[misc]
                value, u, run = beam_route(fiber, win, outputs[rows], medium, walk_phase, targets, method,
                                           control, target, cap, stream, threads, report)
                used[run_key] = int(run.photons)
                scatterings[run_key] = float(run.scal[S_SCATTERINGS] / max(run.scal[S_LAUNCHED], 1.0))
                walked[0] += int(run.photons)
                seconds += run.seconds
                if cache is not None:
                    cache.put(run_key, value, u, int(run.photons), scatterings[run_key])
            if progress is not None:
                progress(walked[0], d * len(groups) + gi + 1, runs)
            R[np.ix_(np.asarray(rows), group)] = value.reshape(len(rows), group.size, K)
            u_R[np.ix_(np.asarray(rows), group)] = u.reshape(len(rows), group.size, K)
    return AbsorptionTable(R=R, u_R=u_R, nodes=nodes, wavelengths_nm=wl, photons=used, seconds=seconds,
                           scatterings=scatterings, groups=groups, optics=optics)
