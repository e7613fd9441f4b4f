"""docs/quality.md section B for the fabric layer: every regime finite and bounded, or flagged.

Regimes x methods: grazing incidence and observation (80, 89, 89.99 deg; exactly 90 an error),
roughness 0.001 and 1, a non-absorbing and a nearly black fiber, for the woven Monte Carlo,
the summation and the classic model.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from simulate import fabric as fab
from simulate import fiber as F
from simulate import raytrace as W
from simulate.geometry import weave
from simulate.geometry.mesh import mesh as weave_mesh
from simulate.media.medium import HGMedium
from simulate.optics.microfacet import OpticsDomainWarning


def _d(theta, phi=0.0):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


@pytest.fixture(scope="module")
def mesh():
    return weave_mesh(weave.preset("plain", points_per_span=6, sides=12))


@pytest.fixture(scope="module")
def tables():
    out = {}
    for name, mu_a in (("white", 0.0), ("grey", 0.01), ("black", 50.0)):
        fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=mu_a, g=0.5), 0.3, 10.0)
        out[name] = W.yarn_table(fib, [550.0], photons_per_row=2000, seed=3)
    return out


@pytest.mark.parametrize("theta", [80.0, 89.0, 89.99])
def test_mc_grazing_is_finite_bounded_and_flagged(mesh, tables, theta):
    det = np.array([_d(0.0), _d(theta), _d(theta, 180.0)])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = W.trace(mesh, W.FiberSurface(tables["grey"], 0.35, 1.5), _d(theta, 10.0), det, target_rel_err=0.05,
                    max_rays=4096, seed=1, chunk=1024)
    flagged = any(issubclass(x.category, OpticsDomainWarning) and "85 deg" in str(x.message) for x in caught)
    assert flagged == (theta > 85.0)
    assert np.all(np.isfinite(r.beta)) and np.all(np.isfinite(r.u_beta)) and np.all(r.beta >= 0)
    assert 0.0 <= r.reflected[0] + r.transmitted[0] <= 1.0 + 4 * r.info["u_reflected_plus_transmitted"][0]
    assert r.info["lost_rays"] <= 0.01 * r.rays


def test_mc_exactly_grazing_is_an_error(mesh, tables):
    with pytest.raises(ValueError, match="above the fabric"):
        W.trace(mesh, W.FiberSurface(tables["grey"], 0.35, 1.5), _d(90.0), np.array([_d(0.0)]))
    with pytest.raises(ValueError, match="above the fabric"):
        W.trace(mesh, W.FiberSurface(tables["grey"], 0.35, 1.5), _d(30.0), np.array([_d(90.0)]))


@pytest.mark.parametrize("m", [0.001, 1.0])
def test_mc_roughness_extremes(mesh, tables, m):
    r = W.trace(mesh, W.FiberSurface(tables["grey"], m, 1.5), _d(30.0), np.array([_d(0.0), _d(30.0, 180.0)]),
                target_rel_err=0.05, max_rays=4096, seed=2, chunk=1024)
    assert np.all(np.isfinite(r.beta)) and np.all(r.beta > 0)
    assert r.reflected[0] + r.transmitted[0] <= 1.05


@pytest.mark.parametrize("name", ["white", "black"])
def test_mc_albedo_extremes(mesh, tables, name):
    r = W.trace(mesh, W.FiberSurface(tables[name], 0.35, 1.5), _d(20.0), np.array([_d(0.0), _d(45.0)]),
                target_rel_err=0.05, max_rays=4096, seed=3, chunk=1024)
    assert np.all(np.isfinite(r.beta)) and np.all(r.beta > 0)
    total = r.reflected[0] + r.transmitted[0]
    if name == "white":
        assert total > 0.9
    else:
        # a black volume leaves the surface reflection (a few per cent) and the gaps' transmission
        assert total < 0.3 and r.reflected[0] < 0.15


@pytest.mark.parametrize("theta", [80.0, 89.0, 89.99])
def test_summation_and_classic_grazing_finite_and_flagged(theta):
    w_i = np.atleast_2d(_d(theta))
    w_o = np.atleast_2d(_d(30.0, 180.0))
    lambert = lambda a, b: np.clip(a[:, 2:3], 0, None) * 0.5 / np.pi  # noqa: E731 - a Lambertian R_B

    beta = fab.summation_beta(lambert, w_i, w_o)
    assert np.all(np.isfinite(beta)) and np.all(beta >= 0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        c = fab.classic_beta(np.array([0.4]), w_i, w_o, 0.35, 1.5)
    assert np.all(np.isfinite(c)) and np.all(c >= 0)
    # Cook-Torrance flags directions beyond 85 deg (its 1/cos is unbounded towards the horizon)
    assert any(issubclass(x.category, OpticsDomainWarning) for x in caught) == (theta > 85.0)
