"""QUALITY B cells for the fiber layer: every route finite and bounded, or a clear error -- never a NaN or a hang."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from simulate.fiber import Fiber, normal_albedo, range_outputs, surface_brdf, volume_brdf
from simulate.media.medium import HGMedium, MieMedium
from simulate.montecarlo import ParameterError
from simulate.optics.fresnel import OpticsDomainWarning


def _finite_bounded(est, albedo_bound=True):
    assert np.all(np.isfinite(est.R)) and np.all(np.isfinite(est.u_R))
    assert np.all(est.R >= 0) and np.all(est.u_R >= 0)


def _fiber(mu_s, mu_a, g=0.7, radius=5.0, n=1.557):
    return Fiber(radius_um=radius, n_host=n, medium=HGMedium(mu_s=mu_s, mu_a=mu_a, g=g), roughness=0.3)


W_IN = np.array([[0.0, 0.0, 1.0], [0.2, 0.5, -math.sqrt(0.71)]])
W_OUT = np.array([[0.0, 0.0, 1.0], [0.3, -0.2, math.sqrt(0.87)]])


@pytest.mark.parametrize("mu_s_r", [1e-3, 1e3])
@pytest.mark.parametrize("method", ["nee", "beam"])
def test_optical_radius_extremes(mu_s_r, method):
    fiber = _fiber(mu_s_r / 5.0, 1e-3 * mu_s_r / 5.0)
    out = range_outputs([0.8, 0.5], [1.0, 0.8], [-math.pi, -1.0], [math.pi, 1.0], fiber.half_width)
    # optically thick: next-event scores each of a photon's ~1e3 scattering events (14x the beam route's
    # cost per photon), so it walks 4000 photons, the beam route 20000
    thick = 4_000 if method == "nee" else 20_000
    est = volume_brdf(fiber, W_IN, None, [500.0], method=method, outputs=out, target_rel_err=0.2,
                      max_photons=thick if mu_s_r > 1 else 200_000, seed=1)
    _finite_bounded(est)


@pytest.mark.parametrize("albedo", [1.0, 1e-6])
def test_albedo_extremes(albedo):
    fiber = _fiber(2.0 * albedo, 2.0 * (1 - albedo))
    est = volume_brdf(fiber, W_IN, W_OUT, [500.0], target_rel_err=0.2, max_photons=100_000, seed=2)
    _finite_bounded(est)
    rho, u = normal_albedo(fiber, [500.0], target_rel_err=0.1, seed=3)
    assert np.all(np.isfinite(rho)) and 0.0 <= rho[0] <= 1.0


@pytest.mark.parametrize("theta_deg", [80.0, 89.0, 89.99])
def test_grazing_directions(theta_deg):
    t = math.radians(theta_deg)
    w = np.array([[math.sin(t), 0.0, math.cos(t)], [0.0, math.sin(t), math.cos(t)]])
    fiber = _fiber(1.0, 0.05)
    # 10000 photons per direction: the target is never reached at 89.99 deg (the exit's Fresnel transmittance
    # is ~1e-3; its ~1000 internal reflections are drawn at once, so a photon costs about what one at 80 deg does)
    est = volume_brdf(fiber, w, w[::-1], [500.0], target_rel_err=0.2, max_photons=10_000, seed=4)
    _finite_bounded(est)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)
        surf = surface_brdf(fiber, w, w[::-1])
    assert np.all(np.isfinite(surf)) and np.all(surf >= 0)


def test_exactly_grazing_exit_is_a_clear_error():
    fiber = _fiber(1.0, 0.05)
    with pytest.raises(ParameterError, match="w_out"):
        volume_brdf(fiber, W_IN[:1], np.array([[1.0, 0.0, 0.0]]), [500.0], target_rel_err=0.2)


def test_particles_without_index_contrast_scatter_nothing_and_say_so():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        medium = MieMedium(n_host=1.557, particle_n=1.557, radius_um=0.3, volume_fraction=0.05)
        fiber = Fiber(radius_um=5.0, n_host=1.557, medium=medium, roughness=0.3)
        est = volume_brdf(fiber, W_IN, W_OUT, [500.0], target_rel_err=0.2, max_photons=20_000, seed=5)
    assert any("scatter nothing" in str(w.message) for w in caught)
    # no scatterers: nothing for the next-event route to score at point directions (the bare
    # cylinder's light is a delta on a cone, see simulate.fiber)
    assert np.all(est.R == 0.0) and np.all(np.isfinite(est.u_R))


@pytest.mark.parametrize("field, value", [("radius_um", 0.0), ("n_host", float("nan")), ("roughness", -1.0),
                                          ("cell_width_deg", 400.0)])
def test_bad_fiber_fields_are_named(field, value):
    args = dict(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=1.0, mu_a=0.1, g=0.5), roughness=0.3)
    args[field] = value
    with pytest.raises(ParameterError, match=field):
        Fiber(**args)


@pytest.mark.parametrize("profile, depth", [("skin", 1.0), ("ring", 5.0), ("core", 0.0), ("ring", True)])
def test_a_bad_dye_profile_is_named(profile, depth):
    args = dict(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=1.0, mu_a=0.1, g=0.5), roughness=0.3)
    with pytest.raises(ParameterError, match="dye_"):
        Fiber(**args, dye_profile=profile, dye_depth_um=depth)


def test_a_dye_profile_is_refused_by_the_next_event_route():
    """The next-event vertex estimators attenuate towards the exit with a uniform dye: a ring is refused, named."""
    fiber = Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=1.0, mu_a=0.1, g=0.5), roughness=0.3,
                  dye_profile="ring", dye_depth_um=1.0)
    with pytest.raises(ParameterError, match="dye profile"):
        volume_brdf(fiber, W_IN, W_OUT, [500.0], target_rel_err=0.2, max_photons=2_000, seed=5)


@pytest.mark.parametrize("f_out", [0.9, 0.999])
def test_the_reflection_order_follows_the_geometric_law_below_and_above_the_switch(f_out):
    """The next-event estimator's number of internal reflections before an exit, P(k) = (1 - F) F^k: one draw
    per reflection up to F = 0.95, one draw by the inverse CDF above it (near-grazing exits, 1000 reflections
    expected at 89.99 deg). Both give the law: its mean F / (1 - F) and its tail P(k >= m) = F^m within 4 SE."""
    from simulate.montecarlo import tallies as T
    from simulate.montecarlo.rng import seed_state

    assert (f_out > T._LOOP_F) == (f_out > 0.95)
    n = 20_000
    s = tuple(np.uint64(v) for v in seed_state(11, 0))
    k = np.empty(n)
    for i in range(n):
        k[i], *rest = T.reflection_order(f_out, *s)
        s = tuple(np.uint64(v) for v in rest)
    mean = f_out / (1.0 - f_out)
    assert abs(k.mean() - mean) < 4.0 * math.sqrt(f_out / (1.0 - f_out) ** 2 / n)
    for m in (1, int(mean), int(3 * mean)):
        p = f_out ** m
        assert abs(np.mean(k >= m) - p) < 4.0 * math.sqrt(p * (1.0 - p) / n), m


def test_the_exit_point_turned_by_k_reflections_at_once_is_the_one_turned_k_times():
    from simulate.montecarlo import tallies as T

    step = 2.3
    ny, nz = -math.sin(0.4), math.cos(0.4)
    for k in (0, 1, 7, 1000):
        once = T.turned(ny, nz, math.cos(step), math.sin(step), k, 0.999)
        each = T.turned(ny, nz, math.cos(step), math.sin(step), k, 0.5)
        np.testing.assert_allclose(once, each, atol=1e-10)
        np.testing.assert_allclose(once, (-math.sin(0.4 + k * step), math.cos(0.4 + k * step)), atol=1e-10)
