"""Slab validation: van de Hulst reference, bookkeeping, geometric optics, convergence."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.montecarlo import run_slab
from simulate.optics.phase import PhaseTable

RD_REF = 0.09739
TT_REF = 0.66096


def test_van_de_hulst_reference(van_de_hulst):
    r = run_slab(photons=1_000_000, seed=12345, **van_de_hulst)
    assert abs(r.Rd - RD_REF) < 3 * r.u_Rd
    assert abs(r.Tt - TT_REF) < 3 * r.u_Tt
    # the standard errors are those of 1e6 Bernoulli-like scores, not vanishing or inflated
    assert 1e-4 < r.u_Rd < 5e-4 and 1e-4 < r.u_Tt < 6e-4
    # unscattered transmittance exp(-mu_t d) is part of Tt
    assert r.Tu == pytest.approx(math.exp(-2.0), abs=4 * math.sqrt(math.exp(-2) * (1 - math.exp(-2)) / 1e6))
    assert r.Rsp == 0.0 and r.capped == 0


def test_phase_table_matches_hg(van_de_hulst):
    """Sampling the inverse-CDF table of HG gives the analytic-HG answer (independent streams)."""
    table = PhaseTable.from_hg(0.75, 4096)
    case = {k: v for k, v in van_de_hulst.items() if k != "g"}
    r = run_slab(phase_table=table, photons=400_000, seed=7, **case)
    assert abs(r.Rd - RD_REF) < 3.5 * r.u_Rd
    assert abs(r.Tt - TT_REF) < 3.5 * r.u_Tt


@pytest.mark.parametrize("n", [1.0, 1.4])
def test_energy_bookkeeping(n):
    r = run_slab(5.0, 50.0, g=0.9, n=n, thickness=0.1, photons=100_000, seed=3, weight_threshold=0.05)
    e = r.energy
    assert e.specular + e.entered == pytest.approx(1.0, abs=1e-12)
    assert abs(e.residual) < 1e-10  # exact identity per photon
    assert e.roulette_gain > 0 and e.roulette_killed > 0  # roulette really ran
    # roulette is zero in expectation: its balance (tallied per photon) within 4 of its own
    # standard errors, and that standard error is not degenerate
    assert e.u_roulette_balance > 0
    assert abs(e.roulette_balance) < 4 * e.u_roulette_balance
    assert e.exited == pytest.approx(r.Rd + r.Tt, abs=1e-12)


def test_no_absorption_everything_exits():
    r = run_slab(0.0, 200.0, g=0.8, n=1.5, thickness=0.05, photons=50_000, seed=11)
    assert r.absorbed == 0.0 and r.energy.roulette_killed == 0.0 and r.capped == 0
    assert r.Rd + r.Tt == pytest.approx(r.energy.entered, rel=1e-12)
    assert r.energy.entered == pytest.approx(1.0 - 0.04, abs=1e-12)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
@pytest.mark.parametrize("mu_a", [0.0, 8.0])
def test_bare_slab_geometric_optics(theta_deg, mu_a, fresnel_ref):
    """No scatterers: Fresnel-weighted multiple internal reflections (analytic series)."""
    n, d = 1.5, 0.1
    r = run_slab(mu_a, 0.0, n=n, thickness=d, photons=200_000, seed=5, theta_i_deg=theta_deg, angular_bins=(20, 6))
    ci = math.cos(math.radians(theta_deg))
    f = float(fresnel_ref(ci, 1.0, n))
    ct = math.sqrt(1.0 - (math.sin(math.radians(theta_deg)) / n) ** 2)
    a = math.exp(-mu_a * d / ct)
    denom = 1.0 - f * f * a * a
    r_ref = (1 - f) ** 2 * f * a * a / denom
    t_ref = (1 - f) ** 2 * a / denom
    assert r.Rsp == pytest.approx(f, rel=1e-12)
    assert abs(r.Rd - r_ref) < 4 * r.u_Rd + 1e-12
    assert abs(r.Tt - t_ref) < 4 * r.u_Tt + 1e-12
    # exit directions: the mirror direction on top, the incident direction below
    ang = r.angular
    # the bin of mu = cos(theta_i); at 60 deg mu = 0.5 lies ON a bin edge, where the last bit of
    # rounding (compiled with or without fused multiply-adds) decides the side: take both then
    bins = sorted({min(int((ci - 1e-9) * 20), 19), min(int((ci + 1e-9) * 20), 19)})
    refl_mu = ang.reflected.sum(axis=1)
    tran_mu = ang.transmitted.sum(axis=1)
    assert refl_mu[bins].sum() == pytest.approx(r.Rd, rel=1e-12)
    assert tran_mu[bins].sum() == pytest.approx(r.Tt, rel=1e-12)
    if theta_deg > 0:
        # travelling towards -x: azimuth pi (first or last azimuth bin)
        edge = ang.reflected[:, 0].sum() + ang.reflected[:, -1].sum()
        assert edge == pytest.approx(r.Rd, rel=1e-12)


def test_angular_bins_sum_to_totals_and_lambertian_shape():
    """Thick scattering slab, n = 1: diffuse reflectance is close to Lambertian (dR/dmu ~ mu)."""
    r = run_slab(0.0, 100.0, g=0.0, n=1.0, thickness=1.0, photons=100_000, seed=9, angular_bins=(10, 4))
    ang = r.angular
    assert ang.reflected.sum() == pytest.approx(r.Rd, rel=1e-12)
    assert ang.transmitted.sum() == pytest.approx(r.Tt, rel=1e-12)
    # azimuthal symmetry at normal incidence
    per_phi = ang.reflected.sum(axis=0)
    u_phi = np.sqrt((ang.u_reflected**2).sum(axis=0))
    assert np.all(np.abs(per_phi - per_phi.mean()) < 4 * u_phi)
    # radiance ~ constant: weight per mu bin grows with mu (Chandrasekhar H-function shape)
    per_mu = ang.reflected.sum(axis=1)
    assert np.all(np.diff(per_mu) > 0)


def test_standard_error_falls_as_inverse_sqrt_n(van_de_hulst):
    """Empirical scatter over 16 seeds vs N: fitted log-log slope -0.5 +- 0.1."""
    counts = np.array([1_000, 3_000, 10_000, 30_000, 100_000, 300_000])
    spread, computed = [], []
    for count in counts:
        rds = []
        for seed in range(16):
            r = run_slab(photons=int(count), seed=1000 + seed, **van_de_hulst)
            rds.append(r.Rd)
        spread.append(np.std(rds, ddof=1))
        computed.append(r.u_Rd)
    slope = np.polyfit(np.log(counts), np.log(spread), 1)[0]
    assert -0.6 <= slope <= -0.4
    slope_computed = np.polyfit(np.log(counts), np.log(computed), 1)[0]
    assert -0.6 <= slope_computed <= -0.4
    # the computed standard error is the observed scatter
    ratio = np.array(computed) / np.array(spread)
    assert np.all((ratio > 0.55) & (ratio < 1.8))


@pytest.mark.parametrize(
    "n, ur1, ut1",
    # adding-doubling (iadpython 0.5.3, quad_pts=32; values change by <= 2e-4 between 16, 32
    # and 64 quadrature points): total reflectance UR1 (includes the specular part) and total
    # transmittance UT1 of the van de Hulst layer with an index-mismatched boundary
    [(1.4, 0.116216, 0.527044), (1.5, 0.126827, 0.493165)],
)
def test_index_mismatch_matches_adding_doubling(n, ur1, ut1, van_de_hulst):
    r = run_slab(photons=1_000_000, seed=2024, **(van_de_hulst | {"n": n}))
    assert abs(r.Rd + r.Rsp - ur1) < 3 * r.u_Rd + 3e-4
    assert abs(r.Tt - ut1) < 3 * r.u_Tt + 3e-4
    assert r.Rsp == pytest.approx(((n - 1) / (n + 1)) ** 2, rel=1e-9)
