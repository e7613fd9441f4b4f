r"""Two shape ratios of any BRDF dataset: opposition (shadow-hiding) and mirror-to-neighbours.

Both are ratios of one dataset's own values at one wavelength (or channel), so the normalisation
factor ``k(lambda)`` of a comparison cancels: they are the same for a simulation before and
after normalising, and a model is judged by its ratio against the measurement's. A felt's fibres
show in both (docs/notes/felt-structure.md), but nothing here is felt-specific.

**Opposition ratio** (shadow-hiding). At an incidence ``theta_i > 0`` let ``w_r`` be the retro
direction (towards the source). The *ring at rho* is the set of directions at angle ``rho`` from
``w_r``; ``beta`` averaged over the dataset's points on the ring at 6 deg over its average on the
ring at 30 deg,

.. math::

    O(\lambda) = \frac{\langle \beta \rangle_{\angle(w_o, w_r) = 6^\circ}}
                      {\langle \beta \rangle_{\angle(w_o, w_r) = 30^\circ}},

per wavelength. A point belongs to a ring when its angle from ``w_r`` is within
:data:`RING_TOL_DEG` of the ring's. A ring's average is the mean over its azimuth sectors about
``w_r`` (:data:`SECTORS`, 30 deg each) of each sector's mean, so that points a plan adds on one
side do not weight it; a ring needs points in at least :data:`MIN_RING_POINTS` sectors spread
round it (the length of the mean of the sectors' unit vectors at most
:data:`MAX_RING_RESULTANT`: a ring seen from one side only would measure a slope, not a peak).
Sample rotations of one incidence are pooled. :func:`ring_directions` gives the
``(theta_o, phi_o - phi_i)`` pairs of a ring, to put in a plan's ``directions_deg``.

**Mirror-to-neighbours ratio**. In the plane of incidence, ``beta`` at the mirror direction
(signed angle ``s = theta_i`` within :data:`MIRROR_TOL_DEG`) over the mean of its two in-plane
neighbours, one on each side, at ``s - theta_i`` in ``[-15, -10]`` and ``[10, 15]`` deg (the one
nearest 10 deg on each side). A mirror lobe gives a ratio well above 1; a smooth diffuse curve
about 1.

Uncertainties: ``u_beta`` propagated to first order (independent points).

When a dataset holds no incidence with the points a ratio needs, the ratio is None with a
reason (:class:`Missing`); the ``metrics.json`` document of :mod:`compare.comparison` carries
either the ratios per incidence or that reason, under ``"shape"``.

Examples
--------
>>> d = ring_directions(40.0, 6.0, 4)
>>> [(round(t, 2), round(p, 2)) for t, p in d]
[(34.0, 0.0), (40.37, 350.71), (46.0, 0.0), (40.37, 9.29)]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["INNER_DEG", "OUTER_DEG", "RING_TOL_DEG", "SECTORS", "MIN_RING_POINTS", "MAX_RING_RESULTANT",
           "MIRROR_TOL_DEG", "NEIGHBOUR_DEG", "Missing", "Ratio", "ring_directions",
           "opposition_ratios", "mirror_ratios", "shape_document"]

#: the rings' angular radii about the retro direction, degrees
INNER_DEG = 6.0
OUTER_DEG = 30.0
#: a point is on a ring when its angle from the retro direction is within this of the ring's
RING_TOL_DEG = 0.5
#: the ring's azimuth sectors about the retro direction (centred on 0, 30, ... deg from the plane
#: of incidence); the ring's mean is the mean of its sectors' means
SECTORS = 12
#: a ring needs points in this many sectors, spread round it (their mean unit vector at most this long)
MIN_RING_POINTS = 4
MAX_RING_RESULTANT = 0.5
#: the mirror point's tolerance in ``s`` and the neighbours' range of ``|s - theta_i|``, degrees
MIRROR_TOL_DEG = 0.5
NEIGHBOUR_DEG = (10.0, 15.0)
#: incidences below this have no distinct retro ring (the ring would straddle the normal)
MIN_THETA_I_DEG = 1.0


@dataclass(frozen=True)
class Ratio:
    """A ratio at one incidence.

    ``value[band]`` and ``u[band]`` per wavelength or channel code, and the number of points of
    the numerator and the denominator.
    """

    theta_i: float
    value: dict
    u: dict
    n_points: tuple[int, int]


@dataclass(frozen=True)
class Missing:
    """No ratio: ``reason`` says which points the dataset lacks."""

    reason: str


def _unit(theta_deg, phi_deg) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _retro_frame(theta_i: np.ndarray, phi_i: np.ndarray):
    """The retro direction ``w_r`` and a frame about it, per row.

    ``e1`` lies in the plane of incidence, towards the normal; ``e2`` completes the frame.
    """
    w_r = _unit(theta_i, phi_i)
    e1 = _unit(np.asarray(theta_i) - 90.0, phi_i)       # in plane, perpendicular to w_r
    e2 = np.cross(w_r, e1)
    return w_r, e1, e2


def ring_directions(theta_i: float, radius_deg: float, n: int = 12) -> list[tuple[float, float]]:
    """``n`` directions evenly round a ring about the retro direction of incidence ``theta_i``.

    The ring is ``radius_deg`` from the retro direction (``phi_i = 0``); the directions are
    ``(theta_o, phi_o - phi_i)`` in degrees (azimuth in [0, 360)), those below the horizon
    (``theta_o >= 90``) left out.

    Parameters
    ----------
    theta_i : float
        Incidence zenith angle, degrees.
    radius_deg : float
        Angle of the ring's directions from the retro direction, degrees.
    n : int
        Directions on the ring, evenly spaced in azimuth about the retro direction.

    Returns
    -------
    list of (float, float)
        ``(theta_o, phi_o - phi_i)`` pairs, degrees: a plan's ``directions_deg``.
    """
    w_r, e1, e2 = (v[0] for v in _retro_frame(np.array([theta_i]), np.array([0.0])))
    rho = math.radians(radius_deg)
    out = []
    for k in range(n):
        psi = 2.0 * math.pi * k / n
        w = math.cos(rho) * w_r + math.sin(rho) * (math.cos(psi) * e1 + math.sin(psi) * e2)
        if w[2] <= 1e-9:
            continue
        theta = math.degrees(math.acos(min(1.0, w[2])))
        phi = math.degrees(math.atan2(w[1], w[0])) % 360.0 if theta > 1e-9 else 180.0
        phi = 0.0 if phi > 360.0 - 1e-9 else phi
        out.append((theta, phi))
    return out


_DIRECTION_COLUMNS = ["phi_i", "theta_o", "phi_o"]


def _n_geometries(rows: pd.DataFrame) -> int:
    return int(len(rows[_DIRECTION_COLUMNS].drop_duplicates()))


def _band_column(table: pd.DataFrame) -> str:
    return "channel" if "channel" in table.columns else "wavelength_nm"


def _mean_per_band(rows: pd.DataFrame, band: str) -> tuple[pd.Series, pd.Series]:
    g = rows.groupby(band, sort=True)
    mean = g["beta"].mean()
    u = g["u_beta"].apply(lambda x: float(np.sqrt(np.sum(np.square(x.to_numpy(float))))) / len(x))
    return mean, u


def _ring_mean(rows: pd.DataFrame, band: str) -> tuple[pd.Series, pd.Series]:
    """Per band, the mean over the ring's azimuth sectors of each sector's mean.

    A ring sampled more densely on one side is then not weighted towards it.
    """
    per = rows.groupby(["_sector", band], sort=True)
    m = per["beta"].mean()
    u2 = per["u_beta"].apply(lambda x: float(np.sum(np.square(x.to_numpy(float)))) / len(x) ** 2)
    g_m, g_u = m.groupby(level=band), u2.groupby(level=band)
    return g_m.mean(), np.sqrt(g_u.sum()) / g_m.count()


def _ratio(num: tuple[pd.Series, pd.Series], den: tuple[pd.Series, pd.Series]) -> tuple[dict, dict]:
    (a, ua), (b, ub) = num, den
    shared = a.index.intersection(b.index)
    value, u = {}, {}
    for key in shared:
        r = float(a[key]) / float(b[key]) if float(b[key]) != 0.0 else float("nan")
        rel = math.hypot(float(ua[key]) / float(a[key]) if float(a[key]) else 0.0,
                         float(ub[key]) / float(b[key]) if float(b[key]) else 0.0)
        value[key], u[key] = r, abs(r) * rel
    return value, u


def opposition_ratios(table: pd.DataFrame, inner_deg: float = INNER_DEG,
                      outer_deg: float = OUTER_DEG) -> dict[float, Ratio] | Missing:
    """The opposition ratio at every oblique incidence of ``table`` that holds both rings.

    ``table`` is a dataset's table (columns ``theta_i, phi_i, theta_o, phi_o``, ``wavelength_nm``
    or ``channel``, ``beta``, ``u_beta``); the ratios are keyed by ``theta_i`` (module docstring),
    :class:`Missing` when no incidence holds both rings.

    Parameters
    ----------
    table : pandas.DataFrame
        A dataset's table.
    inner_deg, outer_deg : float
        The rings' angles from the retro direction, degrees (numerator and denominator).

    Returns
    -------
    dict of float -> Ratio, or Missing
        The ratio per incidence, or why there is none.

    Examples
    --------
    >>> rows = []
    >>> for rho, beta in ((6.0, 1.2), (30.0, 1.0)):
    ...     for t, p in ring_directions(40.0, rho, 8):
    ...         rows.append(dict(theta_i=40.0, phi_i=0.0, theta_o=t, phi_o=p, wavelength_nm=550.0,
    ...                          beta=beta, u_beta=0.0))
    >>> r = opposition_ratios(pd.DataFrame(rows))
    >>> round(r[40.0].value[550.0], 6), r[40.0].n_points
    (1.2, (8, 8))
    """
    band = _band_column(table)
    out: dict[float, Ratio] = {}
    why = []
    for theta_i, rows in table.groupby("theta_i", sort=True):
        if theta_i < MIN_THETA_I_DEG:
            continue
        ti, pi = rows["theta_i"].to_numpy(float), rows["phi_i"].to_numpy(float)
        w_r, e1, e2 = _retro_frame(ti, pi)
        w_o = _unit(rows["theta_o"].to_numpy(float), rows["phi_o"].to_numpy(float))
        ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", w_o, w_r), -1.0, 1.0)))
        psi = np.arctan2(np.einsum("ij,ij->i", w_o, e2), np.einsum("ij,ij->i", w_o, e1))
        sector = np.mod(np.rint(psi / (2.0 * math.pi / SECTORS)), SECTORS).astype(int)
        rings = []
        for rho in (inner_deg, outer_deg):
            on = np.abs(ang - rho) <= RING_TOL_DEG
            n = _n_geometries(rows.loc[on])
            held = np.unique(sector[on])
            spread = abs(np.mean(np.exp(2j * math.pi * held / SECTORS))) if held.size else 1.0
            if held.size < MIN_RING_POINTS or spread > MAX_RING_RESULTANT:
                why.append(f"{theta_i:g} deg: {n} point(s) on the ring at {rho:g} deg"
                           + (f" (all on one side, mean azimuth vector {spread:.2f})"
                              if held.size >= MIN_RING_POINTS else ""))
                break
            rings.append((_ring_mean(rows.loc[on].assign(_sector=sector[on]), band), n))
        if len(rings) < 2:
            continue
        value, u = _ratio(rings[0][0], rings[1][0])
        out[float(theta_i)] = Ratio(float(theta_i), value, u, (rings[0][1], rings[1][1]))
    if out:
        return out
    return Missing(f"no oblique incidence holds both rings about the retro direction (at "
                   f"{inner_deg:g} and {outer_deg:g} deg, >= {MIN_RING_POINTS} points each, "
                   "spread round it)" + (": " + "; ".join(why) if why else ""))


def mirror_ratios(table: pd.DataFrame) -> dict[float, Ratio] | Missing:
    """The mirror-to-neighbours ratio at every oblique incidence of ``table``.

    An incidence needs the in-plane mirror point and a neighbour on each side (module docstring);
    :class:`Missing` when none has them.

    Parameters
    ----------
    table : pandas.DataFrame
        A dataset's table (as :func:`opposition_ratios`).

    Returns
    -------
    dict of float -> Ratio, or Missing
        The ratio per incidence, or why there is none.

    Examples
    --------
    >>> s = [20.0, 30.0, 40.0]
    >>> t = pd.DataFrame(dict(theta_i=30.0, phi_i=0.0, theta_o=s, phi_o=180.0, wavelength_nm=550.0,
    ...                       beta=[1.0, 3.0, 2.0], u_beta=0.0))
    >>> round(mirror_ratios(t)[30.0].value[550.0], 6)
    2.0
    """
    from gonio.data.geometry import signed_angle

    band = _band_column(table)
    lo, hi = NEIGHBOUR_DEG
    out: dict[float, Ratio] = {}
    why = []
    for theta_i, rows in table.groupby("theta_i", sort=True):
        if theta_i < MIN_THETA_I_DEG:
            continue
        s = np.asarray(signed_angle(rows["theta_i"], rows["phi_i"], rows["theta_o"], rows["phi_o"]), float)
        d = s - theta_i
        at = np.abs(d) <= MIRROR_TOL_DEG
        picks = []
        for sign in (-1.0, 1.0):
            side = (sign * d >= lo - 1e-9) & (sign * d <= hi + 1e-9)
            if side.any():
                best = np.min(np.abs(np.abs(d[side]) - lo))
                picks.append(side & (np.abs(np.abs(np.abs(d) - lo) - best) < 1e-9))
        if not at.any() or len(picks) < 2:
            why.append(f"{theta_i:g} deg: " + ("no in-plane point at the mirror direction" if not at.any()
                                               else "no in-plane neighbour on each side at 10-15 deg"))
            continue
        mirror = _mean_per_band(rows.loc[at], band)
        lower, upper = (_mean_per_band(rows.loc[p], band) for p in picks)
        shared = lower[0].index.intersection(upper[0].index)
        nb_mean = 0.5 * (lower[0][shared] + upper[0][shared])
        nb_u = 0.5 * np.hypot(lower[1][shared], upper[1][shared])
        value, u = _ratio(mirror, (nb_mean, nb_u))
        out[float(theta_i)] = Ratio(float(theta_i), value, u,
                                    (_n_geometries(rows.loc[at]), _n_geometries(rows.loc[picks[0] | picks[1]])))
    if out:
        return out
    return Missing("no oblique incidence holds the in-plane mirror point and a neighbour 10-15 deg "
                   "on each side" + (": " + "; ".join(why) if why else ""))


def shape_document(table: pd.DataFrame, key) -> dict:
    """Both ratios of ``table`` as JSON-able data.

    Per ratio either ``{"per_incidence": {theta_i: {"value": {band key: r}, "u": {...},
    "n_points": [num, den]}}}`` or ``{"reason": str}``.

    Parameters
    ----------
    table : pandas.DataFrame
        A dataset's table (as :func:`opposition_ratios`).
    key : callable
        A band's JSON key (:meth:`compare.bands.Bands.key`).

    Returns
    -------
    dict
        ``{"opposition": ..., "mirror": ...}``, the ``"shape"`` entry of ``metrics.json``.
    """
    from .metrics import angle_key

    def num(x):
        x = float(x)
        return x if math.isfinite(x) else None

    doc: dict[str, dict] = {}
    for name, result in (("opposition", opposition_ratios(table)), ("mirror", mirror_ratios(table))):
        if isinstance(result, Missing):
            doc[name] = {"reason": result.reason}
        else:
            doc[name] = {"per_incidence": {
                angle_key(t): {"value": {key(b): num(v) for b, v in r.value.items()},
                               "u": {key(b): num(v) for b, v in r.u.items()},
                               "n_points": list(r.n_points)}
                for t, r in result.items()}}
    return doc
