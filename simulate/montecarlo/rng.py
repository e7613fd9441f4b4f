"""Reproducible random streams for the compiled Monte Carlo kernel.

Every batch of photons owns an independent stream of the xoshiro256** generator
(Blackman & Vigna 2021), seeded from the pair ``(seed, batch)`` through splitmix64
(Steele, Lea & Flood 2014)::

    key   = splitmix64(seed) XOR splitmix64(batch + 0x632BE59BD9B4E019)
    s[k]  = splitmix64 outputs k = 0..3 of the sequence started at key

A photon's random numbers therefore depend only on the seed, the batch index and its
position in the batch -- never on which thread ran the batch -- so a fixed seed gives
identical results for any number of threads.

The state is four ``uint64`` scalars that the kernel carries in local variables (so they
live in registers): :func:`next_u64` takes and returns them. A 64-bit output ``x`` becomes::

    u      = (x >> 11) * 2^-53               uniform in [0, 1)          (to_uniform)
    u_open = ((x >> 11) + 1) * 2^-53         uniform in (0, 1]          (to_uniform_open)
    (a, b) = ((x >> 32) 2^-31 - 1, (x mod 2^32) 2^-31 - 1)
                                             two uniforms in [-1, 1)     (to_signed_pair)

The pair uses the two 32-bit halves of one output: every bit of an xoshiro256** output is
of full quality (the ``**`` scrambler, unlike ``+``, has no weak low bits), and 32 bits
(grid 4.7e-10) are ample for the azimuth of a scattering event, where the pair is a point
of the square accepted when it falls inside the unit disc.

Exponential free paths use the ziggurat method of Marsaglia & Tsang (2000) with 256 layers
(the layout of numpy's ``standard_exponential``): one 64-bit output gives a layer index
``i`` (8 bits) and a 53-bit integer ``j``; ``x = j w_i`` is returned at once when
``j < k_i`` (98.9 % of draws: one table look-up and a multiplication, no logarithm); the
rest is the exact wedge test ``f_{i} + u (f_{i-1} - f_i) < exp(-x)`` or, for the base
layer, the tail ``r - ln(u)`` beyond ``r``. The layer edges ``x_i`` solve
``x_i (exp(-x_{i-1}) - exp(-x_i)) = v`` downwards from ``x_255 = r = 7.69711747013104972``
with ``v = 3.9496598225815572e-3`` (the area of every layer), ``x_0 = 0``; the tables are
built once at import. The samples are exactly Exp(1) distributed (up to the 2^-53 grid).

References
----------
Blackman, D. & Vigna, S. (2021). Scrambled linear pseudorandom number generators.
*ACM Trans. Math. Softw.* 47(4), 36.
Steele, G. L., Lea, D. & Flood, C. H. (2014). Fast splittable pseudorandom number
generators. *OOPSLA '14*, 453-472.
Marsaglia, G. & Tsang, W. W. (2000). The ziggurat method for generating random variables.
*J. Stat. Softw.* 5(8), 1-7.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "ZIGGURAT_R",
    "ZIGGURAT_V",
    "splitmix64",
    "seed_state",
    "next_u64",
    "to_uniform",
    "to_uniform_open",
    "to_signed_pair",
    "exponential",
    "ziggurat_tables",
    "stream_uniforms",
    "stream_exponentials",
]

_U = np.uint64
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_BATCH_SALT = np.uint64(0x632BE59BD9B4E019)
_LOW32 = np.uint64(0xFFFFFFFF)
_LOW8 = np.uint64(0xFF)
_INV53 = 1.0 / 9007199254740992.0  # 2^-53
_INV31 = 1.0 / 2147483648.0  # 2^-31

ZIGGURAT_R = 7.69711747013104972  # right edge of the base layer
ZIGGURAT_V = 3.9496598225815571993e-3  # area of each of the 256 layers


def ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tables of the 256-layer exponential ziggurat.

    Returns
    -------
    k : numpy.ndarray
        ``uint64[256]``: fast-acceptance thresholds ``round(2^53 x_{i-1} / x_i)``
        (base layer: ``round(2^53 r / q)`` with ``q = v e^r``).
    w : numpy.ndarray
        ``float64[256]``: ``x_i 2^-53`` (base layer ``q 2^-53``).
    f : numpy.ndarray
        ``float64[256]``: ``exp(-x_i)``.
    x : numpy.ndarray
        ``float64[256]``: layer edges, ``x_0 = 0 < x_1 < ... < x_255 = r``.
    """
    x = np.empty(256)
    x[255] = ZIGGURAT_R
    for i in range(255, 1, -1):
        x[i - 1] = -math.log(math.exp(-x[i]) + ZIGGURAT_V / x[i])
    x[0] = 0.0
    q = ZIGGURAT_V * math.exp(ZIGGURAT_R)
    scale = 2.0**53
    k = np.empty(256, dtype=np.uint64)
    k[0] = np.uint64(round(ZIGGURAT_R / q * scale))
    k[1:] = np.round(x[:-1] / x[1:] * scale).astype(np.uint64)
    w = x / scale
    w[0] = q / scale
    f = np.exp(-x)
    return k, w, f, x


_ZK, _ZW, _ZF, _ = ziggurat_tables()


@numba.njit(cache=True, inline="always")
def _rotl(x: np.uint64, k: int) -> np.uint64:
    return (x << _U(k)) | (x >> _U(64 - k))


@numba.njit(cache=True, inline="always")
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> _U(30))) * _MIX1
    z = (z ^ (z >> _U(27))) * _MIX2
    return z ^ (z >> _U(31))


@numba.njit(cache=True)
def splitmix64(x: np.uint64) -> np.uint64:
    """Return the splitmix64 finaliser of ``x + golden`` (one step of the sequence)."""
    return _mix(x + _GOLDEN)


@numba.njit(cache=True)
def seed_state(seed: int, batch: int) -> tuple[np.uint64, np.uint64, np.uint64, np.uint64]:
    """The xoshiro256** state ``(s0, s1, s2, s3)`` of stream ``(seed, batch)``."""
    key = splitmix64(_U(seed)) ^ splitmix64(_U(batch) + _BATCH_SALT)
    s0 = _mix(key + _GOLDEN)
    s1 = _mix(key + _U(2) * _GOLDEN)
    s2 = _mix(key + _U(3) * _GOLDEN)
    s3 = _mix(key + _U(4) * _GOLDEN)
    if s0 == 0 and s1 == 0 and s2 == 0 and s3 == 0:
        s0 = _GOLDEN  # the all-zero state is the one fixed point of xoshiro
    return s0, s1, s2, s3


@numba.njit(cache=True, inline="always")
def next_u64(
    s0: np.uint64, s1: np.uint64, s2: np.uint64, s3: np.uint64
) -> tuple[np.uint64, np.uint64, np.uint64, np.uint64, np.uint64]:
    """Advance xoshiro256**: return ``(output, s0, s1, s2, s3)``."""
    result = _rotl(s1 * _U(5), 7) * _U(9)
    t = s1 << _U(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 45)
    return result, s0, s1, s2, s3


@numba.njit(cache=True, inline="always")
def to_uniform(x: np.uint64) -> float:
    """Uniform double in [0, 1) from the top 53 bits of ``x``."""
    return float(x >> _U(11)) * _INV53


@numba.njit(cache=True, inline="always")
def to_uniform_open(x: np.uint64) -> float:
    """Uniform double in (0, 1] from the top 53 bits of ``x`` (safe as the argument of ``log``)."""
    return float((x >> _U(11)) + _U(1)) * _INV53


@numba.njit(cache=True, inline="always")
def to_signed_pair(x: np.uint64) -> tuple[float, float]:
    """Two independent uniforms in [-1, 1) from the 32-bit halves of ``x``."""
    return float(x >> _U(32)) * _INV31 - 1.0, float(x & _LOW32) * _INV31 - 1.0


# fastmath given explicitly (False): numba compiles a callee with its caller's fastmath flags unless
# the callee sets its own, and caches whichever flavour was compiled first; this function is called
# by the (fastmath) kernel and by stream_exponentials, so its numerics would depend on which ran first
@numba.njit(cache=True, fastmath=False)
def _exponential_slow(
    i: int, j: np.uint64, s0: np.uint64, s1: np.uint64, s2: np.uint64, s3: np.uint64
) -> tuple[float, np.uint64, np.uint64, np.uint64, np.uint64]:
    """The rare branches of :func:`exponential` (wedges, tail, retries)."""
    while True:
        if i == 0:
            r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
            return ZIGGURAT_R - math.log(to_uniform_open(r)), s0, s1, s2, s3
        x = float(j) * _ZW[i]
        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        if _ZF[i] + to_uniform(r) * (_ZF[i - 1] - _ZF[i]) < math.exp(-x):
            return x, s0, s1, s2, s3
        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        j = r >> _U(3)
        i = int(j & _LOW8)
        j = j >> _U(8)
        if j < _ZK[i]:
            return float(j) * _ZW[i], s0, s1, s2, s3


@numba.njit(cache=True, inline="always")
def exponential(
    s0: np.uint64, s1: np.uint64, s2: np.uint64, s3: np.uint64
) -> tuple[float, np.uint64, np.uint64, np.uint64, np.uint64]:
    """An Exp(1) variate by the ziggurat method: return ``(value, s0, s1, s2, s3)``."""
    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
    j = r >> _U(3)
    i = int(j & _LOW8)
    j = j >> _U(8)
    if j < _ZK[i]:
        return float(j) * _ZW[i], s0, s1, s2, s3
    return _exponential_slow(i, j, s0, s1, s2, s3)


@numba.njit(cache=True)
def stream_uniforms(seed: int, batch: int, count: int) -> np.ndarray:
    """Return the first ``count`` uniforms in [0, 1) of stream ``(seed, batch)`` (for tests).

    Parameters
    ----------
    seed, batch : int
        Non-negative stream identifiers.
    count : int
        Number of values.

    Returns
    -------
    numpy.ndarray
        ``float64[count]``.
    """
    s0, s1, s2, s3 = seed_state(seed, batch)
    out = np.empty(count)
    for n in range(count):
        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        out[n] = to_uniform(r)
    return out


@numba.njit(cache=True)
def stream_exponentials(seed: int, batch: int, count: int) -> np.ndarray:
    """Return ``count`` successive :func:`exponential` variates of stream ``(seed, batch)`` (for tests).

    Parameters
    ----------
    seed, batch : int
        Non-negative stream identifiers.
    count : int
        Number of values.

    Returns
    -------
    numpy.ndarray
        ``float64[count]``, Exp(1) distributed.
    """
    s0, s1, s2, s3 = seed_state(seed, batch)
    out = np.empty(count)
    for n in range(count):
        e, s0, s1, s2, s3 = exponential(s0, s1, s2, s3)
        out[n] = e
    return out
