"""MieMedium / HGMedium: docs/physics.md section 2 equations, units and flags."""

import warnings

import numpy as np
import pytest

from simulate.media.medium import HGMedium, LogNormalSize, MieMedium, Spectrum
from simulate.optics.fresnel import OpticsDomainWarning

BH_X = 5.21282
BH_QSCA = 3.10543


def _bh_radius_um(wavelength_nm, n_host):
    return BH_X * wavelength_nm / 1000.0 / (2 * np.pi * n_host)


@pytest.mark.parametrize("n_host", [1.0, 1.557])
def test_scattering_coefficient_from_bohren_huffman(n_host):
    lam = 600.0
    r = _bh_radius_um(lam, n_host)
    N = 0.02  # per um^3
    med = MieMedium(n_host=n_host, particle_n=1.55 * n_host, radius_um=r, number_density_per_um3=N,
                    mu_a_host_per_um=1e-3)
    op = med.optical_properties(lam)
    assert op.mu_s == pytest.approx(N * BH_QSCA * np.pi * r * r, rel=5e-6)
    assert op.mu_a == 1e-3  # non-absorbing spheres: only the host absorbs
    assert op.mu_t == pytest.approx(op.mu_s + 1e-3, rel=1e-15)
    assert op.albedo == pytest.approx(op.mu_s / op.mu_t, rel=1e-15)
    assert op.g == pytest.approx(0.63314, abs=1e-5)
    assert op.x == pytest.approx(BH_X, rel=1e-12)
    assert abs(op.phase.mean_cosine() - op.g) < 1e-4


def test_volume_fraction_and_number_density_agree():
    r, fv = 0.2, 0.01
    a = MieMedium(n_host=1.557, particle_n=2.7, radius_um=r, volume_fraction=fv)
    N = fv / (4 / 3 * np.pi * r**3)
    b = MieMedium(n_host=1.557, particle_n=2.7, radius_um=r, number_density_per_um3=N)
    assert a.number_density == pytest.approx(N, rel=1e-15)
    assert a.optical_properties(500.0, with_phase=False).mu_s == pytest.approx(
        b.optical_properties(500.0, with_phase=False).mu_s, rel=1e-14)


def test_lognormal_volume_fraction_uses_third_moment():
    d = LogNormalSize(0.1, 1.4)
    med = MieMedium(n_host=1.5, particle_n=2.0, size_distribution=d, volume_fraction=0.05)
    s = np.log(1.4)
    mean_v = 4 / 3 * np.pi * 0.1**3 * np.exp(4.5 * s * s)
    assert med.number_density == pytest.approx(0.05 / mean_v, rel=1e-13)


def test_absorbing_particles_and_host_spectrum():
    n_h, lam, r, N = 1.557, 550.0, 0.1, 0.5
    k_spec = Spectrum(np.array([400.0, 700.0]), np.array([0.0, 0.3]), name="particle k")
    host = Spectrum(np.array([400.0, 700.0]), np.array([2e-3, 0.0]), name="host mu_a")
    med = MieMedium(n_host=n_h, particle_n=1.6, particle_k=k_spec, radius_um=r,
                    number_density_per_um3=N, mu_a_host_per_um=host)
    op = med.optical_properties(lam)
    from simulate.optics.mie import sphere_efficiencies  # reference: the wrapper's own pieces checked elsewhere
    e = sphere_efficiencies(1.6 - 0.15j, n_h, r, lam)  # k linearly interpolated: 0.15 at 550 nm
    assert op.mu_a == pytest.approx(N * (e.qext - e.qsca) * np.pi * r * r + 1e-3, rel=1e-12)
    assert op.mu_s == pytest.approx(N * e.qsca * np.pi * r * r, rel=1e-12)
    with pytest.warns(OpticsDomainWarning, match="outside the tabulated range"):
        med.optical_properties(800.0, with_phase=False)


def test_coefficient_spectrum_shape():
    med = MieMedium(n_host=1.557, particle_n=2.7, radius_um=0.15, volume_fraction=0.02)
    mu_s, mu_a, g = med.coefficients(np.array([400.0, 550.0, 700.0]))
    assert mu_s.shape == (3,) and np.all(mu_s > 0) and np.all(mu_a == 0) and np.all((g > 0) & (g < 1))


def test_albedo_one_and_near_zero():
    white = MieMedium(n_host=1.557, particle_n=2.7, radius_um=0.15, volume_fraction=0.02)
    assert white.optical_properties(550.0).albedo == 1.0
    black = MieMedium(n_host=1.557, particle_n=1.6, particle_k=2.0, radius_um=0.005,
                      volume_fraction=0.05, mu_a_host_per_um=10.0)
    op = black.optical_properties(550.0)
    assert 0 < op.albedo < 1e-3
    assert np.isfinite([op.mu_s, op.mu_a, op.g]).all()
    assert abs(op.phase.mean_cosine() - op.g) < 1e-4


def test_no_contrast_medium_is_transparent_and_flagged():
    med = MieMedium(n_host=1.557, particle_n=1.557, radius_um=0.3, volume_fraction=0.02)
    with pytest.warns(OpticsDomainWarning, match="scatter nothing"):
        op = med.optical_properties(550.0)
    assert (op.mu_s, op.mu_a, op.mu_t, op.albedo, op.g) == (0.0, 0.0, 0.0, 0.0, 0.0)
    assert np.all(np.isfinite(op.phase.cos_table))


def test_dense_packing_is_flagged():
    with pytest.warns(OpticsDomainWarning, match="independent"):
        MieMedium(n_host=1.5, particle_n=2.0, radius_um=0.1, volume_fraction=0.3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        MieMedium(n_host=1.5, particle_n=2.0, radius_um=0.1, volume_fraction=0.05)


def test_exactly_one_size_and_one_amount():
    with pytest.raises(ValueError, match="radius_um and size_distribution"):
        MieMedium(n_host=1.5, particle_n=2.0, volume_fraction=0.01)
    with pytest.raises(ValueError, match="number_density_per_um3 and volume_fraction"):
        MieMedium(n_host=1.5, particle_n=2.0, radius_um=0.1, volume_fraction=0.01, number_density_per_um3=1.0)
    with pytest.raises(ValueError, match="particle_k"):
        MieMedium(n_host=1.5, particle_n=2.0, particle_k=-0.1, radius_um=0.1, volume_fraction=0.01)


def test_hg_medium():
    op = HGMedium(mu_s=90.0, mu_a=10.0, g=0.75).optical_properties()
    assert op.mu_t == 100.0 and op.albedo == 0.9 and op.g == 0.75
    assert abs(op.phase.mean_cosine() - 0.75) < 1e-6
    assert HGMedium(mu_s=0.0, mu_a=0.0, g=0.0).optical_properties().albedo == 0.0
    with pytest.raises(ValueError):
        HGMedium(mu_s=1.0, mu_a=0.0, g=1.0)
