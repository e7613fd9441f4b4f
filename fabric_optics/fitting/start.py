"""Starts of ``simulate fit`` that find the colour: a dye of any colour and its inverted start.

Why: a dye curve of a few bands started from another colour may not reach the measured one
(docs/notes/fit-trust.md, "The colour start, for every method"). The ``knots`` dye curve (:mod:`simulate.config`, docs/physics.md section 2) can take any colour;
:func:`knots_config` turns any config's dye into ``K`` knots, and :func:`inverted_start` gives the
knots a start that already has the measured colour.

The inversion (per wavelength, through the model's own table)
--------------------------------------------------------------
The fit tabulates the volume term over host absorption (:mod:`simulate.fiber.absorption`), so the
model at any *constant* absorption ``nu`` is a table read: ``B[j, l] = beta(g*, l; nu_j)`` at the
colour geometry ``g*`` of compare (the geometry nearest normal/normal,
:class:`compare.residual.ModelResidual`), on a fine grid ``nu_j`` (uniform in ``log(nu + NU_0)``).
``beta`` falls monotonically with ``nu`` at every wavelength, so ``beta(g*, l; mu(l))`` for a
spectrum ``mu(l)`` is a 1-D interpolation per wavelength (linear in ``log beta`` against
``log(nu + NU_0)``). The knots ``v`` are then the bounded least-squares solution of::

    d(v) = log(M beta(g*; mu_v)) - log(m)                    (bands: wavelengths or R, G, B)
    r(v) = [ d - mean(d),  W_LEVEL mean(d),  W_SMOOTH diff2(v) ]

``m`` the measured band values at ``g*``, ``M`` the measurement's bands (identity/interpolation
for a spectral measurement, :func:`compare.bands.conversion_matrix` for RGB). ``d - mean(d) = 0``
means every band ratio, hence hue and saturation, is the measured one; the level term (weight
0.3) prefers the measured absolute level where it is reachable (an absolute measurement: the
amount of absorption also sets the angular shape), and the second differences (0.02 per log10)
pick the smoothest of the many spectra with three equal ratios (RGB gives three numbers for K
knots). The grid costs 40 table reads; the solve a few hundred cheap evaluations, no photon.
"""

from __future__ import annotations

import logging
import math
import re
import tomllib

import numpy as np
from scipy.optimize import least_squares

from compare.bands import conversion_matrix
from fabric_optics.paths import toml_dumps
from simulate.config import SimulationConfig, knots_curve, parse_config
from simulate.fiber.absorption import NU_0

__all__ = ["DEFAULT_KNOTS", "knots_config", "inverted_start", "knot_indices", "knot_owners"]

log = logging.getLogger(__name__)

#: Knots of ``simulate fit --dye knots``.
DEFAULT_KNOTS = 8
_GRID = 40
W_LEVEL = 0.3
W_SMOOTH = 0.02
_KNOT = re.compile(r"^(?:populations\[(\d+)\]\.)?fiber\.dye\.log10_per_um\[(\d+)\]$")


def knots_config(config: SimulationConfig, wavelengths_nm, count: int = DEFAULT_KNOTS) -> SimulationConfig:
    """``config`` with its dye replaced by ``count`` knots spanning ``wavelengths_nm``.

    The knots are sampled from its present dye (clipped to [1e-4, 3] /um; no dye: 1e-3 /um,
    cellulose's baseline).

    Parameters
    ----------
    config : SimulationConfig
        The config.
    wavelengths_nm : array_like
        The model wavelengths (nm); the knots span their range.
    count : int, default DEFAULT_KNOTS
        The knots.

    Returns
    -------
    SimulationConfig
        The config with knots, parsed again.
    """
    wl = np.asarray(wavelengths_nm, float)
    knots = np.linspace(float(wl.min()), float(wl.max()), count)

    def as_knots(dye) -> dict:
        mu = dye(knots) if dye is not None else np.full(count, 1e-3)
        return {"curve": "knots", "wavelength_nm": [round(float(k), 3) for k in knots],
                "log10_per_um": [round(float(v), 6) for v in np.log10(np.clip(mu, 1e-4, 3.0))]}

    doc = tomllib.loads(config.text)
    doc.setdefault("fiber", {})["dye"] = as_knots(config.dye)
    # a blend: each population its own knots, sampled from its dye (its own, or the config's it took)
    for item, pop in zip(doc.get("populations") or [], config.populations or (), strict=True):
        item.setdefault("fiber", {})["dye"] = as_knots(pop.dye)
    return parse_config(toml_dumps(doc), f"{config.name}.toml", source=config.source)


def knot_indices(names: list[str]) -> dict[int, int]:
    """``{free-parameter index: knot index}`` of the free dye knots among ``names``.

    The knots of the config's dye and of the populations' dyes.

    Parameters
    ----------
    names : list of str
        The free parameters' names.

    Returns
    -------
    dict of int to int
        Free-parameter index -> knot index.
    """
    return {i: k for i, (_, k) in knot_owners(names).items()}


def knot_owners(names: list[str]) -> dict[int, tuple[int | None, int]]:
    """``{free-parameter index: (population, knot index)}`` of the free dye knots among ``names``.

    Population None for the config's ``[fiber.dye]``, ``k`` for ``populations[k]``'s own.

    Parameters
    ----------
    names : list of str
        The free parameters' names.

    Returns
    -------
    dict of int to (int or None, int)
        Free-parameter index -> ``(population, knot index)``.
    """
    out: dict[int, tuple[int | None, int]] = {}
    for i, name in enumerate(names):
        m = _KNOT.match(name)
        if m:
            out[i] = (None if m.group(1) is None else int(m.group(1)), int(m.group(2)))
    return out


def _bands_at_colour_geometry(problem) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(g*, M, m)``: the model geometry row of the colour geometry, the band matrix, the measured bands."""
    res = problem.residual_model()
    if not res.has_colour:
        return None
    geo = res.colour_geometry
    g = problem.geometries
    cols = ["theta_i", "phi_i", "theta_o", "phi_o"]
    dist = sum((g[c].to_numpy(float) - float(geo[c])) ** 2 for c in cols)
    g_star = int(np.argmin(dist))
    t = problem.measured.table
    sel = np.ones(len(t), dtype=bool)
    for c in cols:
        sel &= np.abs(t[c].to_numpy(float) - float(g.iloc[g_star][c])) < 1e-6
    rows = t[sel]
    wl = problem.wavelengths_nm
    if "channel" in t.columns:
        channels = [c for c in ("R", "G", "B") if c in set(rows["channel"])]
        if len(channels) < 3:
            return None
        m = np.array([float(rows.loc[rows["channel"] == c, "beta"].mean()) for c in channels])
        M = conversion_matrix(wl, channels, problem.measured.meta.get("colour_space") or "linear sRGB")
    else:
        rows = rows.groupby("wavelength_nm")["beta"].mean()
        mw = rows.index.to_numpy(float)
        keep = (mw >= wl.min()) & (mw <= wl.max())
        mw, m = mw[keep], rows.to_numpy(float)[keep]
        eye = np.eye(wl.size)
        M = np.array([np.interp(mw, wl, eye[l]) for l in range(wl.size)]).T
    if m.size < 2 or not np.all(m > 0):
        return None
    return g_star, M, m


def inverted_start(problem, x: np.ndarray) -> tuple[np.ndarray, str]:
    """``x`` with its free dye knots set by the inversion of the module docstring, and a note.

    Returns ``x`` unchanged (and says why in the note) when no knot is free, the measurement has no
    colour, or no three bands at the colour geometry.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit.
    x : numpy.ndarray
        The start point, one value per free parameter.

    Returns
    -------
    x : numpy.ndarray
        The start point with the knots set (a copy; ``x`` itself when unchanged).
    note : str
        How the fit starts.
    """
    config = problem.config_at(x)
    if config.populations and len(config.populations) > 1:
        return _inverted_blend(problem, x, config)
    config = config.population_configs()[0][1]      # one population: its fiber (its own dye)
    idx = knot_indices([p.name for p in problem.free])
    if not idx or config.dye is None or config.dye.curve != "knots":
        return x, "no free dye knots: the config's values start the fit"
    bands = _bands_at_colour_geometry(problem)
    if bands is None:
        return x, "the measurement has no colour at its colour geometry: the config's knots start the fit"
    g_star, M, m = bands
    wl = problem.wavelengths_nm
    table = problem.table(config)
    xg = np.linspace(math.log(NU_0), math.log(table.nu_max + NU_0), _GRID)
    nu = np.clip(np.exp(xg) - NU_0, 0.0, table.nu_max)
    B = np.array([problem.model_at_host(config, np.full(wl.size, v))[0][g_star] for v in nu])  # [J, L]
    logB = np.log(np.maximum(B, 1e-300))
    knots_nm = np.asarray(config.dye.params["wavelength_nm"], float)
    values = np.asarray(config.dye.params["log10_per_um"], float)
    free_k = np.array(sorted(idx.values()))
    lo = np.array([problem.free[i].low for i in sorted(idx)])
    hi = np.array([problem.free[i].high for i in sorted(idx)])
    log_m = np.log(m)

    def residual(v: np.ndarray) -> np.ndarray:
        vals = values.copy()
        vals[free_k] = v
        xl = np.log(knots_curve(knots_nm, vals, wl) + NU_0)
        beta = np.exp([np.interp(xl[l], xg, logB[:, l]) for l in range(wl.size)])
        d = np.log(np.maximum(M @ beta, 1e-12)) - log_m
        return np.concatenate([d - d.mean(), [W_LEVEL * d.mean()], W_SMOOTH * np.diff(vals, 2)])

    best = None
    for v0 in (np.clip(values[free_k], lo, hi), np.clip(np.full(free_k.size, -1.5), lo, hi)):
        sol = least_squares(residual, v0, bounds=(lo, hi), method="trf")
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    out = x.copy()
    for i, k in sorted(idx.items()):
        out[i] = float(np.clip(best.x[int(np.searchsorted(free_k, k))], problem.free[i].low, problem.free[i].high))
    ratio_err = float(np.max(np.abs(residual(best.x)[:m.size])))
    note = (f"dye knots started from the measurement's colour (inverted at the colour geometry through the "
            f"model's absorption table; largest band-ratio error {ratio_err:.3f} in log)")
    log.info("%s", note)
    return out, note


def _inverted_blend(problem, x: np.ndarray, config) -> tuple[np.ndarray, str]:
    """The colour start of a blend.

    Every free knot of every population moved by ONE offset per knot ``delta`` (log10), solved so that the
    share-weighted mix has the measured colour (the residual of the module docstring with the mix in place of one
    fiber; second differences of ``delta``). The populations keep their differences from each other (what sets their
    share apart); the offset gives the mix the measured colour.
    """
    owners = knot_owners([p.name for p in problem.free])
    pops = config.population_configs()
    free_pops = sorted({k for k, _ in owners.values() if k is not None})
    if not free_pops:
        return x, "no free dye knots of a population: the config's values start the fit"
    dyes = [c.dye for _, c in pops]
    if any(d is None or d.curve != "knots" for d in dyes):
        return x, "a population's dye is not knots: the config's values start the fit"
    grids = {tuple(np.asarray(d.params["wavelength_nm"], float)) for d in dyes}
    if len(grids) != 1:
        return x, "the populations' knots lie at different wavelengths: the config's values start the fit"
    bands = _bands_at_colour_geometry(problem)
    if bands is None:
        return x, "the measurement has no colour at its colour geometry: the config's knots start the fit"
    g_star, M, m = bands
    wl = problem.wavelengths_nm
    knots_nm = np.asarray(dyes[0].params["wavelength_nm"], float)
    K = knots_nm.size
    values = [np.asarray(d.params["log10_per_um"], float) for d in dyes]
    free_mask = np.zeros((len(pops), K), dtype=bool)
    lo = np.full(K, -np.inf)
    hi = np.full(K, np.inf)
    for i, (k, j) in owners.items():
        if k is None:
            continue
        free_mask[k, j] = True
        lo[j] = max(lo[j], problem.free[i].low - values[k][j])
        hi[j] = min(hi[j], problem.free[i].high - values[k][j])
    moved = free_mask.any(axis=0)
    lo, hi = np.where(moved, lo, -1e-9), np.where(moved, hi, 1e-9)
    if np.any(lo >= hi):
        return x, "the populations' knots leave no common room within their bounds: the config's values start the fit"
    table = problem.table(pops[0][1])      # the populations share the fiber's scattering (make_spec): one table
    xg = np.linspace(math.log(NU_0), math.log(table.nu_max + NU_0), _GRID)
    nu = np.clip(np.exp(xg) - NU_0, 0.0, table.nu_max)
    B = np.array([problem.model_at_host(pops[0][1], np.full(wl.size, v))[0][g_star] for v in nu])  # [J, L]
    logB = np.log(np.maximum(B, 1e-300))
    shares = np.array([share for share, _ in pops])
    log_m = np.log(m)

    def shifted(delta: np.ndarray) -> list[np.ndarray]:
        return [v + np.where(free_mask[k], delta, 0.0) for k, v in enumerate(values)]

    def residual(delta: np.ndarray) -> np.ndarray:
        mix = np.zeros(wl.size)
        for share, vals in zip(shares, shifted(delta), strict=True):
            xl = np.log(knots_curve(knots_nm, vals, wl) + NU_0)
            mix += share * np.exp([np.interp(xl[l], xg, logB[:, l]) for l in range(wl.size)])
        d = np.log(np.maximum(M @ mix, 1e-12)) - log_m
        return np.concatenate([d - d.mean(), [W_LEVEL * d.mean()], W_SMOOTH * np.diff(delta, 2)])

    sol = least_squares(residual, np.clip(np.zeros(K), lo, hi), bounds=(lo, hi), method="trf")
    new = shifted(sol.x)
    out = x.copy()
    for i, (k, j) in owners.items():
        if k is not None:
            out[i] = float(np.clip(new[k][j], problem.free[i].low, problem.free[i].high))
    ratio_err = float(np.max(np.abs(residual(sol.x)[:m.size])))
    note = (f"the populations' dye knots started from the measurement's colour: one offset per knot for all of them, "
            f"so that their share-weighted mix has the measured colour (largest band-ratio error {ratio_err:.3f} "
            "in log)")
    log.info("%s", note)
    return out, note
