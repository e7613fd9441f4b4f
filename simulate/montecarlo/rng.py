"""Reproducible random streams for the compiled Monte Carlo kernel.

Every batch of photons owns an independent stream of the xoshiro256** generator
(Blackman & Vigna 2021), seeded from the pair ``(seed, batch)`` through splitmix64
(Steele, Lea & Flood 2014)::

    key   = splitmix64(seed) XOR splitmix64(batch + 0x632BE59BD9B4E019)
    s[k]  = splitmix64 outputs k = 0..3 of the sequence started at key

A photon's random numbers therefore depend only on the seed, the batch index and its
position in the batch -- never on which thread ran the batch -- so a fixed seed gives
identical results for any number of threads. Uniform doubles take the top 53 bits::

    u = (x >> 11) * 2^-53            in [0, 1)
    u_open = ((x >> 11) + 1) * 2^-53 in (0, 1]   (safe for -ln(u))

The generator state is a ``uint64[4]`` array owned by the batch; all functions are
``numba.njit(cache=True)`` and are inlined into the kernel.

References
----------
Blackman, D. & Vigna, S. (2021). Scrambled linear pseudorandom number generators.
*ACM Trans. Math. Softw.* 47(4), 36.
Steele, G. L., Lea, D. & Flood, C. H. (2014). Fast splittable pseudorandom number
generators. *OOPSLA '14*, 453-472.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["splitmix64", "seed_stream", "next_u64", "uniform", "uniform_open", "stream_uniforms"]

_U = np.uint64
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_BATCH_SALT = np.uint64(0x632BE59BD9B4E019)
_INV53 = 1.0 / 9007199254740992.0  # 2^-53


@numba.njit(cache=True, inline="always")
def _rotl(x: np.uint64, k: int) -> np.uint64:
    return (x << _U(k)) | (x >> _U(64 - k))


@numba.njit(cache=True)
def splitmix64(x: np.uint64) -> np.uint64:
    """Return the splitmix64 finaliser of ``x + golden`` (one step of the sequence)."""
    z = x + _GOLDEN
    z = (z ^ (z >> _U(30))) * _MIX1
    z = (z ^ (z >> _U(27))) * _MIX2
    return z ^ (z >> _U(31))


@numba.njit(cache=True)
def seed_stream(state: np.ndarray, seed: int, batch: int) -> None:
    """Fill ``state`` (``uint64[4]``) with the xoshiro256** state of stream ``(seed, batch)``."""
    key = splitmix64(_U(seed)) ^ splitmix64(_U(batch) + _BATCH_SALT)
    for k in range(4):
        key = key + _GOLDEN
        z = key
        z = (z ^ (z >> _U(30))) * _MIX1
        z = (z ^ (z >> _U(27))) * _MIX2
        state[k] = z ^ (z >> _U(31))
    if state[0] == 0 and state[1] == 0 and state[2] == 0 and state[3] == 0:
        state[0] = _GOLDEN  # the all-zero state is the one fixed point of xoshiro


@numba.njit(cache=True, inline="always")
def next_u64(state: np.ndarray) -> np.uint64:
    """Advance xoshiro256** and return the next 64-bit output."""
    s0 = state[0]
    s1 = state[1]
    s2 = state[2]
    s3 = state[3]
    result = _rotl(s1 * _U(5), 7) * _U(9)
    t = s1 << _U(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 45)
    state[0] = s0
    state[1] = s1
    state[2] = s2
    state[3] = s3
    return result


@numba.njit(cache=True, inline="always")
def uniform(state: np.ndarray) -> float:
    """Uniform double in [0, 1)."""
    return float(next_u64(state) >> _U(11)) * _INV53


@numba.njit(cache=True, inline="always")
def uniform_open(state: np.ndarray) -> float:
    """Uniform double in (0, 1], safe as the argument of ``log``."""
    return float((next_u64(state) >> _U(11)) + _U(1)) * _INV53


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
    state = np.empty(4, dtype=np.uint64)
    seed_stream(state, seed, batch)
    out = np.empty(count)
    for i in range(count):
        out[i] = uniform(state)
    return out
