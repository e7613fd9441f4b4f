"""The vectorisable exponential and the spectral scoring built on it.

References are independent of the code under test: numpy's ``exp`` (libm) and the formula of
:func:`simulate.montecarlo.tallies._score_spectral`'s docstring evaluated with numpy.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from simulate.montecarlo import tallies as T
from simulate.montecarlo.vecmath import EXP_MAX_ARG, EXP_MIN_ARG, vexp


@numba.njit(cache=False)
def _vexp_array(x):
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = vexp(x[i])
    return out


def test_vexp_within_two_ulp_of_libm_over_its_range():
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.uniform(EXP_MIN_ARG, EXP_MAX_ARG, 200_000), rng.uniform(-1.0, 1.0, 200_000),
                        -rng.exponential(1e-6, 10_000), np.arange(-708, 710, dtype=float),
                        [-0.34657359027997264, 0.34657359027997264, -1e-300, 1e-300]])
    got = _vexp_array(x)
    ref = np.exp(x)
    ulp = np.abs(got - ref) / np.spacing(ref)
    assert ulp.max() <= 2.0, (x[np.argmax(ulp)], ulp.max())


def test_vexp_special_values():
    x = np.array([0.0, -0.0, -708.5, -745.2, -1e308, -np.inf, 709.5, 1e308, np.inf, np.nan])
    got = _vexp_array(x)
    assert got[0] == 1.0 and got[1] == 1.0
    assert np.all(got[2:6] == 0.0)
    assert np.all(np.isposinf(got[6:9]))
    assert math.isnan(got[9])


@numba.njit(cache=False)
def _score_histories(hist, touched, n_touched, marks, bins, blocks, n_spec, g0, spec_w, spec_mu_t, paths,
                     phase_ratio, ratio, cos_s, history_of):
    """Score (block, path, cos) triples; a new history starts where ``history_of`` changes."""
    scratch = T.Scratch(hist, touched, n_touched, marks, n_spec)
    spectral = T.Spectral(spec_w, spec_mu_t, phase_ratio, ratio)
    for i in range(blocks.size):
        if i > 0 and history_of[i] != history_of[i - 1]:
            T.flush_history(scratch, bins)
        T._score_spectral(scratch, blocks[i], g0[i], spectral, paths[i], cos_s[i])
    T.flush_history(scratch, bins)


@pytest.mark.parametrize("phase_ratio", [False, True])
def test_spectral_scores_sum_per_history_and_square_per_history(phase_ratio):
    """bins[k] = (sum over histories of h_k, sum of h_k^2), h_k = sum of the history's scores in k."""
    rng = np.random.default_rng(2)
    n_spec, n_blocks, n_grid = 7, 4, 33
    spec_w = rng.uniform(0.2, 2.0, n_spec)
    spec_mu_t = rng.uniform(0.0, 3.0, n_spec)
    ratio = rng.uniform(0.5, 1.5, (n_grid, n_spec))
    # histories 0, 0, 0, 1, 1, 2: history 0 scores block 2 twice
    blocks = np.array([2, 0, 2, 3, 0, 2])
    history_of = np.array([0, 0, 0, 1, 1, 2])
    g0 = rng.uniform(0.1, 1.0, blocks.size)
    paths = rng.uniform(0.0, 5.0, blocks.size)
    cos_s = rng.uniform(-1.0, 1.0, blocks.size)
    hist = np.zeros(n_blocks * n_spec)
    bins = np.zeros((n_blocks * n_spec, 2))
    touched = np.zeros(n_blocks, dtype=np.int64)
    marks = np.zeros(n_blocks, dtype=np.bool_)
    _score_histories(hist, touched, np.zeros(1, dtype=np.int64), marks, bins, blocks, n_spec, g0, spec_w, spec_mu_t,
                     paths, phase_ratio, ratio, cos_s, history_of)

    # reference: the docstring's formula, numpy exp, the ratio interpolated on t = sqrt((1 - mu) / 2)
    scores = np.zeros((history_of.max() + 1, n_blocks, n_spec))
    for i in range(blocks.size):
        t = math.sqrt((1.0 - cos_s[i]) / 2.0) * (n_grid - 1)
        j = min(int(t), n_grid - 2)
        p = ratio[j] + (t - j) * (ratio[j + 1] - ratio[j]) if phase_ratio else 1.0
        scores[history_of[i], blocks[i]] += g0[i] * spec_w * p * np.exp(-spec_mu_t * paths[i])
    want_sum = scores.sum(axis=0).ravel()
    want_sq = (scores ** 2).sum(axis=0).ravel()
    np.testing.assert_allclose(bins[:, 0], want_sum, rtol=1e-13, atol=0)
    np.testing.assert_allclose(bins[:, 1], want_sq, rtol=1e-13, atol=0)
    # the scratch tally is clean for the next history
    assert not hist.any() and not marks.any()
    # block 1 was never scored: its bins stay exactly zero
    assert not bins[n_spec:2 * n_spec].any()
