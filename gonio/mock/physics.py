"""Forward measurement model of the mock photometer head: counts from the sample's truth.

The measurement equation of docs/instrument.md run forwards. For integration time ``t`` (ms), gain
factor ``G`` (1, 4, 16, 64), wavelength ``lambda`` and the radiance coefficient ``f`` of what sits
in the beam at ``(w_i, w_o)``::

    signal   = K(lambda) t G f cos(theta_o)          (shutter open; 0 when closed)
    dark     = D0 + d t G                             (bias D0 and amplified dark current d)
    reading  = round(dark + signal + e),  e ~ N(0, G (signal + d t G) + sigma_read^2)
    reading  = clip(reading, 0, 65535)

The shot-noise variance ``G * mean`` follows from one photo-electron per count at ``G = 1``
amplified ``G`` times; ``sigma_read`` is the read noise after the amplifier. ``K(lambda)`` is
a smooth lamp-times-responsivity curve: a CIE illuminant A lamp (Planck, 2856 K) times a
silicon-like detector / grating response, scaled so that the white standard at 0/45, 100 ms,
gain x1 stays below saturation (60000 counts) at every wavelength.

Noise is reproducible: the normal deviates of one ``READ? n`` come from a Philox stream keyed by
``(seed, axis positions, slot, wavelength, t, gain, shutter, lamp, first repetition, n)`` through
``numpy.random.SeedSequence`` - never by call count - so an interrupted and resumed session
reproduces an uninterrupted one exactly.

References
----------
CIE 15:2004 (illuminant A, Planck's law with c2 = 1.4388e-2 m K); docs/instrument.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.instrument import head_commands as HC

__all__ = [
    "K_counts_per_ms", "dark_counts", "DARK_OFFSET_COUNTS", "DARK_RATE_COUNTS_PER_MS",
    "READ_NOISE_COUNTS", "ReadingState", "expected_counts", "simulate_readings", "noise_key",
    "summarise",
]

DARK_OFFSET_COUNTS = 200.0
DARK_RATE_COUNTS_PER_MS = 0.05
READ_NOISE_COUNTS = 3.0
_K_PEAK = 600.0          # counts / ms at the maximum of K, gain x1, f = 1, cos = 1
_NOISE_DOMAIN = 0x6E6F6973   # separates the noise streams from the fault streams


def _planck_relative(wavelength_nm, temperature_k: float = 2856.0):
    wl = np.asarray(wavelength_nm, dtype=float) * 1e-9
    c2 = 1.4388e-2
    return wl ** -5 / np.expm1(c2 / (wl * temperature_k))


def _shape(wavelength_nm):
    wl = np.asarray(wavelength_nm, dtype=float)
    response = np.exp(-0.5 * ((wl - 560.0) / 150.0) ** 2)      # grating x detector, broad
    return _planck_relative(wl) * response


_GRID = np.linspace(HC.WAVE_RANGE_NM[0], HC.WAVE_RANGE_NM[1], 401)
_SHAPE_MAX = float(np.max(_shape(_GRID)))


def K_counts_per_ms(wavelength_nm) -> np.ndarray:
    """Lamp-times-responsivity ``K(lambda)``: counts per ms at gain x1 for ``f cos(theta_o) = 1``."""
    return _K_PEAK * _shape(wavelength_nm) / _SHAPE_MAX


def dark_counts(itime_ms, gain_factor) -> np.ndarray:
    """Mean dark reading ``D0 + d t G`` (shutter closed)."""
    t = np.asarray(itime_ms, dtype=float)
    return DARK_OFFSET_COUNTS + DARK_RATE_COUNTS_PER_MS * t * np.asarray(gain_factor, dtype=float)


@dataclass(frozen=True)
class ReadingState:
    """Everything a reading depends on (the noise key without seed and repetition)."""

    positions_mdeg: tuple[int, int, int, int]
    slot: int
    wavelength_dnm: int          # wavelength in 0.1 nm
    itime_ms: int
    gain_step: int
    shutter_open: bool
    lamp_on: bool

    @property
    def wavelength_nm(self) -> float:
        """The wavelength, nm."""
        return self.wavelength_dnm / 10.0

    @property
    def gain_factor(self) -> int:
        """The gain factor of the gain step."""
        return HC.GAIN_FACTORS[self.gain_step]


def expected_counts(state: ReadingState, f_value: float, cos_theta_o: float) -> tuple[float, float]:
    """Mean signal and mean dark (counts) of one reading before noise and clipping."""
    g = state.gain_factor
    signal = 0.0
    if state.shutter_open and state.lamp_on:
        k = float(K_counts_per_ms(state.wavelength_nm))
        signal = k * state.itime_ms * g * f_value * max(cos_theta_o, 0.0)
    return signal, float(dark_counts(state.itime_ms, g))


def noise_key(seed: int, state: ReadingState, first_repetition: int, n: int) -> list[int]:
    """Non-negative integers keying the Philox stream of one ``READ?``."""
    pos = [int(p) + (1 << 31) for p in state.positions_mdeg]
    return [_NOISE_DOMAIN, int(seed) & 0xFFFFFFFFFFFFFFFF, *pos, state.slot, state.wavelength_dnm,
            state.itime_ms, state.gain_step, int(state.shutter_open), int(state.lamp_on),
            int(first_repetition), int(n)]


def simulate_readings(seed: int, state: ReadingState, f_value: float, cos_theta_o: float,
                      first_repetition: int, n: int) -> np.ndarray:
    """``n`` integer readings (counts, float array) of the forward model, reproducibly seeded."""
    signal, dark = expected_counts(state, f_value, cos_theta_o)
    g = state.gain_factor
    dark_current = dark - DARK_OFFSET_COUNTS
    variance = g * (signal + dark_current) + READ_NOISE_COUNTS ** 2
    key = noise_key(seed, state, first_repetition, n)
    rng = np.random.Generator(np.random.Philox(np.random.SeedSequence(key)))
    z = rng.standard_normal(n)
    readings = np.rint(dark + signal + np.sqrt(variance) * z)
    return np.clip(readings, 0.0, float(HC.ADC_MAX_COUNTS))


def summarise(readings: np.ndarray) -> tuple[float, float, int, int]:
    """``(mean, std, n, saturated-flag)`` of readings; ``std`` uses ``n - 1`` (0 for one reading)."""
    n = int(readings.size)
    mean = float(np.mean(readings))
    std = float(np.std(readings, ddof=1)) if n > 1 else 0.0
    flags = HC.FLAG_SATURATED if np.any(readings >= HC.SATURATION_COUNTS) else 0
    return mean, std, n, flags
