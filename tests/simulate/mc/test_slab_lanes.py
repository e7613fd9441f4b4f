"""The plain slab's two-lane loop (:mod:`simulate.montecarlo.slab_lanes`) against the kernel's loop.

A slab run without tallies goes through the two-lane loop; the same run with angular bins goes
through the general (scoring) kernel, one photon at a time. The two draw different photons, so
their estimates must agree within their standard errors -- for every feature of the plain path:
Fresnel entry at oblique incidence, internal reflection, the table phase function, Russian
roulette and the event cap -- and each must keep its exact energy balance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.montecarlo import run_slab

CASES = {
    "van de Hulst": dict(mu_a=10.0, mu_s=90.0, g=0.75, n=1.0, thickness=0.02),
    "index 1.5, 40 degrees": dict(mu_a=1.0, mu_s=20.0, g=0.5, n=1.5, thickness=0.1, theta_i_deg=40.0),
    "roulette": dict(mu_a=2.0, mu_s=18.0, g=0.3, n=1.33, thickness=0.2, weight_threshold=0.05, survival=0.5),
    "event cap": dict(mu_a=0.5, mu_s=30.0, g=0.0, n=1.0, thickness=0.2, max_events=4),
}


def _z(a: float, ua: float, b: float, ub: float) -> float:
    return (a - b) / math.hypot(ua, ub)


@pytest.mark.parametrize("name", list(CASES))
def test_two_lanes_agree_with_the_kernel_within_errors(name):
    kw = CASES[name]
    lanes = run_slab(photons=200_000, seed=11, **kw)
    kernel = run_slab(photons=200_000, seed=12, angular_bins=(1, 1), **kw)
    assert abs(_z(lanes.Rd, lanes.u_Rd, kernel.Rd, kernel.u_Rd)) < 4.5, (lanes.Rd, kernel.Rd)
    assert abs(_z(lanes.Tt, lanes.u_Tt, kernel.Tt, kernel.u_Tt)) < 4.5, (lanes.Tt, kernel.Tt)
    # unscattered transmission: a binomial fraction of the entered weight
    w_in = lanes.energy.entered
    u_tu = math.sqrt(max(kernel.Tu * (w_in - kernel.Tu), 1e-12) / 200_000) * math.sqrt(2)
    assert abs(lanes.Tu - kernel.Tu) < 4.5 * u_tu
    assert lanes.Rsp == pytest.approx(kernel.Rsp, rel=1e-12)
    assert lanes.energy.entered == pytest.approx(kernel.energy.entered, rel=1e-12)
    for r in (lanes, kernel):
        assert r.photons == r.energy.launched == 200_000
        assert abs(r.energy.residual) < 1e-12
    if kw.get("weight_threshold"):
        assert lanes.energy.roulette_killed > 0 and lanes.energy.roulette_gain > 0
        assert abs(lanes.energy.roulette_balance) < 4.5 * lanes.energy.u_roulette_balance
    if kw.get("max_events"):
        p_lanes, p_kernel = lanes.capped / 200_000, kernel.capped / 200_000
        assert 0.05 < p_kernel < 0.95
        assert abs(p_lanes - p_kernel) < 4.5 * math.sqrt(2 * p_kernel * (1 - p_kernel) / 200_000)
        assert lanes.energy.capped_weight == pytest.approx(kernel.energy.capped_weight, rel=0.05)
    if kw.get("n", 1.0) != 1.0:
        assert lanes.energy.as_dict()["exited"] > 0 and lanes.events_per_photon == pytest.approx(
            kernel.events_per_photon, rel=0.02)


def test_table_phase_function_in_two_lanes():
    # an inverse-CDF table of the isotropic phase function against g = 0 in the kernel
    table = np.linspace(-1.0, 1.0, 257)
    kw = dict(mu_a=1.0, mu_s=9.0, n=1.2, thickness=0.3)
    lanes = run_slab(phase_table=table, photons=200_000, seed=3, **kw)
    kernel = run_slab(g=0.0, photons=200_000, seed=4, angular_bins=(1, 1), **kw)
    assert abs(_z(lanes.Rd, lanes.u_Rd, kernel.Rd, kernel.u_Rd)) < 4.5
    assert abs(_z(lanes.Tt, lanes.u_Tt, kernel.Tt, kernel.u_Tt)) < 4.5


@pytest.mark.parametrize("photons", [1, 2, 3, 10_001])
def test_every_photon_is_launched_once_and_threads_do_not_matter(photons):
    kw = dict(mu_a=1.0, mu_s=9.0, g=0.8, n=1.4, thickness=0.5, photons=photons, seed=5, batch_size=4_000)
    one = run_slab(threads=1, **kw)
    two = run_slab(threads=2, **kw)
    assert one.energy.launched == photons
    assert abs(one.energy.residual) < 1e-12
    assert one.as_dict() | {"seconds": 0} == two.as_dict() | {"seconds": 0}
