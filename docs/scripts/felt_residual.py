"""Where a felt simulation's curve error against the felt's file lies, and the one-at-a-time variants that move it.

    python docs/scripts/felt_residual.py variants --out DIR          # DIR/<variant>.toml from green-felt-mc.toml
    python docs/scripts/felt_residual.py decompose FILE RUN [RUN ...] [--max-incidence 59.52] [--json OUT]
    python docs/scripts/felt_residual.py noise FILE RUN_A RUN_B [...] # pairs of seeds of one config: the noise
    python docs/scripts/felt_residual.py realisations FILE --group NAME RUN RUN [...] [--group ...] [--json OUT]
    python docs/scripts/felt_residual.py fixed-felt --felt-seed 0 [--table-factor 4] -- ARGS  # `simulate ARGS`, felts held
    python docs/scripts/felt_residual.py combine FILE BASE --runs DIR --out CONFIG   # every field at once
    python docs/scripts/felt_residual.py permute FILE.bsdf --order gbr --out OTHER.bsdf # another colour
    python docs/scripts/felt_residual.py top CONFIG [CONFIG ...] [--seeds 3] [--json OUT]  # volume fraction below the top
    python docs/scripts/felt_residual.py lambert CONFIG [CONFIG ...] [--json OUT]          # its felt of Lambertian fibres
    python docs/scripts/felt_residual.py phase [CONFIG ...] [--variants] [--felt] [--json OUT] # the fibre's own phase

``decompose`` compares each ``RUN`` (a ``simulate fabric`` dataset) with ``FILE`` (``gonio truth`` of the felt's
file) exactly as ``compare check`` does (:func:`compare.comparison.compare_datasets`: the per-channel factor at the
normal, the aligned points), keeps the points at incidences up to ``--max-incidence`` and splits the curve error
of :mod:`compare.metrics` over them. With ``d_j`` the residual of point ``j`` (geometry x channel), ``N`` the points
and ``m`` the file's mean ``beta`` over them, ``NRMSE^2 = sum_j d_j^2 / (N m^2)``; a set ``A`` of points contributes
``sum_{j in A} d_j^2 / (N m^2)`` (the contributions add up to ``NRMSE^2``), and ``NRMSE without A`` is the NRMSE if
the points of ``A`` were matched exactly (``sqrt(NRMSE^2 - contribution)``). The sets (:func:`region`):

* ``back``: in plane, on the source's side beyond the near-normal window (``s < -near``; the retro direction is
  ``s = -theta_i``), ``near``: ``|s| <= near`` (default 20 deg), ``forward``: ``s > near`` (the mirror direction
  ``s = theta_i``), ``grazing``: ``|theta_o| > 70`` deg in plane (the felt's plans observe up to 70 deg: none);
* ``ring-6``, ``ring-30``: out-of-plane points, by their angle from the retro direction (nearest of 6 and 30 deg);
* per incidence, per channel (or wavelength), and the signed bias ``mean(d) / m`` of each set (+: the model high).

The Monte Carlo noise part: ``noise`` takes two seeds of one config and estimates the noise one run adds to
``NRMSE^2`` from their difference, ``mean((a - b)^2) / 2 / m^2`` (both normalised as above, so the noise of the
normal/normal value that sets each band's factor is in it). ``nrmse_noise_u`` is the same from the points' own
``u_sim`` as if independent (it leaves out the factor's noise and its correlation with the points').
``realisations`` takes groups of runs, each the seeds of one config at one target (``--group NAME RUN RUN ...``; the
runs' felt realisations, ``[method] felt_realisations``, and target read from them), and gives per group the NRMSE of
each seed, their standard deviation and range, one run's noise from every pair of seeds
(as ``noise``, pooled over the pairs in quadrature), and ``z``: every pair of seeds' difference at each point of the
runs (their own values, before any comparison) over the two runs' reported ``u_beta`` combined, its RMS and the
fraction beyond 2 and 3 (an error that holds the spread between seeds gives an RMS near 1); with each run's rays, and
its CPU seconds and peak memory when ``RUN.time`` (the output of ``/usr/bin/time -v -o RUN.time``) is beside it.
``fixed-felt`` runs ``simulate ARGS`` (e.g. ``fabric green-felt-mc --method mc --seed 2 ...``) with every felt
realisation that of the run at ``--felt-seed`` (the tables and rays still follow ``--seed``) and, with
``--table-factor N``, the yarn table walked with ``N`` times the photons: seeds of such runs differ by the tables' and
rays' noise alone, the felt's part of a run's noise taken out.
``nrmse_best_scale`` is the NRMSE with each band's factor the least-squares one over the kept points instead of
the normal's (the shape error with the normalisation point taken out). ``by_band_group`` (and
``by_band_group_region``, ``forward_rise_by_band_group``): the same over the wavelength thirds of
:data:`BAND_GROUPS` (which colour carries an error). ``forward_rise``: per incidence,
``beta(s = 70) / beta(s = 30)`` in plane, file and model (:func:`forward_rise`); ``profile``: per incidence and
in-plane ``s``, the model over the file (band sums, :func:`profile`).
``combine`` takes the one-at-a-time runs (``DIR/<variant>``, each field's two) and the preset's ``BASE`` run
and writes the config with every continuous field changed at once where a separable quadratic through each
field's three runs, fitted point by point, predicts the least NRMSE within the scanned ranges (:func:`combine`).
``permute`` writes an RGB RGL file with its channels reordered (``gbr``: new R, G, B = old G, B, R), the same
felt in another colour for a dye-only refit.
``top`` builds the felt of each ``CONFIG`` (its ``[structure]`` and fibre radius; the felt's streams ``0 .. seeds - 1``:
a ``simulate fabric --method mc`` run at seed 0 traces the first) and gives its volume fraction against the depth below
the felt's top, pooled over the seeds (:func:`top_profile`). ``lambert`` traces the same felt (seed 0) with opaque Lambertian fibres of
the albedos ``--albedo`` and gives the in-plane forward rise ``beta(70)/beta(30)`` at the plan's four incidences, all
orders and the single scattering (:func:`lambert_rise`): the felt's geometry alone, without the fibre's optics.
``phase`` gives the fibre's own far field at the felt's normal incidence, averaged over the axis azimuths in the
felt's plane (:func:`fibre_phase`: exit tables plus the surface term, the construction the felt traces), its
``p(110)/p(150) = S(70)/S(30)`` per band group, the opaque Lambertian fibre's (:func:`lambert_phase`), with
``--variants`` the first config with each fibre field of :data:`PHASE_VARIANTS` changed, with ``--felt`` each
``CONFIG``'s felt traced at normal incidence in single scattering and all orders (:func:`felt_rise`), with
``--oblique`` the fibre's ``S(70)/S(30)`` on the mirror's side at oblique beams (:func:`oblique_phase`).
Bad input (a missing dataset, an incidence limit that keeps no point, a config that is not a felt) is one line
naming it, exit 2.
``--json OUT`` writes the result alone; a table of the notes takes it wrapped with its command and machine:
``python docs/scripts/render_figures.py --record NAME OUT --command "..."`` (``docs/data/NAME.json``).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
PRESET = ROOT / "simulate" / "configs" / "green-felt-mc.toml"
#: in-plane regions (signed observation angle ``s``), then the rings
REGIONS = ("back", "near", "forward", "grazing", "ring-6", "ring-30")
RINGS_DEG = (6.0, 30.0)
GRAZING_DEG = 70.0
#: wavelength groups (name, first, last band in nm): the blue, green and red thirds an RGB file's spectra come from
BAND_GROUPS: tuple[tuple[str, float, float], ...] = (("390-500 nm", 390.0, 500.0), ("510-580 nm", 510.0, 580.0),
                                                      ("590-710 nm", 590.0, 710.0))

#: (name, TOML section, key, value): one field of ``green-felt-mc.toml`` changed, each both ways where it can be
VARIANTS: tuple[tuple[str, str, str, Any], ...] = (
    ("scatterers-x0.5", "particles", "volume_fraction", 0.00042),
    ("scatterers-x2", "particles", "volume_fraction", 0.00168),
    ("radius-6", "fiber", "radius_um", 6.0),
    ("radius-11", "fiber", "radius_um", 11.0),
    ("rms-slope-0.2", "surface", "rms_slope", 0.2),
    ("rms-slope-0.5", "surface", "rms_slope", 0.5),
    ("around-0.3", "surface", "transmission_rms_slope_around", 0.3),
    ("around-0.7", "surface", "transmission_rms_slope_around", 0.7),
    ("spread-2", "structure", "felt_spread_deg", 2.0),
    ("spread-10", "structure", "felt_spread_deg", 10.0),
    ("punched-0.1", "structure", "felt_normal_fraction", 0.1),
    ("punched-0.3", "structure", "felt_normal_fraction", 0.3),
    ("crimp-7", "structure", "felt_crimp_percent", 7.0),
    ("crimp-13", "structure", "felt_crimp_percent", 13.0),
)
#: (name, TOML section, {key: value}): fields of one model changed together (a loose top: its fraction of the
#: fiber amount and its depth); written with :data:`VARIANTS`, left out of ``combine``
JOINT_VARIANTS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("fuzz-0.05-300", "structure", {"felt_fuzz_fraction": 0.05, "felt_fuzz_depth_um": 300.0}),
    ("fuzz-0.1-300", "structure", {"felt_fuzz_fraction": 0.1, "felt_fuzz_depth_um": 300.0}),
    ("fuzz-0.2-600", "structure", {"felt_fuzz_fraction": 0.2, "felt_fuzz_depth_um": 600.0}),
    ("fuzz-0.3-1000", "structure", {"felt_fuzz_fraction": 0.3, "felt_fuzz_depth_um": 1000.0}),
)


class InputError(Exception):
    """Bad input: the message is the one line a user sees."""


# ---------------------------------------------------------------------------------------------- variants

def _toml_value(v: Any) -> str:
    """``v`` as a TOML value: a string quoted, a dict as an inline table, a number as Python prints it."""
    if isinstance(v, dict):     # an inline table
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    return json.dumps(v) if isinstance(v, str) else repr(v)


def set_field(text: str, section: str, key: str, value: Any) -> str:
    """``text`` (a TOML document) with ``key`` of ``[section]`` set to ``value``.

    The key's line is replaced if the section has it, else added as the section's first line.

    Parameters
    ----------
    text : str
        The TOML document.
    section : str
        The table's name, as its header writes it.
    key : str
        The key to set.
    value : Any
        Its value (a dict is written as an inline table).

    Returns
    -------
    str
        The document with the key set; every other line unchanged.

    Raises
    ------
    InputError
        The document has no ``[section]``.
    """
    lines = text.splitlines(keepends=True)
    header = re.compile(r"^\s*\[([^\]]+)\]\s*(#.*)?$")
    start = next((i for i, ln in enumerate(lines) if (m := header.match(ln)) and m.group(1).strip() == section), None)
    if start is None:
        raise InputError(f"the config has no [{section}] section to set {key} in")
    end = next((i for i in range(start + 1, len(lines)) if header.match(lines[i])), len(lines))
    line = f"{key} = {_toml_value(value)}\n"
    own = re.compile(rf"^\s*{re.escape(key)}\s*=")
    for i in range(start + 1, end):
        if own.match(lines[i]):
            lines[i] = line
            return "".join(lines)
    lines.insert(start + 1, line)
    return "".join(lines)


def write_variants(preset: Path, out: Path, force: bool = False) -> list[Path]:
    """One config per :data:`VARIANTS` and :data:`JOINT_VARIANTS` entry in ``out``, named after it.

    Its ``name`` field is the variant's name too.

    Parameters
    ----------
    preset : pathlib.Path
        The preset's TOML file.
    out : pathlib.Path
        The folder to write to (made when absent).
    force : bool
        Replace existing files of the same names.

    Returns
    -------
    list of pathlib.Path
        The written configs, in the tables' order.

    Raises
    ------
    InputError
        The preset cannot be read, or a file exists without ``force`` (the ones before it are written).
    """
    try:
        text = preset.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{preset}: cannot read the preset ({exc.strerror})") from None
    out.mkdir(parents=True, exist_ok=True)
    written = []
    changes = [(name, section, {key: value}) for name, section, key, value in VARIANTS] + list(JOINT_VARIANTS)
    for name, section, fields in changes:
        path = out / f"{name}.toml"
        if path.exists() and not force:
            raise InputError(f"{path} exists; pass --force to replace it")
        body = text
        for key, value in fields.items():
            body = set_field(body, section, key, value)
        body = re.sub(r'(?m)^name = ".*"$', f'name = "{name}"', body, count=1)
        path.write_text(body, encoding="utf-8")
        written.append(path)
    return written


# ---------------------------------------------------------------------------------------------- decomposition

def _unit(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    """Unit vectors of the polar angles ``theta_deg`` and azimuths ``phi_deg`` (deg), ``[..., 3]``."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def retro_distance_deg(frame: pd.DataFrame) -> np.ndarray:
    """Angle (deg) between each point's observation direction and its source (retro) direction.

    Parameters
    ----------
    frame : pandas.DataFrame
        Points with ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o`` (deg).

    Returns
    -------
    numpy.ndarray
        The angle per point (deg).
    """
    a = _unit(frame["theta_i"].to_numpy(float), frame["phi_i"].to_numpy(float))
    b = _unit(frame["theta_o"].to_numpy(float), frame["phi_o"].to_numpy(float))
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def region(frame: pd.DataFrame, near_deg: float = 20.0) -> np.ndarray:
    """The region (:data:`REGIONS`) of each point of an aligned frame (module docstring).

    Parameters
    ----------
    frame : pandas.DataFrame
        Aligned points with the signed in-plane angle ``s`` (NaN out of plane) and the angles.
    near_deg : float
        Half-width of the near-normal region (deg).

    Returns
    -------
    numpy.ndarray
        The region's name per point (object array).
    """
    s = frame["s"].to_numpy(float)
    out = np.empty(len(frame), dtype=object)
    inplane = np.isfinite(s)
    out[inplane & (s < -near_deg)] = "back"
    out[inplane & (np.abs(s) <= near_deg)] = "near"
    out[inplane & (s > near_deg)] = "forward"
    out[inplane & (np.abs(s) > GRAZING_DEG)] = "grazing"
    dist = retro_distance_deg(frame)
    rings = np.asarray(RINGS_DEG)
    nearest = rings[np.argmin(np.abs(dist[:, None] - rings[None, :]), axis=1)]
    for r in RINGS_DEG:
        out[~inplane & (nearest == r)] = f"ring-{r:g}"
    return out


def _parts(d: np.ndarray, u: np.ndarray, meas: np.ndarray, m: float, keys: np.ndarray, order: list) -> dict[str, Any]:
    """The squared error of the points split by ``keys`` (in ``order``): share, contribution, NRMSE without, bias, noise."""
    n_all = d.size
    total = float(np.sum(d * d))
    out: dict[str, dict[str, Any]] = {}
    for k in order:
        sel = keys == k
        n = int(sel.sum())
        if n == 0:
            out[str(k)] = {"n": 0}
            continue
        s2 = float(np.sum(d[sel] ** 2))
        out[str(k)] = {"n": n, "share": s2 / total if total > 0 else math.nan, "nrmse_own": math.sqrt(s2 / n) / float(np.mean(meas[sel])),
                       "contribution": s2 / (n_all * m * m),
                       "nrmse_without": math.sqrt(max(total - s2, 0.0) / n_all) / m,
                       "rms_rel": math.sqrt(s2 / n) / m, "bias_rel": float(np.mean(d[sel])) / m,
                       "noise_rel": math.sqrt(float(np.mean(u[sel] ** 2))) / m}
    return out


def forward_rise(frame: pd.DataFrame, low_deg: float = 30.0, high_deg: float = GRAZING_DEG) -> dict[str, dict]:
    """Per incidence, the in-plane forward rise ``beta(s = high) / beta(s = low)`` of the file and of the model.

    Each is the ratio of the band sums (the normalisation cancels in it); incidences lacking either
    point are left out.

    Parameters
    ----------
    frame : pandas.DataFrame
        Aligned points with ``s``, ``beta_meas`` and ``beta_sim``.
    low_deg, high_deg : float
        The two in-plane angles (deg).

    Returns
    -------
    dict
        ``{incidence: {"measured": ratio, "simulated": ratio}}``, the incidence as ``"27.76"``.
    """
    out = {}
    s = frame["s"].to_numpy(float)
    for theta_i in sorted(frame["theta_i"].unique()):
        rows = frame[(frame["theta_i"] == theta_i).to_numpy() & np.isfinite(s)]
        lo = rows[np.abs(rows["s"].to_numpy(float) - low_deg) < 1e-6]
        hi = rows[np.abs(rows["s"].to_numpy(float) - high_deg) < 1e-6]
        if lo.empty or hi.empty:
            continue
        j = lo.merge(hi, on="wavelength_nm", suffixes=("_lo", "_hi"))
        out[f"{theta_i:g}"] = {key: float(j[f"{col}_hi"].sum() / j[f"{col}_lo"].sum())
                               for key, col in (("measured", "beta_meas"), ("simulated", "beta_sim"))}
    return out


def band_group(wavelength_nm: np.ndarray) -> np.ndarray:
    """The :data:`BAND_GROUPS` name of each wavelength (``"other"`` outside them).

    Parameters
    ----------
    wavelength_nm : numpy.ndarray
        Wavelengths (nm).

    Returns
    -------
    numpy.ndarray
        The group's name per wavelength (object array).
    """
    w = np.asarray(wavelength_nm, dtype=float)
    out = np.full(w.shape, "other", dtype=object)
    for name, lo, hi in BAND_GROUPS:
        out[(w >= lo - 1e-9) & (w <= hi + 1e-9)] = name
    return out


def profile(frame: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Per incidence and in-plane ``s``: the model over the file, each summed over the bands.

    The curve's shape error where it lies; a geometry whose file sum is not positive is left out.

    Parameters
    ----------
    frame : pandas.DataFrame
        Aligned points with ``s``, ``beta_meas`` and ``beta_sim``.

    Returns
    -------
    dict
        ``{incidence: {s: model over file}}``, both keys as ``"%g"`` strings.
    """
    rows = frame[np.isfinite(frame["s"].to_numpy(float))]
    out: dict[str, dict[str, float]] = {}
    for (theta_i, s), g in rows.groupby(["theta_i", "s"], sort=True):
        meas = float(g["beta_meas"].sum())
        if meas > 0:
            out.setdefault(f"{theta_i:g}", {})[f"{s:g}"] = float(g["beta_sim"].sum()) / meas
    return out


def best_scale_nrmse(frame: pd.DataFrame) -> float:
    """The NRMSE if each band's factor were the least-squares one over the frame's points.

    Instead of the normal's: ``k_b = sum(meas C) / sum(C^2)`` per band, the curves' shape error with the
    normalisation point taken out.

    Parameters
    ----------
    frame : pandas.DataFrame
        Aligned points with ``wavelength_nm``, ``beta_meas`` and ``beta_sim``.

    Returns
    -------
    float
        The NRMSE over the file's mean ``beta``.
    """
    meas = frame["beta_meas"].to_numpy(float)
    sim = frame["beta_sim"].to_numpy(float)
    bands = frame["wavelength_nm"].to_numpy(float)
    fitted = np.empty_like(sim)
    for b in np.unique(bands):
        sel = bands == b
        c2 = float(np.sum(sim[sel] ** 2))
        fitted[sel] = sim[sel] * (float(np.sum(meas[sel] * sim[sel])) / c2 if c2 > 0 else 0.0)
    return math.sqrt(float(np.mean((fitted - meas) ** 2))) / float(np.mean(meas))


def decompose_frame(frame: pd.DataFrame, near_deg: float = 20.0,
                    band_label=lambda b: f"{float(b):g}") -> dict[str, Any]:
    """The curve error of an aligned, normalised frame split by incidence, region, band and plane.

    The frame has the columns of :func:`compare.align.align` plus ``beta_sim`` and ``u_sim``. The splits
    are by incidence, region, incidence x region, band, band group (and band group x region) and in
    plane / out of plane, with the forward rise of each incidence (:func:`forward_rise`), the profile
    and the NRMSE with each band's least-squares factor.

    Parameters
    ----------
    frame : pandas.DataFrame
        The aligned points kept.
    near_deg : float
        Half-width of the near-normal region (deg).
    band_label : callable
        The name of a band from its wavelength (the comparison's labels).

    Returns
    -------
    dict
        ``n``, ``mean_meas``, ``nrmse``, ``nrmse_noise_u`` and the splits (module docstring).

    Raises
    ------
    InputError
        The frame is empty, or the file's mean ``beta`` over it is not positive.
    """
    if frame.empty:
        raise InputError("no point to decompose")
    meas = frame["beta_meas"].to_numpy(float)
    d = frame["beta_sim"].to_numpy(float) - meas
    u = frame["u_sim"].to_numpy(float) if "u_sim" in frame else np.zeros_like(d)
    u = np.where(np.isfinite(u), u, 0.0)
    n, m = d.size, float(np.mean(meas))
    if not m > 0:
        raise InputError("the file's mean beta over the kept points is not positive: no NRMSE")
    reg = region(frame, near_deg)
    inc = np.array([f"{t:g}" for t in frame["theta_i"].to_numpy(float)], dtype=object)
    incidences = sorted(set(inc), key=float)
    bands = np.array([band_label(b) for b in frame["wavelength_nm"].to_numpy(float)], dtype=object)
    band_order = [band_label(b) for b in sorted(set(frame["wavelength_nm"].to_numpy(float)))]
    plane = np.where(np.isfinite(frame["s"].to_numpy(float)), "in plane", "out of plane").astype(object)
    cross = np.array([f"{a}|{b}" for a, b in zip(inc, reg, strict=True)], dtype=object)
    group = band_group(frame["wavelength_nm"].to_numpy(float))
    groups = [g for g, _, _ in BAND_GROUPS] + (["other"] if np.any(group == "other") else [])
    group_reg = np.array([f"{a}|{b}" for a, b in zip(group, reg, strict=True)], dtype=object)
    nrmse = math.sqrt(float(np.mean(d * d))) / m
    noise = math.sqrt(float(np.mean(u * u))) / m
    return {"n": n, "mean_meas": m, "nrmse": nrmse, "nrmse_noise_u": noise,
            "forward_rise": forward_rise(frame), "profile": profile(frame),
            "nrmse_best_scale": best_scale_nrmse(frame),
            "by_incidence": _parts(d, u, meas, m, inc, incidences),
            "by_region": _parts(d, u, meas, m, reg, list(REGIONS)),
            "by_incidence_region": _parts(d, u, meas, m, cross, [f"{a}|{b}" for a in incidences for b in REGIONS]),
            "by_band": _parts(d, u, meas, m, bands, band_order),
            "by_plane": _parts(d, u, meas, m, plane, ["in plane", "out of plane"]),
            "by_band_group": _parts(d, u, meas, m, group, groups),
            "by_band_group_region": _parts(d, u, meas, m, group_reg, [f"{a}|{b}" for a in groups for b in REGIONS]),
            "forward_rise_by_band_group": {g: forward_rise(frame[group == g]) for g in groups}}


def seed_noise(a: pd.DataFrame, b: pd.DataFrame) -> dict[str, float]:
    """The noise of one run estimated from two seeds' aligned frames of the same points.

    Per point the difference's mean square over two (the variance of one run when both have the same
    noise), over the file's mean ``beta``; and the expected noise from the runs' own ``u_sim`` for
    comparison.

    Parameters
    ----------
    a, b : pandas.DataFrame
        The two runs' aligned frames.

    Returns
    -------
    dict
        ``n``, ``nrmse_seeds`` and ``nrmse_noise_a``, ``nrmse_noise_b`` (from ``u_sim``).

    Raises
    ------
    InputError
        The two frames do not hold the same points.
    """
    keys = ["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm"]
    j = a.merge(b, on=keys, suffixes=("_a", "_b"))
    if len(j) != len(a) or len(j) != len(b):
        raise InputError("the two runs do not hold the same points; give two seeds of one config at one plan")
    diff = j["beta_sim_a"].to_numpy(float) - j["beta_sim_b"].to_numpy(float)
    m = float(np.mean(j["beta_meas_a"].to_numpy(float)))
    ua, ub = j["u_sim_a"].to_numpy(float), j["u_sim_b"].to_numpy(float)
    return {"n": int(len(j)), "nrmse_seeds": math.sqrt(float(np.mean(diff * diff)) / 2.0) / m,
            "nrmse_noise_a": math.sqrt(float(np.mean(ua * ua))) / m, "nrmse_noise_b": math.sqrt(float(np.mean(ub * ub))) / m}


def fixed_felt(argv: list[str], felt_seed: int, table_factor: int = 1) -> int:
    """``simulate argv`` with every felt realisation that of a run at ``felt_seed`` (module docstring).

    Realisation ``j`` is the felt of seed ``felt_seed + FELT_SEED_STRIDE j``; the yarn table's photons
    are multiplied by ``table_factor``.

    Parameters
    ----------
    argv : list of str
        The arguments of ``simulate``.
    felt_seed : int
        The seed whose felts every run takes (>= 0).
    table_factor : int
        Factor on the yarn table's photons (>= 1).

    Returns
    -------
    int
        ``simulate``'s exit status.

    Raises
    ------
    InputError
        A negative seed or a factor below 1.
    """
    from unittest import mock

    import simulate.geometry.felt as felt
    import simulate.raytrace.estimate as est
    from fabric_optics.cli.simulate import main as simulate_main
    from simulate.products import FELT_SEED_STRIDE

    if felt_seed < 0 or table_factor < 1:
        raise InputError(f"--felt-seed {felt_seed} --table-factor {table_factor}: give a seed >= 0 and a factor >= 1")
    build, photons = felt.cached_felt_mesh, est.table_photons

    def held(spec: Any, radius_um: float, seed: int = 0, **kw: Any) -> Any:
        """The felt of realisation ``seed // FELT_SEED_STRIDE`` at ``felt_seed``."""
        return build(spec, radius_um, seed=felt_seed + FELT_SEED_STRIDE * (seed // FELT_SEED_STRIDE), **kw)

    with mock.patch.object(felt, "cached_felt_mesh", held), \
            mock.patch.object(est, "table_photons", lambda target, **kw: table_factor * photons(target, **kw)):
        return int(simulate_main(argv))


def _time_v(path: Path) -> dict[str, float]:
    """User + system CPU seconds and the peak resident memory (MB) of a ``/usr/bin/time -v`` output; ``{}`` without one."""
    if not path.is_file():
        return {}
    got: dict[str, float] = {}
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        key, _, value = line.strip().rpartition(": ")
        if key in ("User time (seconds)", "System time (seconds)"):
            got["cpu_s"] = got.get("cpu_s", 0.0) + float(value)
        elif key == "Maximum resident set size (kbytes)":
            got["peak_rss_mb"] = float(value) / 1024.0
    return got


def realisation_groups(file: str, groups: list[list[str]], max_incidence: float) -> list[dict[str, Any]]:
    """Per group of seeds of one config at one target: each seed's NRMSE, their spread, the noise and the z.

    One run's noise comes from every pair of seeds, and the pairs' differences over their reported
    errors give the z (module docstring, ``realisations``).

    Parameters
    ----------
    file : str
        The file's dataset (``gonio truth``).
    groups : list of list of str
        ``[NAME, RUN, RUN, ...]`` per group.
    max_incidence : float
        Largest incidence kept (deg).

    Returns
    -------
    list of dict
        One row per group: its realisations and target, each seed's figures, the NRMSE's mean, standard
        deviation and range, the noise of one run, the pairs, the z's RMS and the fractions beyond 2
        and 3, and the means of the rays, errors, CPU seconds and peak memory (None when a run lacks one).

    Raises
    ------
    InputError
        A group of fewer than two runs, a run that is not a felt Monte Carlo run, or runs of
        different realisations or targets in one group.
    """
    from itertools import combinations

    out = []
    keys = ["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm"]
    for name, *runs in groups:
        if len(runs) < 2:
            raise InputError(f"--group {name}: give two or more runs (seeds of one config)")
        members = []
        for run, frame, cmp in compared(file, runs, max_incidence):
            prov = _read(run).meta.get("provenance", {})
            info = prov.get("fiber_info") or {}
            if "realisations" not in info:
                raise InputError(f"{run}: not a felt Monte Carlo run (no realisations in its provenance)")
            members.append((run, frame, cmp, prov, info))
        ks = {(int(m[4]["realisations"]), float(m[3]["target_rel_err"])) for m in members}
        if len(ks) != 1:
            raise InputError(f"--group {name}: its runs differ in realisations or target ({sorted(ks)}); "
                             "give one config at one target per group")
        k, target = ks.pop()
        seeds = []
        for run, frame, cmp, prov, info in members:
            seeds.append({"run": run, "seed": int(prov["seed"]), "nrmse": float(decompose_frame(frame, 20.0,
                                                                                                cmp.bands.label)["nrmse"]),
                          "rel_err": float(prov["rel_err"]), "rays": int(info["rays"]),
                          **_time_v(Path(f"{run.rstrip('/')}.time"))})
        pairs, z = [], []
        for (ra, fa, *_), (rb, fb, *_) in combinations(members, 2):
            pairs.append(seed_noise(fa, fb)["nrmse_seeds"])
            ta, tb = _read(ra).table, _read(rb).table
            j = ta.merge(tb, on=keys, suffixes=("_a", "_b"))
            u = np.sqrt(j["u_beta_a"].to_numpy(float) ** 2 + j["u_beta_b"].to_numpy(float) ** 2)
            ok = u > 0
            z.append((j["beta_a"].to_numpy(float)[ok] - j["beta_b"].to_numpy(float)[ok]) / u[ok])
        nr = [r["nrmse"] for r in seeds]
        zz = np.concatenate(z) if z else np.zeros(0)
        row = {"group": name, "realisations": k, "target_rel_err": target, "runs": seeds,
               "nrmse_mean": float(np.mean(nr)), "nrmse_std": float(np.std(nr, ddof=1)) if len(nr) > 1 else None,
               "nrmse_range": float(max(nr) - min(nr)),
               "noise_one_run": math.sqrt(float(np.mean(np.square(pairs)))) if pairs else None, "pairs": len(pairs),
               "z_rms": math.sqrt(float(np.mean(zz * zz))) if zz.size else None,
               "z_above_2": float(np.mean(np.abs(zz) > 2.0)) if zz.size else None,
               "z_above_3": float(np.mean(np.abs(zz) > 3.0)) if zz.size else None}
        for key in ("cpu_s", "peak_rss_mb", "rays", "rel_err"):
            vals = [r[key] for r in seeds if key in r]
            row[f"{key}_mean"] = float(np.mean(vals)) if len(vals) == len(seeds) else None
        out.append(row)
    return out


def combine(r0: np.ndarray, fields: list[tuple[str, float, float, np.ndarray, float, np.ndarray]],
            starts: int = 20, seed: int = 0) -> tuple[list[float], float]:
    """Every field at once from one-at-a-time runs: the changes that minimise the predicted mean square.

    Each point's residual is taken as ``r0 + sum_f a_f h_f + b_f h_f^2`` (the quadratic through the
    field's three runs, ``h`` the change from the base), and the changes within each field's scanned
    range that minimise its mean square are searched by L-BFGS-B from the base and ``starts`` random
    points.

    Parameters
    ----------
    r0 : numpy.ndarray
        The base run's residuals over the file's mean.
    fields : list of tuple
        Per field ``(name, base value, value 1, residuals 1, value 2, residuals 2)``.
    starts : int
        Random starting points besides the base.
    seed : int
        Their seed.

    Returns
    -------
    values : list of float
        Each field's value.
    nrmse : float
        The predicted NRMSE.
    """
    from scipy.optimize import minimize

    models = []
    for _, base, v1, r1, v2, r2 in fields:
        h1, h2 = v1 - base, v2 - base
        coef = np.linalg.solve(np.array([[h1, h1 * h1], [h2, h2 * h2]]), np.vstack([r1 - r0, r2 - r0]))
        models.append((base, min(h1, h2, 0.0), max(h1, h2, 0.0), coef))

    def changes(z: np.ndarray) -> list[float]:
        """The fields' changes from the unit-cube point ``z`` (0 and 1 the ends of each scanned range)."""
        return [lo + (hi - lo) * float(zz) for (_, lo, hi, _), zz in zip(models, z, strict=True)]

    def mean_square(z: np.ndarray) -> float:
        """The predicted mean square residual at the unit-cube point ``z``."""
        r = r0.copy()
        for (_, _, _, c), h in zip(models, changes(z), strict=True):
            r = r + c[0] * h + c[1] * h * h
        return float(np.mean(r * r))

    rng = np.random.default_rng(seed)
    z0 = [np.array([-lo / (hi - lo) for _, lo, hi, _ in models])] + [rng.random(len(models)) for _ in range(starts)]
    best = min((minimize(mean_square, z, bounds=[(0.0, 1.0)] * len(models), method="L-BFGS-B") for z in z0),
               key=lambda res: res.fun)
    return [base + h for (base, _, _, _), h in zip(models, changes(best.x), strict=True)], math.sqrt(best.fun)


# ---------------------------------------------------------------------------------------------- datasets

def _read(path: str):
    """The dataset at ``path``; InputError naming it when it is not one."""
    from gonio.data import DatasetError, read_dataset
    try:
        return read_dataset(path)
    except (DatasetError, OSError) as exc:
        raise InputError(f"{path}: not a dataset ({str(exc).splitlines()[0]})") from None


def compared(file: str, runs: list[str], max_incidence: float) -> list[tuple[str, pd.DataFrame, Any]]:
    """``(name, frame, comparison)`` per run against ``file``, the frame cut at ``max_incidence``.

    Each run is compared exactly as ``compare check`` compares it
    (:func:`compare.comparison.compare_datasets`).

    Parameters
    ----------
    file : str
        The file's dataset.
    runs : list of str
        The runs' datasets.
    max_incidence : float
        Largest incidence kept (deg).

    Returns
    -------
    list of tuple
        Per run its path, its aligned frame and the comparison.

    Raises
    ------
    InputError
        A path is not a dataset, a run cannot be compared, or no point is left at or below
        ``max_incidence``.
    """
    import logging

    from compare.comparison import compare_datasets
    from compare.errors import CompareError
    logging.getLogger("compare").setLevel(logging.ERROR)
    measured = _read(file)
    out = []
    for run in runs:
        sim = _read(run)
        try:
            cmp = compare_datasets(measured, [sim])
        except CompareError as exc:
            raise InputError(f"{run}: cannot be compared with {file} ({exc})") from None
        name = next(iter(cmp.frames))
        frame = cmp.frames[name]
        kept = frame[frame["theta_i"] <= max_incidence + 1e-9].reset_index(drop=True)
        if kept.empty:
            raise InputError(f"--max-incidence {max_incidence:g}: no point of {run} at or below it")
        out.append((run, kept, cmp))
    return out


#: the bands of the retro-ring ratio ``beta(6 deg) / beta(30 deg)`` :func:`retro` reports
RETRO_BANDS_NM = (550.0, 650.0)


def retro(path: str, max_incidence: float = 90.0, bands: tuple[float, ...] = RETRO_BANDS_NM) -> dict[str, dict]:
    """The retro-ring ratio of a dataset at ``bands``, per oblique incidence that holds both rings.

    The dataset's own values, scale-free (:func:`compare.ratios.opposition_ratios`).

    Parameters
    ----------
    path : str
        The dataset.
    max_incidence : float
        Largest incidence kept (deg).
    bands : tuple of float
        The bands (nm); those the dataset lacks are left out.

    Returns
    -------
    dict
        ``{incidence: {band: {"ratio": r, "u": standard error}}}``; ``{}`` when no incidence holds both rings.
    """
    from compare.ratios import Missing, opposition_ratios

    table = _read(path).table
    ratios = opposition_ratios(table)
    if isinstance(ratios, Missing):
        return {}
    out = {}
    for ti, r in ratios.items():
        if ti > max_incidence + 1e-9:
            continue
        keys = {round(float(k), 6): k for k in r.value}
        out[f"{ti:g}"] = {f"{b:g}": {"ratio": float(r.value[keys[round(b, 6)]]), "u": float(r.u[keys[round(b, 6)]])}
                          for b in bands if round(b, 6) in keys}
    return out


def _colour(cmp) -> dict[str, float]:
    """The comparison's colour differences and level (``dh``, ``ds``, ``k_Y``); ``{}`` without a colour."""
    if cmp.colour is None:
        return {}
    sc = next(iter(cmp.colour.simulated.values()))
    return {"dh": float(sc.dh), "ds": float(sc.ds), "k_Y": float(sc.scale)}


def _print(run: str, res: dict[str, Any]) -> None:
    """Print one run's decomposition: the NRMSE, the noise, the forward rise and each split."""
    rise = ", ".join(f"{t}: {r['measured']:.2f}/{r['simulated']:.2f}" for t, r in res["forward_rise"].items())
    print(f"{run}: NRMSE {res['nrmse']:.4f} over {res['n']} points (u_sim-based noise {res['nrmse_noise_u']:.4f}; "
          f"best scale per band {res['nrmse_best_scale']:.4f}; forward rise file/model {rise})" + "".join(f", {k} {v:+.4f}" for k, v in res.get("colour", {}).items()))
    for part in ("by_incidence", "by_region", "by_band", "by_band_group", "by_plane", "by_incidence_region",
                 "by_band_group_region"):
        print(f"  {part}: " + "; ".join(
            f"{k} n{v['n']} share {100 * v['share']:.1f}% own {v['nrmse_own']:.3f} rms {v['rms_rel']:.3f} bias {v['bias_rel']:+.3f} "
            f"without {v['nrmse_without']:.3f}" for k, v in res[part].items() if v["n"]))


def permute_channels(src: Path, out: Path, order: str, force: bool = False) -> None:
    """Write the RGB RGL ``.bsdf`` file ``src`` with its channels reordered.

    Every other field (the sampling tables) is kept.

    Parameters
    ----------
    src : pathlib.Path
        The RGB RGL file.
    out : pathlib.Path
        The file to write.
    order : str
        The old channel each new R, G, B takes (``"gbr"``: new R, G, B = old G, B, R).
    force : bool
        Replace ``out`` when it exists.

    Raises
    ------
    InputError
        ``order`` is not a permutation of ``rgb``, ``out`` exists without ``force``, or ``src`` is not an
        RGB tensor file.
    """
    from gonio.data.bsdf_export import write_tensor_file
    from gonio.data.formats.errors import FormatError
    from gonio.data.formats.tensor import parse_tensor_bytes

    if sorted(order) != ["b", "g", "r"]:
        raise InputError(f"--order {order}: give the three letters r, g, b once each (e.g. gbr)")
    if out.exists() and not force:
        raise InputError(f"{out} exists; pass --force to replace it")
    try:
        fields = parse_tensor_bytes(src.read_bytes(), src)
    except (OSError, FormatError) as exc:
        raise InputError(f"{src}: not a readable tensor file ({str(exc).splitlines()[0]})") from None
    rgb = fields.get("rgb")
    if rgb is None or rgb.ndim != 5 or rgb.shape[2] != 3:
        raise InputError(f"{src}: no 'rgb' field of shape [phi_i, theta_i, 3, n, n]; give an RGB RGL .bsdf file")
    fields["rgb"] = np.ascontiguousarray(rgb[:, :, ["rgb".index(c) for c in order]])
    write_tensor_file(out, fields)


# ---------------------------------------------------------------------------------------------- the felt's geometry

def _point_segment_distance(p: np.ndarray, a: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Distance ``[n, m]`` from each point ``p`` (``[n, 3]``) to each segment ``a + t d``, ``t`` in ``[0, 1]`` (``[m, 3]``)."""
    w = p[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("nmi,mi->nm", w, d) / np.einsum("mi,mi->m", d, d)[None, :], 0.0, 1.0)
    r = w - t[..., None] * d[None, :, :]
    return np.sqrt(np.einsum("nmi,nmi->nm", r, r))


def top_profile(mesh: Any, bin_um: float, depth_um: float, n: int = 4000, seed: int = 1) -> np.ndarray:
    """The fraction of the cell inside a fibre in each layer below the felt's top down to ``depth_um``.

    Layer ``k`` is ``[k bin_um, (k + 1) bin_um]`` below ``z = 0``: ``n`` fixed-seed random points per
    layer, each tested against every fibre image's axis pieces
    (:func:`simulate.geometry.felt.fiber_pieces`; inside: nearer than the radius). Standard error
    ``sqrt(f (1 - f) / n)``.

    Parameters
    ----------
    mesh : simulate.geometry.mesh.FiberMesh
        A felt realisation.
    bin_um : float
        The layers' thickness (um).
    depth_um : float
        The depth profiled (um).
    n : int
        Points per layer.
    seed : int
        The points' seed.

    Returns
    -------
    numpy.ndarray
        The fraction per layer, from the top.
    """
    from simulate.geometry.felt import fiber_pieces

    p0, pd = fiber_pieces(mesh)
    a, d = p0.reshape(-1, 3), pd.reshape(-1, 3)
    R, L = float(mesh.yarn_radius_um), float(mesh.Lx)
    rng = np.random.default_rng(seed)
    edges = np.arange(0.0, depth_um + 0.5 * bin_um, bin_um)
    out = []
    for top, bottom in zip(edges[:-1], edges[1:], strict=True):
        pts = np.stack([rng.uniform(0.0, L, n), rng.uniform(0.0, L, n), -rng.uniform(top, bottom, n)], axis=-1)
        inside = np.zeros(n, bool)
        for k in range(0, len(a), 256):
            inside |= (_point_segment_distance(pts, a[k:k + 256], d[k:k + 256]) < R).any(axis=1)
        out.append(float(inside.mean()))
    return np.array(out)


#: the in-plane forward rise's incidences and the two observation angles on the mirror's side
RISE_INCIDENCES = (0.0, 30.0, 45.0, 60.0)


def lambert_rise(mesh: Any, albedos: list[float], target_rel_err: float = 0.01, seed: int = 1,
                 rotations: int = 8) -> dict[str, dict[str, Any]]:
    """The in-plane forward rise ``beta(70)/beta(30)`` of ``mesh`` with opaque Lambertian fibres.

    The observation is on the mirror's side; :class:`simulate.raytrace.Lambert` puts the albedos on the
    spectral axis, so one trace scores all on the same paths. Per incidence of :data:`RISE_INCIDENCES`,
    all orders (``all``) and the single scattering (``single``, the same for every albedo), each the mean
    over ``rotations`` turns of the incidence about the normal, with its standard error (the two betas'
    relative errors in quadrature).

    Parameters
    ----------
    mesh : simulate.geometry.mesh.FiberMesh
        A felt realisation.
    albedos : list of float
        The fibres' albedos.
    target_rel_err : float
        Each trace's target relative error.
    seed : int
        The rays' seed.
    rotations : int
        Turns of the incidence about the normal.

    Returns
    -------
    dict
        ``{"all 30": {"ratio": [...], "se": [...]}, ...}``, a value per albedo.
    """
    from simulate import raytrace as W
    from simulate.optics.microfacet import directions_deg
    from simulate.raytrace.integrator import trace_rotations

    turns = 2.0 * math.pi * np.arange(rotations) / rotations
    det = directions_deg([GRAZING_DEG, 30.0], [180.0, 180.0])
    out: dict[str, dict[str, Any]] = {}
    for events, label in ((0, "all"), (1, "single")):
        for theta_i in RISE_INCIDENCES:
            w_in = directions_deg([theta_i], [0.0])[0]
            res = trace_rotations(mesh, W.Lambert(np.asarray(albedos, float)), w_in, det, turns,
                                  target_rel_err=target_rel_err, seed=seed, max_events=events)
            beta = np.mean([r.beta for r in res], axis=0)                         # [2, albedos]
            u = np.sqrt(np.sum([r.u_beta ** 2 for r in res], axis=0)) / len(res)
            ratio = beta[0] / beta[1]
            se = ratio * np.hypot(u[0] / beta[0], u[1] / beta[1])
            out[f"{label} {theta_i:g}"] = {"ratio": ratio.tolist(), "se": se.tolist()}
    return out


# ---------------------------------------------------------------------------------------------- the fibre's phase

#: view angles (deg) in the plane of incidence of the phase curve, the beam along the felt's normal: the scattering
#: angle is ``180 - |view|`` (0 = forward), so views 70 and 30 are the scattering angles 110 and 150 deg
PHASE_VIEWS_DEG = tuple(float(v) for v in range(-80, 81, 10))
#: the view angles of ``p(110)/p(150)``: ``beta(70)/beta(30)`` of the felt in single scattering is that times the
#: felt's geometric factor (:func:`extinction_factor`)
PHASE_HIGH_DEG, PHASE_LOW_DEG = 70.0, 30.0
#: (name, ((TOML section, key, value), ...)): fibre fields of ``green-felt-mc.toml`` changed for ``phase --variants``
#: (a dict value is written as an inline table)
PHASE_VARIANTS: tuple[tuple[str, tuple[tuple[str, str, Any], ...]], ...] = (
    ("boundary-smooth", (("surface", "transmission_rms_slope", 0.0), ("surface", "transmission_rms_slope_around", 0.0))),
    ("boundary-0.3", (("surface", "transmission_rms_slope", 0.3), ("surface", "transmission_rms_slope_around", 0.3))),
    ("boundary-0.5", (("surface", "transmission_rms_slope", 0.5), ("surface", "transmission_rms_slope_around", 0.5))),
    ("boundary-1.0", (("surface", "transmission_rms_slope", 1.0), ("surface", "transmission_rms_slope_around", 1.0))),
    ("boundary-0.1-1.0", (("surface", "transmission_rms_slope_around", 1.0),)),
    ("boundary-0.1-1.0-rms-0.1", (("surface", "transmission_rms_slope_around", 1.0), ("surface", "rms_slope", 0.1))),
    ("rms-slope-0.1", (("surface", "rms_slope", 0.1),)),
    ("rms-slope-0.2", (("surface", "rms_slope", 0.2),)),
    ("rms-slope-0.5", (("surface", "rms_slope", 0.5),)),
    ("rms-slope-0.8", (("surface", "rms_slope", 0.8),)),
    ("scatterers-x0.1", (("particles", "volume_fraction", 0.000084),)),
    ("scatterers-x10", (("particles", "volume_fraction", 0.0084),)),
    ("scatterers-x30", (("particles", "volume_fraction", 0.0252),)),
    ("particles-0.05", (("particles", "size", {"median_radius_um": 0.05, "sigma_g": 1.4}),)),
    ("particles-0.3", (("particles", "size", {"median_radius_um": 0.3, "sigma_g": 1.4}),)),
    ("particles-1.0", (("particles", "size", {"median_radius_um": 1.0, "sigma_g": 1.4}),)),
    ("radius-5", (("fiber", "radius_um", 5.0),)),
    ("radius-12", (("fiber", "radius_um", 12.0),)),
    ("n-host-1.4", (("fiber", "n_host", 1.4),)),
    ("n-host-1.6", (("fiber", "n_host", 1.6),)),
)


def felt_views(views_deg: Any, azimuths: int) -> np.ndarray:
    """Exit directions ``[A, V, 3]`` in the fibre's frame for a fibre lying in the felt's plane.

    The fibre's axis (x) lies at ``A`` azimuths ``alpha`` (uniform midpoints over the turn) from the
    plane of incidence, the views ``V`` in that plane (``view > 0``: towards +x of the felt). The beam
    along the felt's normal is ``(0, 0, 1)`` in every fibre's frame (the frame's z is the felt's normal).

    Parameters
    ----------
    views_deg : array_like
        View angles in the plane of incidence (deg from the normal).
    azimuths : int
        Number of axis azimuths.

    Returns
    -------
    numpy.ndarray
        ``[A, V, 3]`` unit vectors.
    """
    th = np.radians(np.asarray(views_deg, float))
    alpha = (np.arange(int(azimuths)) + 0.5) * 2.0 * math.pi / int(azimuths)
    s, c = np.sin(th)[None, :], np.cos(th)[None, :]
    return np.stack([s * np.cos(alpha)[:, None], -s * np.sin(alpha)[:, None], np.broadcast_to(c, (alpha.size, th.size))],
                    axis=-1)


def lambert_far_field(w_in: np.ndarray, w_out: np.ndarray, radius_um: float = 1.0, albedo: float = 1.0) -> np.ndarray:
    """``S`` (um/sr) of an opaque Lambertian cylinder (axis x), closed form.

    With ``phi`` the angle between the directions' projections across the axis,
    ``S = albedo R |w_i,perp| |w_o,perp| ((pi - phi) cos phi + sin phi) / (2 pi)`` (the cell sum of
    ``albedo / pi (w_i . n)_+ (w_o . n)_+ R dpsi`` over the lit and seen cells).

    Parameters
    ----------
    w_in : numpy.ndarray
        Incident directions ``[..., 3]`` (towards the source), in the fibre's frame.
    w_out : numpy.ndarray
        Outgoing directions ``[..., 3]``, broadcast against ``w_in``.
    radius_um : float
        The cylinder's radius (um).
    albedo : float
        Its albedo.

    Returns
    -------
    numpy.ndarray
        ``S`` per direction pair.
    """
    pi_ = np.asarray(w_in, float)[..., 1:]
    po = np.asarray(w_out, float)[..., 1:]
    ni, no = np.linalg.norm(pi_, axis=-1), np.linalg.norm(po, axis=-1)
    cos = np.clip(np.sum(pi_ * po, axis=-1) / np.maximum(ni * no, 1e-300), -1.0, 1.0)
    phi = np.arccos(cos)
    return albedo * radius_um * ni * no * ((math.pi - phi) * cos + np.sin(phi)) / (2.0 * math.pi)


def extinction_factor(view_deg: float, plane: bool = True) -> float:
    """The single-scattering factor ``1 / (mu_o a + mu_i b)`` of a half-space of fibres at normal incidence.

    ``a``, ``b`` are the extinction per unit fibre length along the beam and the view over ``2 R``:
    fibres lying in the plane (``plane``) take ``a = 1`` (the beam across every fibre) and
    ``b = <|w_o,perp|>`` over the axis azimuths, ``(2 / pi) E(sin^2 theta_o)``; isotropic scatterers
    ``a = b = 1`` (Lommel-Seeliger's ``1 / (mu_i + mu_o)``).

    Parameters
    ----------
    view_deg : float
        The view's angle from the normal (deg).
    plane : bool
        Fibres lying in the plane; else isotropic scatterers.

    Returns
    -------
    float
        The factor.
    """
    from scipy.special import ellipe

    th = math.radians(view_deg)
    b = 2.0 / math.pi * float(ellipe(math.sin(th) ** 2)) if plane else 1.0
    return 1.0 / (math.cos(th) + b)


def band_means(values: np.ndarray, wavelengths_nm: np.ndarray) -> dict[str, np.ndarray]:
    """The mean over the last axis within each of :data:`BAND_GROUPS` (and ``"all"``).

    Parameters
    ----------
    values : numpy.ndarray
        Values over the wavelengths on the last axis.
    wavelengths_nm : numpy.ndarray
        The wavelengths (nm).

    Returns
    -------
    dict of str to numpy.ndarray
        The mean per group holding a wavelength, then ``"all"``.
    """
    wl = np.asarray(wavelengths_nm, float)
    out = {name: values[..., (wl >= lo) & (wl <= hi)].mean(axis=-1) for name, lo, hi in BAND_GROUPS
           if np.any((wl >= lo) & (wl <= hi))}
    out["all"] = values.mean(axis=-1)
    return out


def _rise(curve: np.ndarray, views: np.ndarray, high: float = PHASE_HIGH_DEG, low: float = PHASE_LOW_DEG) -> np.ndarray:
    """``S(high) / S(low)``, each the mean of the two sides (curve ``[V, ...]`` over ``views``)."""
    def at(v: float) -> np.ndarray:
        return 0.5 * (curve[np.argmin(np.abs(views - v))] + curve[np.argmin(np.abs(views + v))])
    return at(high) / at(low)


def sphere_integral(far_field: Any, n_theta: int = 90, n_phi: int = 180, upper_only: bool = False) -> np.ndarray:
    """``int S dOmega`` over the sphere (or the felt's upper half, ``z > 0``) of a far field.

    By the midpoint rule in ``cos theta`` and the azimuth.

    Parameters
    ----------
    far_field : callable
        ``far_field(w_out [O, 3]) -> [O, ...]``.
    n_theta, n_phi : int
        The grid's cells in ``cos theta`` and the azimuth.
    upper_only : bool
        Integrate over ``z > 0`` only.

    Returns
    -------
    numpy.ndarray
        The integral, of the far field's trailing shape.
    """
    mu = (np.arange(n_theta) + 0.5) / n_theta * (1.0 if upper_only else 2.0) - (0.0 if upper_only else 1.0)
    ph = (np.arange(n_phi) + 0.5) * 2.0 * math.pi / n_phi
    st = np.sqrt(1.0 - mu ** 2)
    w = np.stack([np.outer(st, np.cos(ph)), np.outer(st, np.sin(ph)), np.outer(mu, np.ones_like(ph))], -1).reshape(-1, 3)
    d_omega = (1.0 if upper_only else 2.0) / n_theta * 2.0 * math.pi / n_phi
    return np.asarray(far_field(w)).sum(axis=0) * d_omega


def fibre_phase(fiber: Any, wavelengths_nm: Any, *, photons_per_row: int = 4000, tables: int = 4, seed: int = 0,
                azimuths: int = 72, bins: tuple[int, int] = (10, 20), views_deg: Any = PHASE_VIEWS_DEG,
                threads: int = 1, sphere: tuple[int, int] = (90, 180)) -> dict[str, Any]:
    """The fibre's far field at the felt's normal incidence, averaged over the axis azimuths in the plane.

    ``S = S_vol + S_surf`` (:mod:`simulate.fiber.farfield`): the volume term from ``tables`` independent
    exit tables (:func:`simulate.fiber.farfield.exit_table`, seeds ``tables * seed + j``, the fibre's
    rough boundary for light crossing it included, with the light that crosses the fibre without
    scattering) and the Cook-Torrance surface term, each at the views of ``views_deg`` in the plane of
    incidence for ``azimuths`` axis azimuths (:func:`felt_views`), then their mean.

    Parameters
    ----------
    fiber : simulate.fiber.Fiber
        The fibre.
    wavelengths_nm : array_like
        The wavelengths (nm).
    photons_per_row : int
        Photons per exit-table row.
    tables : int
        Independent exit tables (at least 2: their spread is the error).
    seed : int
        The tables' seed.
    azimuths : int
        Axis azimuths averaged (at least 4).
    bins : tuple of (int, int)
        The exit tables' bins.
    views_deg : array_like
        View angles in the plane of incidence (deg).
    threads : int
        Threads of the tables' walks.
    sphere : tuple of (int, int)
        The midpoint grid of the albedo integrals (:func:`sphere_integral`).

    Returns
    -------
    dict
        The settings, the seconds, the surface's albedo and per band group of :data:`BAND_GROUPS`
        (the mean over its wavelengths): the curve ``S(view)``, the volume's share of it,
        ``p(110)/p(150) = S(70)/S(30)`` (both sides' mean) and its standard error over the tables, the
        volume albedo ``a(w_i)`` (all exits of the volume over ``2 R``) and the share of the scattered
        power that leaves into the felt's upper half (towards the source's side).

    Raises
    ------
    InputError
        Fewer than 2 tables, too few photons per row or fewer than 4 azimuths.
    """
    from simulate.fiber import farfield as FF

    if tables < 2 or photons_per_row < FF.MIN_PHOTONS_PER_ROW or azimuths < 4:
        raise InputError(f"phase: give --tables >= 2, --photons >= {FF.MIN_PHOTONS_PER_ROW} and --azimuths >= 4")
    wl = np.atleast_1d(np.asarray(wavelengths_nm, float))
    views = np.asarray(views_deg, float)
    w_in = np.array([0.0, 0.0, 1.0])
    grid = felt_views(views, azimuths).reshape(-1, 3)
    s_surf = FF.surface_far_field(fiber, np.repeat(w_in[None], grid.shape[0], 0), grid).reshape(azimuths, -1).mean(0)
    surf_of = lambda w: FF.surface_far_field(fiber, np.repeat(w_in[None], w.shape[0], 0), w)  # noqa: E731
    surf_albedo = float(sphere_integral(surf_of, *sphere) / (2.0 * fiber.radius_um))
    surf_up = float(sphere_integral(surf_of, *sphere, upper_only=True) / (2.0 * fiber.radius_um))
    vols, albedos, ups = [], [], []
    started = time.perf_counter()
    for j in range(int(tables)):
        tab = FF.exit_table(fiber, wl, w_t=(0.0, 0.26), bins=bins, photons_per_row=int(photons_per_row),
                            seed=int(tables) * int(seed) + j, threads=threads, cache=False)
        rad = tab.exit_radiance(w_in)

        def vol_of(w: np.ndarray, tab=tab, rad=rad) -> np.ndarray:
            R, cos = tab.lookup(rad, w)
            return tab.radius_um * tab.dpsi * np.einsum("ok,okl->ol", cos, R)

        vols.append(vol_of(grid).reshape(azimuths, views.size, wl.size).mean(0))
        albedos.append(tab.albedo(w_in))
        ups.append(sphere_integral(vol_of, *sphere, upper_only=True) / (2.0 * fiber.radius_um))
    vol = np.mean(vols, axis=0)                                        # [V, L]
    total = vol + s_surf[:, None]
    albedo = np.mean(albedos, axis=0)
    up = np.mean(ups, axis=0)
    out: dict[str, Any] = {"views_deg": views.tolist(), "photons_per_row": int(photons_per_row), "tables": int(tables),
                           "azimuths": int(azimuths), "bins": list(bins), "seconds": time.perf_counter() - started,
                           "surface_albedo": surf_albedo, "bands": {}}
    per_table = [band_means(v + s_surf[:, None], wl) for v in vols]
    for band, curve in band_means(total, wl).items():
        ratios = np.array([_rise(t[band], views) for t in per_table])
        vshare = band_means(vol, wl)[band] / curve
        out["bands"][band] = {
            "curve": curve.tolist(), "volume_share": vshare.tolist(), "ratio": float(_rise(curve, views)),
            "se": float(ratios.std(ddof=1) / math.sqrt(ratios.size)),
            "volume_albedo": float(band_means(albedo, wl)[band]),
            "upper_share": float((band_means(up, wl)[band] + surf_up) / (band_means(albedo, wl)[band] + surf_albedo))}
    return out


def to_fibre_frame(w: np.ndarray, azimuths: int) -> np.ndarray:
    """Felt-frame directions ``w [..., 3]`` in the frame of a fibre lying in the felt's plane, per axis azimuth.

    The ``azimuths`` are uniform midpoints over the turn, from the felt's x; the frame's x is the axis
    and z the felt's normal (:func:`felt_views` is this for the views in the plane of incidence).

    Parameters
    ----------
    w : numpy.ndarray
        Directions ``[..., 3]`` in the felt's frame.
    azimuths : int
        Number of axis azimuths.

    Returns
    -------
    numpy.ndarray
        ``[A, ..., 3]``.
    """
    w = np.asarray(w, float)
    alpha = (np.arange(int(azimuths)) + 0.5) * 2.0 * math.pi / int(azimuths)
    c = np.cos(alpha).reshape((-1,) + (1,) * (w.ndim - 1))
    s = np.sin(alpha).reshape((-1,) + (1,) * (w.ndim - 1))
    x, y, z = w[..., 0][None], w[..., 1][None], w[..., 2][None]
    return np.stack([x * c + y * s, -x * s + y * c, np.broadcast_to(z, (c.shape[0],) + z.shape[1:])], axis=-1)


def oblique_phase(fiber: Any, wavelengths_nm: Any, incidences_deg: Any, *, photons_per_row: int = 4000,
                  tables: int = 4, seed: int = 0, azimuths: int = 72, bins: tuple[int, int] = (10, 20),
                  w_t_nodes: Any = (0.0, 0.25, 0.5, 0.75, 0.95), threads: int = 1) -> dict[str, Any]:
    """:func:`fibre_phase` at oblique beams: the fibre's share of the felt's forward rise.

    The source is at ``theta_i`` on the felt's -x side, the views 30 and 70 deg on the mirror's side
    (+x) in the plane of incidence. The beam meets a fibre at azimuth ``alpha`` with
    ``|w_t| = sin theta_i |cos alpha|``: the exit tables take the felt's axial nodes ``w_t_nodes``
    (their interpolation, :meth:`ExitTable.exit_radiance`).

    Parameters
    ----------
    fiber : simulate.fiber.Fiber
        The fibre.
    wavelengths_nm : array_like
        The wavelengths (nm).
    incidences_deg : array_like
        The beams' angles from the felt's normal, in (0, 90) deg.
    photons_per_row : int
        Photons per exit-table row.
    tables : int
        Independent exit tables (at least 2).
    seed : int
        The tables' seed.
    azimuths : int
        Axis azimuths averaged (at least 4).
    bins : tuple of (int, int)
        The exit tables' bins.
    w_t_nodes : array_like
        The tables' axial nodes.
    threads : int
        Threads of the tables' walks.

    Returns
    -------
    dict
        The settings, the opaque Lambertian fibre's ``S(70)/S(30)`` per incidence, per band group the
        ratio and its standard error over the tables per incidence, and the seconds.

    Raises
    ------
    InputError
        Bad table, photon or azimuth counts, or an incidence outside (0, 90) deg.
    """
    from simulate.fiber import farfield as FF

    if tables < 2 or photons_per_row < FF.MIN_PHOTONS_PER_ROW or azimuths < 4:
        raise InputError(f"phase: give --tables >= 2, --photons >= {FF.MIN_PHOTONS_PER_ROW} and --azimuths >= 4")
    wl = np.atleast_1d(np.asarray(wavelengths_nm, float))
    incid = [float(t) for t in incidences_deg]
    if not incid or not all(0.0 < t < 90.0 for t in incid):
        raise InputError("--oblique: give incidences in (0, 90) deg, comma-separated")
    views = np.radians([PHASE_HIGH_DEG, PHASE_LOW_DEG])
    w_out = np.stack([np.sin(views), np.zeros(2), np.cos(views)], -1)
    wo_f = to_fibre_frame(w_out, azimuths)                                      # [A, 2, 3]
    started = time.perf_counter()
    tabs = [FF.exit_table(fiber, wl, w_t=w_t_nodes, bins=bins, photons_per_row=int(photons_per_row),
                          seed=int(tables) * int(seed) + j, threads=threads, cache=False) for j in range(int(tables))]
    out: dict[str, Any] = {"incidences_deg": incid, "photons_per_row": int(photons_per_row), "tables": int(tables),
                           "w_t_nodes": [float(x) for x in w_t_nodes], "lambert": [], "bands": {}}
    per: dict[str, list[list[float]]] = {}
    for t in incid:
        th = math.radians(t)
        wi_f = to_fibre_frame(np.array([-math.sin(th), 0.0, math.cos(th)]), azimuths)       # [A, 3]
        lam = lambert_far_field(np.repeat(wi_f[:, None], 2, 1), wo_f).mean(axis=0)
        out["lambert"].append(float(lam[0] / lam[1]))
        surf = FF.surface_far_field(fiber, np.repeat(wi_f, 2, 0), wo_f.reshape(-1, 3)).reshape(azimuths, 2).mean(0)
        curves = []
        for tab in tabs:
            S = np.zeros((2, wl.size))
            for a in range(int(azimuths)):
                R, cos = tab.lookup(tab.exit_radiance(wi_f[a]), wo_f[a])
                S += tab.radius_um * tab.dpsi * np.einsum("ok,okl->ol", cos, R)
            curves.append(band_means(S / azimuths + surf[:, None], wl))
        for band in curves[0]:
            mean = np.mean([c[band] for c in curves], axis=0)
            ratios = np.array([c[band][0] / c[band][1] for c in curves])
            per.setdefault(band, []).append([float(mean[0] / mean[1]), float(ratios.std(ddof=1) / math.sqrt(ratios.size))])
    out["bands"] = {b: {"ratio": [r for r, _ in v], "se": [e for _, e in v]} for b, v in per.items()}
    out["seconds"] = time.perf_counter() - started
    return out

def lambert_phase(azimuths: int = 72, views_deg: Any = PHASE_VIEWS_DEG) -> dict[str, Any]:
    """:func:`fibre_phase`'s curve and ratio for the opaque Lambertian fibre of albedo 1.

    From :func:`lambert_far_field`, with its albedo from the sphere integral (1) and its share into the
    felt's upper half.

    Parameters
    ----------
    azimuths : int
        Axis azimuths averaged.
    views_deg : array_like
        View angles in the plane of incidence (deg).

    Returns
    -------
    dict
        ``curve``, ``ratio``, ``albedo`` and ``upper_share``.
    """
    views = np.asarray(views_deg, float)
    grid = felt_views(views, azimuths)
    w_in = np.array([0.0, 0.0, 1.0])
    curve = lambert_far_field(w_in, grid).mean(axis=0)
    def of(w: np.ndarray) -> np.ndarray:
        """The Lambertian fibre's ``S`` towards ``w`` for the beam along the normal."""
        return lambert_far_field(w_in, w)
    return {"curve": curve.tolist(), "ratio": float(_rise(curve, views)),
            "albedo": float(sphere_integral(of) / 2.0), "upper_share": float(sphere_integral(of, upper_only=True)
                                                                              / sphere_integral(of))}


def felt_rise(config: Any, *, target_rel_err: float = 0.02, seed: int = 0, max_events: int = 1,
              threads: int = 1) -> dict[str, Any]:
    """The felt Monte Carlo of ``config`` at normal incidence: ``beta(70)/beta(30)`` per band group.

    Traced as ``simulate fabric --method mc`` traces it (its two felts, exit bins, axial shift and
    nodes), towards the in-plane views 30 and 70 deg on both sides, following ``max_events`` fibre
    scatterings; both sides' mean, with its standard error (the betas' relative errors in quadrature).

    Parameters
    ----------
    config : simulate.config.Config
        A felt's config.
    target_rel_err : float
        The trace's target relative error.
    seed : int
        The felts' and rays' seed.
    max_events : int
        Fibre scatterings followed (1: single; 0: all).
    threads : int
        Threads of the trace.

    Returns
    -------
    dict
        The settings, the rays, the seconds and per band group the ratio and its standard error.
    """
    from simulate import raytrace
    from simulate.geometry.felt import cached_felt_mesh
    from simulate.optics.microfacet import directions_deg
    from simulate.products import FELT_SEED_STRIDE

    wl = np.asarray(config.wavelengths_nm, float)
    fiber = config.fiber(wl)
    spec = config.structure
    felts = tuple(cached_felt_mesh(spec, float(fiber.radius_um), seed=seed + FELT_SEED_STRIDE * h)[0] for h in (0, 1))
    views = [PHASE_HIGH_DEG, PHASE_LOW_DEG, PHASE_HIGH_DEG, PHASE_LOW_DEG]
    w_o = directions_deg(views, [0.0, 0.0, 180.0, 180.0])
    w_i = np.repeat(directions_deg([0.0], [0.0]), len(views), axis=0)
    bins = config.exit_bins or raytrace.estimate.default_exit_bins(fiber, wl, True)
    started = time.perf_counter()
    beta, u, info = raytrace.fabric_beta(felts, fiber, w_i, w_o, wl, target_rel_err=target_rel_err, seed=seed,
                                      threads=threads, structure=spec, exit_bins=bins,
                                      axial_shift=bool(config.axial_shift), w_t_nodes=config.w_t_nodes(),
                                      max_events=max_events)
    out: dict[str, Any] = {"max_events": int(max_events), "target_rel_err": target_rel_err, "seed": int(seed),
                           "rays": int(info["rays"]), "seconds": time.perf_counter() - started, "bands": {}}
    b, v = band_means(beta, wl), band_means(u ** 2, wl)
    n_wl = {name: int(np.sum((wl >= lo) & (wl <= hi))) for name, lo, hi in BAND_GROUPS}
    n_wl["all"] = wl.size
    for band, bb in b.items():
        ub = np.sqrt(v[band] / n_wl[band])          # the band mean's error, the wavelengths' errors independent
        hi, lo = 0.5 * (bb[0] + bb[2]), 0.5 * (bb[1] + bb[3])
        u_hi, u_lo = 0.5 * math.hypot(ub[0], ub[2]), 0.5 * math.hypot(ub[1], ub[3])
        r = hi / lo
        out["bands"][band] = {"ratio": float(r), "se": float(r * math.hypot(u_hi / hi, u_lo / lo))}
    return out


def _felt_of(config_name: str, seed: int) -> Any:
    """The felt realisation of config ``config_name`` at ``seed``; InputError when the config is not a felt."""
    from simulate.config import ConfigError, load_config
    from simulate.geometry.felt import cached_felt_mesh

    try:
        config = load_config(config_name)
    except ConfigError as exc:
        raise InputError(str(exc)) from None
    spec = getattr(config, "structure", None)
    if spec is None or spec.kind != "nonwoven":
        raise InputError(f"{config_name}: not a felt; give a config with [structure] kind = \"nonwoven\"")
    return cached_felt_mesh(spec, float(config.radius_um), seed=seed)[0]


def _top(args) -> int:
    """``top``: print and write the volume fraction against the depth below the top of each CONFIG's felt."""
    if args.seeds < 1 or not (0.0 < args.bin_um <= args.depth_um):
        raise InputError("top: give --seeds >= 1 and 0 < --bin-um <= --depth-um")
    result = {}
    for name in args.configs:
        prof = np.mean([top_profile(_felt_of(name, s), args.bin_um, args.depth_um) for s in range(args.seeds)], axis=0)
        result[name] = prof.tolist()
        print(f"{name}: " + ", ".join(f"{k * args.bin_um:.0f}-{(k + 1) * args.bin_um:.0f} um {v:.3f}"
                                      for k, v in enumerate(prof)))
    if args.json:
        args.json.write_text(json.dumps({"seeds": args.seeds, "bin_um": args.bin_um, "profiles": result}, indent=1)
                             + "\n", encoding="utf-8")
    return 0


def _lambert(args) -> int:
    """``lambert``: print and write the forward rise of each CONFIG's felt with opaque Lambertian fibres."""
    try:
        albedos = [float(a) for a in args.albedo.split(",")]
    except ValueError:
        albedos = []
    if not albedos or not all(0.0 < a <= 1.0 for a in albedos):
        raise InputError(f"--albedo {args.albedo}: give albedos in (0, 1], comma-separated")
    result = {}
    for name in args.configs:
        rise = lambert_rise(_felt_of(name, 0), albedos, args.target)
        result[name] = rise
        for key, v in rise.items():
            print(f"{name} {key} deg: " + ", ".join(f"albedo {a:g} {r:.3f} +- {e:.3f}"
                                                   for a, r, e in zip(albedos, v["ratio"], v["se"], strict=True)))
    if args.json:
        args.json.write_text(json.dumps({"albedos": albedos, "rise": result}, indent=1) + "\n", encoding="utf-8")
    return 0


def _load(config: str) -> Any:
    """The config ``config``; InputError with the config's own message when it does not load."""
    from simulate.config import ConfigError, load_config

    try:
        return load_config(config)
    except ConfigError as exc:
        raise InputError(str(exc)) from None


def _phase_configs(args) -> tuple[dict[str, Any], list[str]]:
    """The configs ``phase`` measures (the variants' too) and those ``--oblique`` measures; InputError on bad input."""
    from simulate.config import resolve_config_path

    if args.felt_target <= 0.0 or args.felt_target >= 1.0:
        raise InputError(f"--felt-target {args.felt_target:g}: give a relative error in (0, 1)")
    if args.oblique is not None:
        try:
            ok = all(0.0 < float(t) < 90.0 for t in args.oblique.split(","))
        except ValueError:
            ok = False
        if not ok:
            raise InputError(f"--oblique {args.oblique}: give incidences in (0, 90) deg, comma-separated")
    configs: dict[str, Any] = {name: _load(name) for name in args.configs}
    if args.variants:
        base = args.configs[0]
        try:
            text = resolve_config_path(base).read_text(encoding="utf-8")
        except (OSError, ValueError) as exc:
            raise InputError(f"{base}: cannot read the config to vary ({exc})") from None
        with tempfile.TemporaryDirectory() as tmp:
            for name, fields in PHASE_VARIANTS:
                body = text
                for section, key, value in fields:
                    body = set_field(body, section, key, value)
                path = Path(tmp) / f"{name}.toml"
                path.write_text(re.sub(r'(?m)^name = ".*"$', f'name = "{name}"', body, count=1), encoding="utf-8")
                configs[name] = _load(str(path))
    for name, config in configs.items():
        if args.felt and (getattr(config, "structure", None) is None or config.structure.kind != "nonwoven"):
            raise InputError(f"{name}: not a felt; --felt traces a config with [structure] kind = \"nonwoven\"")
    of = args.configs if not args.oblique_of else [n.strip() for n in args.oblique_of.split(",")]
    unknown = [n for n in of if n not in configs]
    if unknown:
        raise InputError(f"--oblique-of {','.join(unknown)}: not a config or variant of this run; "
                         f"known: {', '.join(configs)}")
    return configs, of


def _phase_oblique(args, configs: dict[str, Any], of: list[str], result: dict[str, Any]) -> None:
    """``phase --oblique``: each config of ``of`` at the oblique beams, into ``result`` (written after each)."""
    try:
        incid = [float(t) for t in args.oblique.split(",")]
    except ValueError:
        incid = []
    result["oblique"] = {}
    for name in of:
        config = configs[name]
        wl = np.asarray(config.wavelengths_nm, float)
        res = oblique_phase(config.fiber(wl), wl, incid, photons_per_row=args.photons, tables=args.tables,
                            seed=args.seed, azimuths=args.azimuths, w_t_nodes=config.w_t_nodes())
        result["oblique"][name] = res
        print(f"{name}: S(70)/S(30) on the mirror's side at {', '.join(f'{t:g}' for t in incid)} deg: "
              + ", ".join(f"{r:.3f} +- {e:.3f}" for r, e in zip(res["bands"]["all"]["ratio"],
                                                                res["bands"]["all"]["se"], strict=True))
              + " (Lambertian " + ", ".join(f"{r:.3f}" for r in res["lambert"]) + ")")
        if args.json:
            args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")


def _phase_felt(args, configs: dict[str, Any], result: dict[str, Any]) -> None:
    """``phase --felt``: each CONFIG's felt in single scattering and all orders, into ``result`` (written after each)."""
    for name in args.configs:
        config = configs[name]
        result["felt"][name] = {key: felt_rise(config, target_rel_err=args.felt_target, seed=args.seed,
                                               max_events=events) for key, events in (("single", 1), ("all", 0))}
        for key, v in result["felt"][name].items():
            print(f"{name} felt, {key}: beta(70)/beta(30) " + ", ".join(
                f"{b} {x['ratio']:.3f} +- {x['se']:.3f}" for b, x in v["bands"].items()))
        if args.json:
            args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")


def _phase(args) -> int:
    """``phase``: the fibre's far field per config (and variant), at oblique beams and in the felt when asked."""
    if not args.configs:
        args.configs = ["green-felt-mc"]
    configs, of = _phase_configs(args)
    lam = lambert_phase(args.azimuths)
    print(f"opaque Lambertian fibre: p(110)/p(150) {lam['ratio']:.3f}")
    result: dict[str, Any] = {
        "lambert": lam, "configs": {}, "felt": {},
        "factor_plane": extinction_factor(PHASE_HIGH_DEG) / extinction_factor(PHASE_LOW_DEG),
        "factor_isotropic": extinction_factor(PHASE_HIGH_DEG, False) / extinction_factor(PHASE_LOW_DEG, False)}
    for name, config in configs.items():
        wl = np.asarray(config.wavelengths_nm, float)
        res = fibre_phase(config.fiber(wl), wl, photons_per_row=args.photons, tables=args.tables, seed=args.seed,
                          azimuths=args.azimuths)
        result["configs"][name] = res
        print(f"{name}: p(110)/p(150) " + ", ".join(f"{b} {v['ratio']:.3f} +- {v['se']:.3f}"
                                                    for b, v in res["bands"].items()) + f" ({res['seconds']:.0f} s)")
        if args.json:       # what is measured so far is kept
            args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    if args.oblique:
        _phase_oblique(args, configs, of, result)
    if args.felt:
        _phase_felt(args, configs, result)
    return 0


def _combine(args) -> int:
    """``combine``: write the config with every continuous field at its predicted best (:func:`combine`)."""
    if args.out.exists() and not args.force:
        raise InputError(f"{args.out} exists; pass --force to replace it")
    text = args.preset.read_text(encoding="utf-8")
    import tomllib
    preset = tomllib.loads(text)
    pairs: dict[tuple[str, str], list[tuple[str, Any]]] = {}
    for name, section, key, value in VARIANTS:
        if isinstance(value, (int, float)) and (args.runs / name / "radiance.csv").exists():
            pairs.setdefault((section, key), []).append((name, value))
    pairs = {k: v for k, v in pairs.items() if len(v) == 2}
    if not pairs:
        raise InputError(f"--runs {args.runs}: no field has both its variants' runs there (<variant>/radiance.csv)")
    names = [args.base] + [str(args.runs / n) for v in pairs.values() for n, _ in v]
    frames = {run: f for run, f, _ in compared(args.file, names, 90.0)}
    meas = frames[args.base]["beta_meas"].to_numpy(float)
    m = float(np.mean(meas))

    def resid(run: str) -> np.ndarray:
        """The residuals of ``run`` over the file's mean."""
        return (frames[run]["beta_sim"].to_numpy(float) - meas) / m

    fields = []
    for (section, key), ((n1, v1), (n2, v2)) in pairs.items():
        base = preset.get(section, {}).get(key, 0.0)
        fields.append((f"{section}.{key}", float(base), float(v1), resid(str(args.runs / n1)), float(v2),
                       resid(str(args.runs / n2))))
    values, predicted = combine(resid(args.base), fields)
    for (name, base, *_), v in zip(fields, values, strict=True):
        section, key = name.split(".", 1)
        print(f"{name} = {v:.4g}" + (" (the preset's)" if abs(v - base) <= 1e-9 * max(1.0, abs(base)) else ""))
        if abs(v - base) > 1e-9 * max(1.0, abs(base)):
            text = set_field(text, section, key, float(f"{v:.4g}"))
    text = re.sub(r'(?m)^name = ".*"$', 'name = "combined"', text, count=1)
    args.out.write_text(text, encoding="utf-8")
    print(f"predicted NRMSE {predicted:.4f} (the base run's {math.sqrt(float(np.mean(resid(args.base) ** 2))):.4f}); "
          f"wrote {args.out}")
    return 0


def _parser() -> argparse.ArgumentParser:
    """The command line's parser: one subcommand per measurement (module docstring)."""
    ap = argparse.ArgumentParser(prog="felt_residual.py", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("variants", help="write the one-at-a-time variant configs of the preset")
    v.add_argument("--preset", type=Path, default=PRESET)
    v.add_argument("--out", type=Path, required=True)
    v.add_argument("--force", action="store_true")
    d = sub.add_parser("decompose", help="split each run's curve error against FILE")
    d.add_argument("file")
    d.add_argument("runs", nargs="+")
    d.add_argument("--max-incidence", type=float, default=90.0)
    d.add_argument("--near", type=float, default=20.0, help="half-width of the near-normal region (deg)")
    d.add_argument("--json", type=Path)
    n = sub.add_parser("noise", help="the noise of one config from pairs of seeds")
    n.add_argument("file")
    n.add_argument("runs", nargs="+", help="pairs: RUN_A RUN_B [RUN_C RUN_D ...] (two seeds of one config each)")
    n.add_argument("--max-incidence", type=float, default=90.0)
    n.add_argument("--json", type=Path)
    ff = sub.add_parser("fixed-felt", help="`simulate ARGS` with the felt realisations of one seed held")
    ff.add_argument("--felt-seed", type=int, default=0)
    ff.add_argument("--table-factor", type=int, default=1, help="the yarn table's photons times this")
    ff.add_argument("args", nargs=argparse.REMAINDER, help="-- and the arguments of `simulate`")
    rl = sub.add_parser("realisations", help="seeds of one config per felt realisation count: spread, noise, z")
    rl.add_argument("file")
    rl.add_argument("--group", nargs="+", action="append", required=True, metavar="NAME RUN",
                    help="a name and the runs of one config at two or more seeds (repeat for each group)")
    rl.add_argument("--max-incidence", type=float, default=90.0)
    rl.add_argument("--json", type=Path)
    c = sub.add_parser("combine", help="every continuous field at once from the one-at-a-time runs")
    c.add_argument("file")
    c.add_argument("base", help="the preset's run (the variants' seed and target)")
    c.add_argument("--runs", type=Path, required=True, help="folder holding each variant's run as <variant>/")
    c.add_argument("--preset", type=Path, default=PRESET)
    c.add_argument("--out", type=Path, required=True, help="the combined config (TOML) to write")
    c.add_argument("--force", action="store_true")
    pm = sub.add_parser("permute", help="an RGB RGL .bsdf file with its channels reordered (another colour)")
    pm.add_argument("src", type=Path)
    pm.add_argument("--order", required=True, help="the old channel each new R, G, B takes, e.g. gbr")
    pm.add_argument("--out", type=Path, required=True)
    pm.add_argument("--force", action="store_true")
    tp = sub.add_parser("top", help="the felt's volume fraction against the depth below its top")
    tp.add_argument("configs", nargs="+", metavar="CONFIG")
    tp.add_argument("--seeds", type=int, default=3)
    tp.add_argument("--bin-um", type=float, default=33.0)
    tp.add_argument("--depth-um", type=float, default=429.0)
    tp.add_argument("--json", type=Path)
    lb = sub.add_parser("lambert", help="the forward rise of the config's felt with opaque Lambertian fibres")
    lb.add_argument("configs", nargs="+", metavar="CONFIG")
    lb.add_argument("--albedo", default="0.22,0.9", help="comma-separated albedos (default 0.22,0.9)")
    lb.add_argument("--target", type=float, default=0.01, help="each trace's relative error target")
    lb.add_argument("--json", type=Path)
    ph = sub.add_parser("phase", help="the fibre's far field at the felt's normal incidence, averaged in the plane")
    ph.add_argument("configs", nargs="*", metavar="CONFIG", default=["green-felt-mc"])
    ph.add_argument("--variants", action="store_true", help="also the first config with each of PHASE_VARIANTS")
    ph.add_argument("--photons", type=int, default=4000, help="photons per exit-table row (each table)")
    ph.add_argument("--tables", type=int, default=4, help="independent exit tables (their spread: the error)")
    ph.add_argument("--azimuths", type=int, default=72, help="fibre axis azimuths averaged")
    ph.add_argument("--seed", type=int, default=0)
    ph.add_argument("--felt", action="store_true", help="also trace each CONFIG's felt, single and all orders")
    ph.add_argument("--felt-target", type=float, default=0.02, help="the felt traces' relative error target")
    ph.add_argument("--oblique", help="also the fibre's S(70)/S(30) on the mirror's side at these incidences (deg, "
                    "comma-separated)")
    ph.add_argument("--oblique-of", help="the configs or variants (names, comma-separated) --oblique measures; "
                    "default: each CONFIG")
    ph.add_argument("--json", type=Path)
    return ap


def _variants(args) -> int:
    """``variants``: write the variant configs and print their paths."""
    for p in write_variants(args.preset, args.out, args.force):
        print(p)
    return 0


def _permute(args) -> int:
    """``permute``: write the file with its channels reordered and print its path."""
    permute_channels(args.src, args.out, args.order.lower(), args.force)
    print(args.out)
    return 0


def _fixed_felt(args) -> int:
    """``fixed-felt``: ``simulate ARGS`` (after ``--``) with the felts of ``--felt-seed`` held."""
    return fixed_felt(args.args[1:] if args.args[:1] == ["--"] else args.args, args.felt_seed,
                      args.table_factor)


def _realisations(args) -> int:
    """``realisations``: print each group's seeds, spread, noise and z, and write them with ``--json``."""
    rows = realisation_groups(args.file, args.group, args.max_incidence)
    for r in rows:
        print(f"{r['group']} (K {r['realisations']} at {r['target_rel_err']:g}): NRMSE " +
              ", ".join(f"{x['nrmse']:.4f}" for x in r["runs"]) +
              f" (std {r['nrmse_std'] or 0:.4f}, range {r['nrmse_range']:.4f}); noise of one run "
              f"{r['noise_one_run'] or 0:.4f} over {r['pairs']} pairs; z rms {r['z_rms'] or 0:.3f} "
              f"(|z| > 2: {r['z_above_2'] or 0:.3f}); rays {r['rays_mean']:.0f}; CPU {r['cpu_s_mean'] or 0:.1f} s; "
              f"peak {r['peak_rss_mb_mean'] or 0:.0f} MB")
    if args.json:
        args.json.write_text(json.dumps({"file": args.file, "max_incidence": args.max_incidence,
                                         "groups": rows}, indent=1) + "\n", encoding="utf-8")
    return 0


def _noise(args) -> int:
    """``noise``: print each pair's seed-to-seed noise, and write them with ``--json``."""
    if len(args.runs) % 2:
        raise InputError(f"noise: {len(args.runs)} runs given; give pairs (two seeds of one config each)")
    frames = compared(args.file, args.runs, args.max_incidence)
    pairs = []
    for (ra, fa, _), (rb, fb, _) in zip(frames[::2], frames[1::2], strict=True):
        pairs.append({"a": ra, "b": rb, **seed_noise(fa, fb)})
        print(f"{ra} / {rb}: seed-to-seed noise {pairs[-1]['nrmse_seeds']:.4f} (in NRMSE units)")
    if args.json:
        args.json.write_text(json.dumps({"file": args.file, "max_incidence": args.max_incidence,
                                         "pairs": pairs}, indent=1) + "\n", encoding="utf-8")
    return 0


def _decompose(args) -> int:
    """``decompose``: print each run's split of the curve error and retro ratios, and write them with ``--json``."""
    if not (0.0 <= args.near < GRAZING_DEG):
        raise InputError(f"--near {args.near:g}: give a half-width in [0, {GRAZING_DEG:g}) deg")
    results = {}
    for run, frame, cmp in compared(args.file, args.runs, args.max_incidence):
        res = decompose_frame(frame, args.near, cmp.bands.label)
        res["colour"] = _colour(cmp)
        res["retro"] = {"file": retro(args.file, args.max_incidence), "model": retro(run, args.max_incidence)}
        results[run] = res
        _print(run, res)
        print("  retro ratio file/model: " + "; ".join(
            f"{ti} deg " + ", ".join(f"{b} nm {res['retro']['file'][ti][b]['ratio']:.3f}/{m['ratio']:.3f}"
                                     for b, m in bands.items() if b in res["retro"]["file"].get(ti, {}))
            for ti, bands in res["retro"]["model"].items()))
    if args.json:
        args.json.write_text(json.dumps({"file": args.file, "max_incidence": args.max_incidence,
                                         "near": args.near, "runs": results}, indent=1) + "\n", encoding="utf-8")
    return 0


#: the subcommands' handlers
COMMANDS: dict[str, Any] = {"phase": _phase, "variants": _variants, "combine": _combine, "top": _top,
                            "lambert": _lambert, "permute": _permute, "fixed-felt": _fixed_felt,
                            "realisations": _realisations, "noise": _noise, "decompose": _decompose}


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand (module docstring); bad input is one line, exit 2.

    Parameters
    ----------
    argv : list of str, optional
        The subcommand and its arguments; ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        The subcommand's status: 0, or 2 on bad input (``fixed-felt``: ``simulate``'s own status).
    """
    args = _parser().parse_args(argv)
    try:
        return COMMANDS[args.cmd](args)
    except InputError as exc:
        print(f"felt_residual.py: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
