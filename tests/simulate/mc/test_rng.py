"""Random variates of the kernel: ziggurat exponential free paths and the disc-azimuth pair."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy import stats

from simulate.montecarlo import rng


def test_ziggurat_layers_have_equal_area():
    k, w, f, x = rng.ziggurat_tables()
    v = rng.ZIGGURAT_V
    assert x[0] == 0.0 and x[255] == rng.ZIGGURAT_R and np.all(np.diff(x) > 0)
    # layer i >= 1: rectangle [0, x_i] x [exp(-x_i), exp(-x_{i-1})]
    areas = x[1:] * (np.exp(-x[:-1]) - np.exp(-x[1:]))
    assert np.allclose(areas, v, rtol=1e-11, atol=0)
    # base layer: rectangle [0, r] x [0, exp(-r)] plus the tail integral exp(-r)
    r = rng.ZIGGURAT_R
    assert (r + 1.0) * math.exp(-r) == pytest.approx(v, rel=1e-12)
    # the ziggurat covers the density: 256 v = 1 + area above the curve
    assert 256 * v > 1.0
    # fast-acceptance thresholds are the width ratios on the 2^53 grid
    assert np.array_equal(f, np.exp(-x))
    ratio = k[1:].astype(float) / 2.0**53
    assert np.allclose(ratio, x[:-1] / x[1:], rtol=1e-15, atol=2.0**-53)
    assert w[0] * float(k[0]) == pytest.approx(r, rel=1e-15)


def test_exponential_variates_follow_exp1():
    n = 4_000_000
    e = rng.stream_exponentials(17, 3, n)
    assert np.all(e >= 0) and np.all(np.isfinite(e))
    # mean and variance of Exp(1) (both 1) within 4 standard errors
    assert abs(e.mean() - 1.0) < 4 * 1.0 / math.sqrt(n)
    assert abs(e.var() - 1.0) < 4 * math.sqrt(8.0 / n)  # var of (X-1)^2 is 8
    # chi-square over 200 equal-probability bins (199 dof; p ~ 1e-4 threshold ~ 272)
    edges = -np.log1p(-np.linspace(0.0, 1.0, 201)[:-1])
    counts = np.histogram(e, bins=np.append(edges, np.inf))[0]
    expected = n / 200
    assert np.sum((counts - expected) ** 2 / expected) < 272
    # the tail beyond the base layer (r ~ 7.7) and far beyond it (sampled by r - ln u)
    for cut in (rng.ZIGGURAT_R, 2 * rng.ZIGGURAT_R - 3.0):
        p = math.exp(-cut)
        assert abs(np.mean(e > cut) - p) < 4 * math.sqrt(p * (1 - p) / n) + 1.0 / n
    # Kolmogorov-Smirnov on a sub-sample
    assert stats.kstest(e[:500_000], "expon").pvalue > 1e-3


def test_exponential_streams_are_independent():
    a = rng.stream_exponentials(5, 0, 200_000)
    b = rng.stream_exponentials(5, 1, 200_000)
    assert np.array_equal(a, rng.stream_exponentials(5, 0, 200_000))
    assert abs(np.corrcoef(a, b)[0, 1]) < 4 / math.sqrt(a.size)
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < 4 / math.sqrt(a.size)  # no serial correlation


def test_signed_pair_uses_both_halves_exactly():
    assert rng.to_signed_pair(np.uint64(0)) == (-1.0, -1.0)
    top = 1.0 - 2.0**-31
    assert rng.to_signed_pair(np.uint64(2**64 - 1)) == (top, top)
    assert rng.to_signed_pair(np.uint64(2**63)) == (0.0, -1.0)
    assert rng.to_signed_pair(np.uint64(2**31)) == (-1.0, 0.0)


@numba.njit(cache=False)
def _disc_azimuths(seed: int, count: int) -> np.ndarray:
    s0, s1, s2, s3 = rng.seed_state(seed, 0)
    out = np.empty((count, 2))
    for n in range(count):
        while True:
            x, s0, s1, s2, s3 = rng.next_u64(s0, s1, s2, s3)
            a, b = rng.to_signed_pair(x)
            r2 = a * a + b * b
            if r2 <= 1.0 and r2 > 0.0:
                break
        out[n, 0] = (a * a - b * b) / r2
        out[n, 1] = 2.0 * a * b / r2
    return out


def test_disc_pair_gives_uniform_azimuth():
    """The kernel's azimuth construction: (cos phi, sin phi) of a uniform phi."""
    n = 1_000_000
    cs = _disc_azimuths(23, n)
    assert np.allclose(cs[:, 0] ** 2 + cs[:, 1] ** 2, 1.0, rtol=0, atol=1e-15)
    phi = np.arctan2(cs[:, 1], cs[:, 0])
    counts = np.histogram(phi, bins=72, range=(-math.pi, math.pi))[0]
    expected = n / 72
    assert np.sum((counts - expected) ** 2 / expected) < 120  # 71 dof, p ~ 3e-4
    # E[cos phi] = E[sin phi] = E[cos phi sin phi] = 0, E[cos^2 phi] = 1/2
    assert abs(cs[:, 0].mean()) < 4 * math.sqrt(0.5 / n) and abs(cs[:, 1].mean()) < 4 * math.sqrt(0.5 / n)
    assert abs(np.mean(cs[:, 0] ** 2) - 0.5) < 4 * math.sqrt(0.125 / n)
    assert abs(np.mean(cs[:, 0] * cs[:, 1])) < 4 * math.sqrt(0.125 / n)
