"""The kernel's phase function: the compiled sampler and the compiled density describe one distribution."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy import stats

from simulate.montecarlo.scatter import azimuth, evaluate_pdf, phase_arrays, sample_directions
from simulate.optics import mie
from simulate.optics.phase import PhaseTable


def _cases():
    mu = mie.phase_grid(20.0)
    p = mie.phase_function(complex(1.2, 0.0), 20.0, mu)
    return {
        "hg0.8": phase_arrays(g=0.8),
        "hg-0.3": phase_arrays(g=-0.3),
        "iso": phase_arrays(g=0.0),
        "mie-table": phase_arrays(cos_table=PhaseTable.from_tabulated(mu, p, K=2048).cos_table),
    }


@pytest.mark.parametrize("name", list(_cases()))
def test_sampled_cosines_follow_the_evaluated_density(name):
    pa = _cases()[name]
    u = np.array([0.3, -0.5, math.sqrt(1 - 0.34)])
    d = sample_directions(u, 200_000, 17, pa.kind, pa.g, pa.table)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    mu = d @ u
    edges = np.linspace(-1, 1, 41)
    counts, _ = np.histogram(mu, bins=edges)
    # expected counts: 2 pi int p dmu over each bin (fine midpoint rule on the compiled density)
    fine = np.linspace(-1, 1, 40 * 400 + 1)
    mid = 0.5 * (fine[1:] + fine[:-1])
    dens = evaluate_pdf(mid, pa.kind, pa.g, pa.table, pa.pdf, pa.lookup) * 2 * math.pi * np.diff(fine)
    expected = dens.reshape(40, 400).sum(axis=1)
    assert expected.sum() == pytest.approx(1.0, abs=2e-3)  # normalised over the sphere
    expected = expected / expected.sum() * counts.sum()
    keep = expected > 5
    chi2 = np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep])
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-4
    # azimuth uniform about u: the component along a fixed perpendicular has mean 0
    perp = np.cross(u, [1.0, 0.0, 0.0])
    perp /= np.linalg.norm(perp)
    c = d @ perp
    assert abs(c.mean()) < 4 * c.std() / math.sqrt(c.size)


def test_hg_density_matches_the_closed_form():
    pa = phase_arrays(g=0.6)
    mu = np.linspace(-1, 1, 11)
    ref = (1 - 0.36) / (4 * math.pi * (1 + 0.36 - 1.2 * mu) ** 1.5)
    np.testing.assert_allclose(evaluate_pdf(mu, pa.kind, pa.g, pa.table, pa.pdf, pa.lookup), ref, rtol=1e-12)


@numba.njit(cache=False)
def azimuth_pair(r):
    return azimuth(r)


def test_azimuth_table_matches_cos_and_sin():
    # every table node, the last offset before the next node, and a spread of offsets between
    k = np.unique(np.concatenate([np.arange(256) << 16, (np.arange(256) << 16) + 0xFFFF,
                                  np.random.default_rng(5).integers(0, 2**24, 20_000)]))
    got = np.array([azimuth_pair(np.uint64(v)) for v in k])
    phi = 2.0 * math.pi * k / 2**24
    np.testing.assert_allclose(got[:, 0], np.cos(phi), rtol=0, atol=3e-15)
    np.testing.assert_allclose(got[:, 1], np.sin(phi), rtol=0, atol=3e-15)


def test_sampled_azimuth_is_uniform_about_the_old_direction():
    pa = phase_arrays(g=0.5)
    u = np.array([0.3, -0.5, math.sqrt(1 - 0.34)])
    d = sample_directions(u, 200_000, 23, pa.kind, pa.g, pa.table)
    e1 = np.cross(u, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    phi = np.arctan2(d @ e2, d @ e1)
    counts, _ = np.histogram(phi, bins=36, range=(-math.pi, math.pi))
    expected = counts.sum() / 36
    chi2 = np.sum((counts - expected) ** 2 / expected)
    assert stats.chi2.sf(chi2, 35) > 1e-4
