"""QUALITY B cells for the kernel: finite, bounded, flagged -- never NaN or a hang."""

from __future__ import annotations

import logging
import math

import pytest

from simulate.montecarlo import ParameterError, run_cylinder, run_slab


def _bounded(r):
    values = [r.Rd, r.Tt, r.u_Rd, r.u_Tt, r.absorbed, r.Rsp]
    assert all(math.isfinite(v) for v in values)
    assert 0.0 <= r.Rd <= 1.0 and 0.0 <= r.Tt <= 1.0 and 0.0 <= r.Rsp <= 1.0
    assert r.Rd + r.Tt + r.absorbed + r.Rsp <= 1.0 + 10 * (r.u_Rd + r.u_Tt) + 1e-9
    assert abs(r.energy.residual) < 1e-9


@pytest.mark.parametrize("albedo", [1.0, 1e-6])
def test_albedo_extremes(albedo):
    mu_t = 50.0
    r = run_slab(mu_t * (1 - albedo), mu_t * albedo, g=0.5, n=1.33, thickness=0.1, photons=20_000, seed=1)
    _bounded(r)
    if albedo == 1.0:
        assert r.absorbed == 0.0 and r.Rd + r.Tt == pytest.approx(r.energy.entered, rel=1e-12)
    else:
        # essentially no scattering: transmittance of the bare absorbing slab
        f = ((1.33 - 1) / (1.33 + 1)) ** 2
        a = math.exp(-mu_t * 0.1)
        assert r.Tt == pytest.approx((1 - f) ** 2 * a / (1 - f * f * a * a), abs=4 * r.u_Tt + 1e-6)


def test_optically_thin_slab():
    tau = 1e-3
    r = run_slab(0.1 * tau, 0.9 * tau, g=0.0, n=1.0, thickness=1.0, photons=50_000, seed=2)
    _bounded(r)
    assert r.Tu == pytest.approx(math.exp(-tau), abs=4 * math.sqrt(tau / 5e4))
    assert r.events_per_photon < 1.01 and r.capped == 0


def test_optically_huge_slab_finishes_and_reports_the_cap(caplog):
    # finishing at all is the check (pytest-timeout guards a hang); its duration is a benchmark
    r = run_slab(0.0, 1e3, g=0.0, n=1.5, thickness=1.0, photons=2_000, seed=3)  # default cap
    _bounded(r)
    with caplog.at_level(logging.WARNING, logger="simulate.montecarlo.transport"):
        capped = run_slab(0.0, 1e3, g=0.0, n=1.5, thickness=1.0, photons=2_000, seed=3, max_events=200)
    assert capped.capped > 0 and capped.energy.capped_weight > 0
    assert capped.as_dict()["capped"] == capped.capped
    assert abs(capped.energy.residual) < 1e-9  # capped weight is accounted for
    assert "event cap" in caplog.text
    assert capped.Rd + capped.Tt + capped.energy.capped_weight == pytest.approx(capped.energy.entered, rel=1e-9)


@pytest.mark.parametrize("mu_s_r", [1e-3, 1e3])
def test_cylinder_optical_radius_extremes(mu_s_r):
    r = run_cylinder(0.01 * mu_s_r, mu_s_r, g=0.8, n=1.557, radius=1.0, photons=5_000, seed=4)
    assert all(math.isfinite(v) for v in (r.exited, r.u_exited, r.absorbed, r.specular))
    assert 0.0 <= r.exited <= 1.0 and abs(r.energy.residual) < 1e-9
    r2 = run_cylinder(0.0, mu_s_r, g=0.8, n=1.557, radius=1.0, photons=5_000, seed=4, max_events=50)
    if mu_s_r >= 1e3:
        assert r2.capped > 0
    assert r2.exited + r2.energy.capped_weight == pytest.approx(r2.energy.entered, rel=1e-9)


@pytest.mark.parametrize("theta", [80.0, 89.0, 89.99])
def test_grazing_incidence(theta, fresnel_ref):
    r = run_slab(1.0, 20.0, g=0.7, n=1.5, thickness=0.1, photons=20_000, seed=6, theta_i_deg=theta)
    _bounded(r)
    f = float(fresnel_ref(math.cos(math.radians(theta)), 1.0, 1.5))
    assert r.Rsp == pytest.approx(f, rel=1e-9)  # Fresnel reflectance towards 1 at grazing incidence
    assert r.energy.entered == pytest.approx(1.0 - f, rel=1e-9)
    assert r.Rd + r.Tt <= r.energy.entered + 10 * (r.u_Rd + r.u_Tt)


def test_exactly_grazing_is_a_clear_error():
    with pytest.raises(ParameterError, match="theta_i_deg = 90"):
        run_slab(1.0, 20.0, g=0.7, n=1.5, thickness=0.1, photons=10, theta_i_deg=90.0)
    with pytest.raises(ParameterError, match="grazing"):
        run_cylinder(1.0, 20.0, n=1.5, photons=10, source="point", direction=(0.0, 1.0, 0.0))
    with pytest.raises(ParameterError, match="parallel to the cylinder axis"):
        run_cylinder(1.0, 20.0, n=1.5, photons=10, direction=(1.0, 0.0, 0.0))


def test_no_index_contrast():
    r = run_slab(2.0, 0.0, n=1.0, thickness=0.5, photons=20_000, seed=7, theta_i_deg=60.0)
    assert r.Rsp == 0.0 and r.Rd == 0.0
    assert r.Tt == pytest.approx(math.exp(-2.0 * 0.5 / 0.5), abs=4 * r.u_Tt)
    c = run_cylinder(0.0, 5.0, g=0.0, n=1.0, radius=1.0, photons=20_000, seed=7)
    assert c.specular == 0.0 and c.exited == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(mu_a=-1.0), "mu_a"),
        (dict(mu_s=float("nan")), "mu_s"),
        (dict(g=1.0), "g"),
        (dict(n=0.0), "n"),
        (dict(thickness=0.0), "thickness"),
        (dict(photons=0), "photons"),
        (dict(seed=-1), "seed"),
        (dict(theta_i_deg=-5.0), "theta_i_deg"),
        (dict(g=0.5, phase_table=[-1.0, 1.0]), "either g"),
        (dict(phase_table=[1.0, -1.0]), "phase_table"),
        (dict(threads=99), "threads"),
    ],
)
def test_invalid_parameters_are_named(kwargs, name):
    base = dict(mu_a=1.0, mu_s=1.0, thickness=1.0, photons=10)
    with pytest.raises(ParameterError, match=name):
        run_slab(**(base | kwargs))
