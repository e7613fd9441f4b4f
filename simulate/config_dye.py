"""The ``[fiber.dye]`` table of a simulation config: the host absorption as a table or a named smooth curve.

Its schema is part of :mod:`simulate.config`'s; :func:`dye_from_table` reads it with the config's
checked table (:class:`simulate.config_table.Table`), so every error names the file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from simulate.config_table import Table, show
from simulate.media.medium import Spectrum

__all__ = ["DYE_CURVES", "KNOT_LOG10_RANGE", "DyeSpectrum", "dye_from_table", "knots_curve"]

DYE_CURVES = ("gaussian-bands", "logistic-edge", "knots")
#: Range of a knot of the ``knots`` dye curve: log10 of the host absorption in 1/um.
KNOT_LOG10_RANGE = (-6.0, 2.0)


@dataclass(frozen=True)
class DyeSpectrum:
    """Host absorption ``mu_a_host(lambda)`` in 1/um: a table or a named smooth curve.

    ``curve = "table"``: ``params = {"wavelength_nm": [...], "mu_a_per_um": [...]}``;
    ``"gaussian-bands"``: ``baseline_per_um + sum_j peak_per_um_j exp(-(l - center_nm_j)^2 /
    (2 width_nm_j^2))``; ``"logistic-edge"``: ``long_per_um + (short_per_um - long_per_um) /
    (1 + exp((l - edge_nm) / width_nm))`` (strong absorption below the edge); ``"knots"``:
    ``10 ** pchip(wavelength_nm, log10_per_um)(l)`` -- a shape-preserving (PCHIP, Fritsch &
    Carlson 1980, :class:`scipy.interpolate.PchipInterpolator`) interpolation of log10 of the
    absorption between K knots, held at the end values outside them: any colour (docs/physics.md
    section 2), always positive, no overshoot between knots (so the largest knot is the maximum).
    """

    curve: str
    params: dict

    def __call__(self, wavelength_nm: Any) -> np.ndarray:
        """The host absorption ``mu_a`` in 1/um at ``wavelength_nm``."""
        wl = np.asarray(wavelength_nm, dtype=float)
        p = self.params
        if self.curve == "table":
            return np.interp(wl, p["wavelength_nm"], p["mu_a_per_um"])
        if self.curve == "gaussian-bands":
            out = np.full(wl.shape, p["baseline_per_um"])
            for band in p["bands"]:
                out = out + band["peak_per_um"] * np.exp(
                    -0.5 * ((wl - band["center_nm"]) / band["width_nm"]) ** 2)
            return out
        if self.curve == "knots":
            return knots_curve(p["wavelength_nm"], p["log10_per_um"], wl)
        # logistic-edge
        z = np.clip((wl - p["edge_nm"]) / p["width_nm"], -700.0, 700.0)
        return p["long_per_um"] + (p["short_per_um"] - p["long_per_um"]) / (1.0 + np.exp(z))

    def as_spectrum(self, wavelength_nm: np.ndarray) -> Spectrum:
        """A :class:`~simulate.media.medium.Spectrum` sampled at (and exact on) ``wavelength_nm``."""
        wl = np.unique(np.asarray(wavelength_nm, dtype=float))
        if wl.size == 1:  # a Spectrum needs a range; a flat two-point table is exact
            wl = np.array([wl[0] - 1.0, wl[0] + 1.0])
            return Spectrum(wl, np.full(2, float(self(wl[0] + 1.0))), name="dye mu_a_host")
        return Spectrum(wl, self(wl), name="dye mu_a_host")


def knots_curve(knots_nm: Any, log10_per_um: Any, wavelength_nm: Any) -> np.ndarray:
    """``10 ** pchip(knots_nm, log10_per_um)(wavelength_nm)``, end values held (the ``knots`` dye)."""
    from scipy.interpolate import PchipInterpolator

    k = np.asarray(knots_nm, dtype=float)
    v = np.asarray(log10_per_um, dtype=float)
    wl = np.clip(np.asarray(wavelength_nm, dtype=float), k[0], k[-1])
    return np.power(10.0, PchipInterpolator(k, v)(wl))


def _knots(t: Table) -> dict:
    """The ``knots`` curve's parameters: at least 2 increasing wavelengths and their log10 ``mu_a``."""
    wl = t.numbers("wavelength_nm", ge=0.0)
    values = t.numbers("log10_per_um")
    lo, hi = KNOT_LOG10_RANGE
    if len(wl) < 2 or wl[0] <= 0:
        raise t.fail("wavelength_nm", f"must list at least 2 knots > 0 nm, got {len(wl)}")
    if any(b <= a for a, b in pairwise(wl)):
        raise t.fail("wavelength_nm", "must be strictly increasing")
    if len(values) != len(wl):
        raise t.fail("log10_per_um", f"must have as many items as wavelength_nm ({len(wl)}), got {len(values)}")
    for k, v in enumerate(values):
        if not lo <= v <= hi:
            raise t.fail("log10_per_um", f"item {k} must lie in [{lo:g}, {hi:g}] (log10 of 1/um), got {show(v)}")
    return {"wavelength_nm": [float(w) for w in wl], "log10_per_um": [float(v) for v in values]}


def dye_from_table(t: Table) -> DyeSpectrum:
    """The dye of a ``[fiber.dye]`` (or a population's) table: a wavelength table or a named curve.

    Every field is checked; an error names the file and the field (:class:`simulate.config.ConfigError`).
    """
    if t.has("curve"):
        curve = t.string("curve", choices=DYE_CURVES, required=True)
        if curve == "knots":
            params_k = _knots(t)
            t.done()
            return DyeSpectrum(curve, params_k)
        if curve == "gaussian-bands":
            base = t.number("baseline_per_um", 0.0, ge=0.0)
            bands_raw = t.raw("bands", None, required=True)
            if not isinstance(bands_raw, list) or not bands_raw:
                raise t.fail("bands", f"must be a non-empty list of tables, got {show(bands_raw)}")
            bands = []
            for k, b in enumerate(bands_raw):
                bt = Table(b, f"{t.name('bands')}[{k}]", t.file)
                bands.append({"center_nm": bt.number("center_nm", required=True, gt=0.0),
                              "width_nm": bt.number("width_nm", required=True, gt=0.0),
                              "peak_per_um": bt.number("peak_per_um", required=True, ge=0.0)})
                bt.done()
            params: dict = {"baseline_per_um": base, "bands": bands}
        else:
            params = {"short_per_um": t.number("short_per_um", required=True, ge=0.0),
                      "long_per_um": t.number("long_per_um", required=True, ge=0.0),
                      "edge_nm": t.number("edge_nm", required=True, gt=0.0),
                      "width_nm": t.number("width_nm", required=True, gt=0.0)}
        t.done()
        return DyeSpectrum(curve, params)
    wl = t.numbers("wavelength_nm", ge=0.0)
    mu_a = t.numbers("mu_a_per_um", ge=0.0)
    t.done()
    if len(wl) != len(mu_a):
        raise t.fail("mu_a_per_um", f"must have as many items as wavelength_nm ({len(wl)}), got {len(mu_a)}")
    if any(b <= a for a, b in pairwise(wl)):
        raise t.fail("wavelength_nm", "must be strictly increasing")
    return DyeSpectrum("table", {"wavelength_nm": wl, "mu_a_per_um": mu_a})
