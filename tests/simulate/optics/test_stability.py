"""docs/quality.md section B cells of the optics layer: finite, bounded, flagged outside the domain."""

import warnings

import numpy as np
import pytest

from simulate.media.medium import MieMedium
from simulate.optics import fresnel, mie
from simulate.optics import microfacet as mf
from simulate.optics.fresnel import OpticsDomainWarning, fresnel_unpolarized, refracted_cos
from simulate.optics.phase import PhaseTable

GRAZING_DEG = [80.0, 89.0, 89.99, 90.0]
N_HOST = 1.557


@pytest.mark.parametrize("angle_deg", GRAZING_DEG)
@pytest.mark.parametrize("n1,n2", [(1.0, N_HOST), (N_HOST, 1.0), (1.5, 1.5)])
def test_fresnel_grazing(angle_deg, n1, n2):
    th = np.radians(angle_deg)
    for r in (fresnel.reflectance(th, n1, n2), fresnel.reflectance_s(th, n1, n2), fresnel.reflectance_p(th, n1, n2),
              fresnel_unpolarized(np.cos(th), n1, n2)):
        assert np.isfinite(r) and 0.0 <= r <= 1.0
    assert -1.0 <= refracted_cos(np.cos(th), n1, n2) <= 1.0
    if angle_deg == 90.0 and n1 != n2:
        assert float(fresnel.reflectance(th, n1, n2)) == 1.0


def _no_warning(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error", OpticsDomainWarning)
        return fn(*args, **kw)


@pytest.mark.parametrize("m", [0.001, 0.3, 1.0])
@pytest.mark.parametrize("angle_deg", GRAZING_DEG)
def test_cook_torrance_grazing_and_roughness_extremes(m, angle_deg):
    th = np.radians(angle_deg)
    phi_o = np.array([0.0, np.pi / 2, np.pi])  # back-scatter, side, mirror azimuth
    cases = [(th, 0.0, np.radians(30.0), phi_o), (np.radians(30.0), 0.0, th, phi_o), (th, 0.0, th, phi_o)]
    flagged = angle_deg > mf.GRAZING_LIMIT_DEG or m > mf.MAX_RMS_SLOPE
    for args in cases:
        if flagged:
            with pytest.warns(OpticsDomainWarning):
                f = mf.cook_torrance_angles(*args, m, N_HOST)
        else:
            f = _no_warning(mf.cook_torrance_angles, *args, m, N_HOST)
        assert np.all(np.isfinite(f)) and np.all(f >= 0)
        if angle_deg == 90.0:
            np.testing.assert_array_equal(f, 0.0)  # the horizon sees no projected area
    # R_surf = f cos_i stays finite and below the mirror bound D(n)/(4 cos_o) at the mirror peak
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)
        a = mf.directional_albedo(th, m, N_HOST)
    assert np.isfinite(a) and 0.0 <= a <= 1.0


def test_rough_surface_flagged_smooth_not():
    with pytest.warns(OpticsDomainWarning, match="RMS slope"):
        mf.beckmann_d(0.9, 1.0)
    _no_warning(mf.beckmann_d, 0.9, 0.001)
    _no_warning(mf.directional_albedo, np.radians(80.0), 0.001, N_HOST)
    d = mf.beckmann_d(np.array([1.0, 0.999999, 0.5, 1e-9, 0.0, -0.5]), 0.001)
    assert np.all(np.isfinite(d)) and d[0] == pytest.approx(1 / (np.pi * 1e-6)) and np.all(d[2:] == 0)
    with pytest.raises(ValueError, match="RMS slope"):
        mf.beckmann_d(1.0, 0.0)


@pytest.mark.parametrize("x", [1e-3, 1e3])
@pytest.mark.parametrize("m", [1.55, 1.33 - 0.01j, 1.0 + 1e-9])
def test_mie_size_parameter_extremes(x, m):
    # finite and bounded is the check; how long x = 1e3 takes is a benchmark, not a test
    e = mie.efficiencies(m, x)
    table = PhaseTable.from_mie(m, x)
    assert np.isfinite([e.qext, e.qsca, e.qabs, e.qback, e.g]).all()
    assert 0 <= e.qsca <= e.qext + 1e-15 and -1 < e.g < 1
    assert np.all(np.isfinite(table.cos_table))
    assert table.quadrature_norm == pytest.approx(1.0, abs=1e-4)
    if e.qsca > 0:
        assert abs(table.mean_cosine() - e.g) < 1e-4


def test_mie_underflowing_scattering_uses_rayleigh_phase():
    p = mie.phase_function(1.5, 1e-90, np.array([-1.0, 0.0, 1.0]))
    np.testing.assert_allclose(p, 3 * (1 + np.array([1.0, 0.0, 1.0])) / (16 * np.pi))


@pytest.mark.parametrize("x", [1e-3, 1e3])
def test_mie_no_contrast(x):
    e = mie.efficiencies(1.0, x)
    assert (e.qext, e.qsca, e.g) == (0.0, 0.0, 0.0)
    with pytest.warns(OpticsDomainWarning):
        p = mie.phase_function(1.0, x, np.linspace(-1, 1, 11))
    assert np.all(np.isfinite(p)) and np.all(p >= 0)


@pytest.mark.parametrize("k,host", [(0.0, 0.0), (3.0, 100.0)])
def test_media_albedo_one_and_near_zero(k, host):
    med = MieMedium(n_host=N_HOST, particle_n=2.0, particle_k=k, radius_um=0.01, volume_fraction=0.01,
                    mu_a_host_per_um=host)
    op = _no_warning(med.optical_properties, 550.0)
    assert np.isfinite([op.mu_s, op.mu_a, op.mu_t, op.g, op.albedo]).all()
    assert 0.0 <= op.albedo <= 1.0
    if k == 0.0:
        assert op.albedo == 1.0
    else:
        assert op.albedo < 1e-4
