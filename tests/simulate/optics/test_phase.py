"""Phase functions and the inverse-CDF sampling table (docs/quality.md section A: sampled g)."""

import numpy as np
import pytest
from scipy import integrate

from simulate.optics import mie
from simulate.optics.phase import PhaseTable, henyey_greenstein


def _kernel_rule(table, u):
    """The Monte Carlo kernel's lookup, written out scalar by scalar."""
    c = table.cos_table
    K = len(c) - 1
    out = []
    for ui in u:
        j = int(np.floor(ui * K))
        f = ui * K - j
        out.append((1 - f) * c[j] + f * c[j + 1])
    return np.array(out)


@pytest.mark.parametrize("g", [-0.5, 0.0, 0.3, 0.9, 0.99])
def test_henyey_greenstein_normalised_with_mean_g(g):
    norm = 2 * np.pi * integrate.quad(lambda mu: henyey_greenstein(mu, g), -1, 1, points=[1.0], limit=200)[0]
    mean = 2 * np.pi * integrate.quad(lambda mu: mu * henyey_greenstein(mu, g), -1, 1, limit=200)[0]
    assert norm == pytest.approx(1.0, abs=1e-9)
    assert mean == pytest.approx(g, abs=1e-9)


@pytest.mark.parametrize("g", [-0.7, 0.0, 0.5, 0.95])
def test_hg_table_nodes_sit_on_the_analytic_cdf(g):
    K = 512
    table = PhaseTable.from_hg(g, K)
    mu = table.cos_table
    if g == 0.0:
        cdf = (mu + 1) / 2
    else:  # F(mu) = (1 - g^2) / (2g) [ (1 + g^2 - 2 g mu)^(-1/2) - (1 + g)^(-1) ]
        cdf = (1 - g * g) / (2 * g) * ((1 + g * g - 2 * g * mu) ** -0.5 - 1 / (1 + g))
    np.testing.assert_allclose(cdf, np.arange(K + 1) / K, atol=1e-12)
    assert table.cos_table.dtype == np.float64 and table.cos_table.shape == (K + 1,)


def test_sample_follows_the_kernel_rule():
    table = PhaseTable.from_hg(0.8, 64)
    u = np.random.default_rng(1).random(1000)
    u = np.concatenate((u, [0.0, 1 / 64, 0.5, 1 - 1e-16]))
    np.testing.assert_allclose(table.sample(u), _kernel_rule(table, u), rtol=0, atol=1e-15)


def test_mean_cosine_and_second_moment_of_piecewise_uniform_table():
    # a 2-interval table: uniform on [-1, 0] and [0, 1] with probability 1/2 each is isotropic
    t = PhaseTable(np.array([-1.0, 0.0, 1.0]))
    assert t.mean_cosine() == 0.0
    assert t.second_moment() == pytest.approx(1 / 3)
    t = PhaseTable(np.array([-1.0, 0.5, 1.0]))  # mean = (1/2)(-0.25) + (1/2)(0.75)
    assert t.mean_cosine() == pytest.approx(0.25)


def test_table_from_rayleigh_samples_matches_analytic_inverse():
    mu = np.cos(np.linspace(0, np.pi, 4001))
    p = 3 * (1 + mu**2) / (16 * np.pi)
    table = PhaseTable.from_tabulated(mu, p, K=1000)
    c = table.cos_table
    cdf = 0.375 * (c + c**3 / 3) + 0.5  # F(mu) of the Rayleigh phase function
    np.testing.assert_allclose(cdf, np.arange(1001) / 1000, atol=1e-7)
    assert table.quadrature_norm == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("m,x", [(1.2, 80.0), (1.33 - 0.001j, 60.0)])
def test_sampled_mean_cosine_reproduces_mie_g(m, x):
    """Forward-peaked Mie: 1e6 samples through the kernel rule give g within 3 SE and 1e-3."""
    g = mie.efficiencies(m, x).g
    assert g > 0.85  # the case really is strongly forward peaked
    table = PhaseTable.from_mie(m, x)
    n = 1_000_000
    mu = table.sample(np.random.default_rng(20261122).random(n))
    se = mu.std(ddof=1) / np.sqrt(n)
    assert abs(mu.mean() - g) < 3 * se
    assert abs(mu.mean() - g) < 1e-3
    assert abs(table.mean_cosine() - g) < 1e-4  # the table's own bias is far below the SE


def test_table_resolves_forward_peak_at_large_x():
    # diffraction: half of the scattered light lies within a few 1/x of the forward direction;
    # the table must put nodes there, not a single interval from 0.99 to 1
    table = PhaseTable.from_mie(1.33, 1000.0, K=4096)
    theta_last = np.arccos(table.cos_table[-2])
    assert theta_last < 1.0 / 1000.0
    assert np.all(np.diff(table.cos_table) >= 0)


def test_invalid_tables_are_refused():
    with pytest.raises(ValueError):
        PhaseTable(np.array([-1.0, 0.5, 0.2, 1.0]))
    with pytest.raises(ValueError):
        PhaseTable(np.array([-0.9, 1.0]))
    with pytest.raises(ValueError, match="-1 < g < 1"):
        PhaseTable.from_hg(1.0)
    with pytest.raises(ValueError, match=">= 0"):
        PhaseTable.from_tabulated([-1.0, 0.0, 1.0], [1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        PhaseTable.from_hg(0.5).sample([1.5])
