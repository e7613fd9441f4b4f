r"""Measurement equation and the white standard's calibration table.

The detector sees the whole illuminated spot, so its signal is proportional to
``beta * cos(theta_o)``. With signal ``S`` and dark ``D`` (shutter closed) at integration time
``t`` and gain factor ``G``, and the white standard (calibrated radiance factor
``beta_ref(lambda)``) measured at the reference geometry (docs/instrument.md, "Measurement equation"):

.. math::

    \beta = \beta_{ref}\, \frac{(S - D)/(t G)}{(S_{ref} - D_{ref})/(t_{ref} G_{ref})}\,
             \frac{\cos\theta_{o,ref}}{\cos\theta_o}

Writing :math:`\beta = C (S - D)` with
:math:`C = \beta_{ref} \cos\theta_{o,ref} / [t G \cos\theta_o\, (S_{ref}-D_{ref})/(t_{ref}G_{ref})]`,
first-order propagation of independent standard errors (GUM, JCGM 100:2008, eq. 10) gives

.. math::

    u_\beta^2 = C^2 (u_S^2 + u_D^2)
               + \beta^2 \left[\frac{u_{S_{ref}}^2 + u_{D_{ref}}^2}{(S_{ref}-D_{ref})^2}
               + \left(\frac{u_{\beta_{ref}}}{\beta_{ref}}\right)^2\right]

where each ``u`` of a mean of ``n`` readings is ``std / sqrt(n)``. The absolute form of the first
term keeps ``u_beta`` finite when ``S - D`` is near zero (a dark sample).

The calibration table is a CSV file with the columns ``wavelength_nm, beta_ref, u_beta_ref``
(``#`` comment lines allowed), interpolated linearly; shipped tables live in
:mod:`gonio.presets` (``spectralon``) and are accepted by name.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = ["CalibrationError", "WhiteStandard", "load_white_standard", "parse_white_standard",
           "radiance_factor", "calibration_problem", "MIN_REFERENCE_Z"]


class CalibrationError(ValueError):
    """The white standard's table is missing or invalid (message names the file and row)."""


@dataclass(frozen=True)
class WhiteStandard:
    """A white standard's calibrated radiance factor ``beta_ref(lambda)`` with uncertainty."""

    name: str
    wavelength_nm: np.ndarray
    beta_ref: np.ndarray
    u_beta_ref: np.ndarray
    sha256: str

    def at(self, wavelength_nm) -> tuple[np.ndarray, np.ndarray]:
        """``(beta_ref, u_beta_ref)`` interpolated linearly at the given wavelengths.

        Raises :class:`CalibrationError` outside the table's range (no extrapolation).
        """
        w = np.asarray(wavelength_nm, dtype=float)
        lo, hi = self.wavelength_nm[0], self.wavelength_nm[-1]
        if np.any((w < lo - 1e-9) | (w > hi + 1e-9)):
            raise CalibrationError(f"{self.name}: the white standard is calibrated over "
                                   f"{lo:g}..{hi:g} nm only; the plan asks for "
                                   f"{float(np.min(w)):g}..{float(np.max(w)):g} nm")
        return (np.interp(w, self.wavelength_nm, self.beta_ref),
                np.interp(w, self.wavelength_nm, self.u_beta_ref))


def load_white_standard(name_or_path: str | Path, base: Path | None = None) -> WhiteStandard:
    """Read a calibration table from a CSV file or a shipped preset name (e.g. ``spectralon``).

    Relative paths are taken relative to ``base`` (the plan's folder) first.
    """
    p = Path(name_or_path)
    candidates = [base / p] if base is not None and not p.is_absolute() else []
    candidates.append(p)
    for c in candidates:
        if c.is_file():
            try:
                raw = c.read_bytes()
            except OSError as exc:
                raise CalibrationError(f"{c}: cannot read the white standard table ({exc.strerror})") from None
            return parse_white_standard(raw, str(c))
    preset = resources.files("gonio.presets") / f"{name_or_path}.csv"
    if "/" not in str(name_or_path) and preset.is_file():
        return parse_white_standard(preset.read_bytes(), str(name_or_path))
    raise CalibrationError(f"{name_or_path}: no such white standard table (a CSV file with columns "
                           "wavelength_nm,beta_ref,u_beta_ref, or the preset 'spectralon')")


def parse_white_standard(raw: bytes, name: str) -> WhiteStandard:
    """Validate a calibration table's CSV bytes; raises :class:`CalibrationError`."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise CalibrationError(f"{name}: not UTF-8 text") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(io.StringIO("\n".join(lines))))
    want = ["wavelength_nm", "beta_ref", "u_beta_ref"]
    if not rows or [c.strip() for c in rows[0]] != want:
        raise CalibrationError(f"{name}: the header must be {','.join(want)}")
    values = []
    for k, row in enumerate(rows[1:], start=2):
        if len(row) != 3:
            raise CalibrationError(f"{name}: row {k}: expected 3 values, got {len(row)}")
        try:
            w, b, u = (float(x) for x in row)
        except ValueError:
            raise CalibrationError(f"{name}: row {k}: not a number: {row}") from None
        if not all(math.isfinite(x) for x in (w, b, u)) or b <= 0 or u < 0:
            raise CalibrationError(f"{name}: row {k}: need finite wavelength, beta_ref > 0, u >= 0")
        values.append((w, b, u))
    if len(values) < 2:
        raise CalibrationError(f"{name}: needs at least two rows")
    arr = np.array(values)
    if np.any(np.diff(arr[:, 0]) <= 0):
        raise CalibrationError(f"{name}: wavelengths must increase strictly")
    return WhiteStandard(name=name, wavelength_nm=arr[:, 0], beta_ref=arr[:, 1],
                         u_beta_ref=arr[:, 2], sha256=hashlib.sha256(raw).hexdigest())


MIN_REFERENCE_Z = 5.0
"""How many standard errors the white standard's signal must stand above the dark."""


def calibration_problem(darks: list[dict], reference: list[dict],
                        standard: WhiteStandard | None = None) -> str | None:
    """Why a calibration (journal ``darks`` and ``reference`` readings) is unusable, or None.

    The white standard's signal ``S_ref - D_ref`` (at the reference reading's integration time
    and gain) is the denominator of the measurement equation. It must be finite and stand above
    the dark by at least :data:`MIN_REFERENCE_Z` of its standard error
    ``sqrt(u_S_ref^2 + u_D_ref^2)``: a reading with the shutter closed, the lamp off or nothing
    in the beam equals the dark within a few standard errors (``z > 5`` by chance has
    probability < 3e-7), and would give ``beta = inf`` or noise. Against the standard's table
    (when ``standard`` is given): every reference wavelength lies in its range and the standard
    is calibrated there (``beta_ref > 0``), so a positive signal is what it must give.
    """
    by_setting = {(d["itime_ms"], d["gain"]): d for d in darks}
    for r in reference:
        wl = float(r["wavelength_nm"])
        d = by_setting.get((r["itime_ms"], r["gain"]))
        if d is None:
            return f"white standard at {wl:g} nm: no dark at {r['itime_ms']} ms, gain {r['gain']}"
        signal = float(r["mean"]) - float(d["mean"])
        u = math.hypot(float(r["sem"]), float(d["sem"]))
        if not (math.isfinite(signal) and math.isfinite(u)) or signal <= MIN_REFERENCE_Z * u:
            z = signal / u if u > 0 else (math.inf if signal > 0 else 0.0)
            return (f"white standard at {wl:g} nm: {signal:.4g} +- {u:.2g} counts above the "
                    f"dark ({z:.3g} standard errors, at least {MIN_REFERENCE_Z:g} needed): is "
                    "the lamp on, the shutter open and the standard in the beam?")
        if standard is not None:
            try:
                beta_ref, _ = standard.at([wl])
            except CalibrationError as exc:
                return str(exc)
            if not beta_ref[0] > 0:
                return f"white standard at {wl:g} nm: the table gives beta_ref <= 0"
    return None


def radiance_factor(signal, u_signal, dark, u_dark, itime_ms, gain_factor, theta_o_deg,
                    ref_signal, u_ref_signal, ref_dark, u_ref_dark, ref_itime_ms,
                    ref_gain_factor, ref_theta_o_deg, beta_ref, u_beta_ref):
    """Radiance factor and its standard uncertainty from the measurement equation.

    All arguments broadcast (numpy). ``u_*`` are standard errors of the means
    (``std / sqrt(n)``); ``gain_factor`` is the amplifier factor (1, 4, 16, 64), not the step.

    Returns
    -------
    beta, u_beta : ndarray
    """
    S, uS, D, uD = (np.asarray(v, dtype=float) for v in (signal, u_signal, dark, u_dark))
    Sr, uSr, Dr, uDr = (np.asarray(v, dtype=float) for v in (ref_signal, u_ref_signal, ref_dark, u_ref_dark))
    ref_rate = (Sr - Dr) / (np.asarray(ref_itime_ms, float) * np.asarray(ref_gain_factor, float))
    C = (np.asarray(beta_ref, float) * np.cos(np.radians(ref_theta_o_deg))
         / (np.asarray(itime_ms, float) * np.asarray(gain_factor, float)
            * np.cos(np.radians(theta_o_deg)) * ref_rate))
    beta = C * (S - D)
    rel_ref = (uSr**2 + uDr**2) / (Sr - Dr) ** 2 + (np.asarray(u_beta_ref, float) / beta_ref) ** 2
    u_beta = np.sqrt(C**2 * (uS**2 + uD**2) + beta**2 * rel_ref)
    return beta, u_beta
