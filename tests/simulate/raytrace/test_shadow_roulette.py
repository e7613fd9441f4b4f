"""Russian roulette on the next-event shadow rays (simulate.raytrace.integrator, "Shadow rays").

A candidate shadow ray is traced with probability ``p = min(1, c / c_ref)`` and scores ``1 / p`` times
its contribution, so ``beta`` keeps its expectation. Checked on a small felt and a plain weave, with
fixed seeds: ``beta`` with the roulette against ``beta`` without it (independent seeds) within a few
combined standard errors -- at the default level and at a level eight times as high, where most
shadow rays are played and a bias would show more; the reported error against the spread over
seeds; the shadow rays and their Embree queries fall; with every candidate kept (a level of ~0) the
run is the run without roulette bit for bit (the paths do not depend on the roulette's draws).
"""

from __future__ import annotations

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry import weave
from simulate.geometry.felt import felt_mesh
from simulate.geometry.mesh import mesh as weave_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace import integrator


def _dirs(theta_deg, phi_deg=0.0):
    t = np.radians(np.atleast_1d(theta_deg))
    p = np.radians(np.broadcast_to(phi_deg, t.shape))
    return np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@pytest.fixture(scope="module")
def table():
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.3, 10.0)
    return W.yarn_table(fib, [550.0], photons_per_row=4000, seed=12, threads=1)


@pytest.fixture(scope="module", params=["felt", "plain weave"])
def scene(request, table):
    if request.param == "felt":
        mesh = felt_mesh(ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=4), 10.0, seed=0)
    else:
        mesh = weave_mesh(weave.Weave(np.array([[1, 0], [0, 1]]), spacing_um=300.0, width_um=250.0,
                                      height_um=100.0, points_per_span=6, sides=12))
    return request.param, mesh, W.FiberSurface(table, 0.35, 1.5), {}


W_IN = _dirs(40.0, 10.0)[0]
DET = _dirs([0.0, 20.0, 45.0, 60.0, 35.0], [0.0, 190.0, 10.0, 100.0, 200.0])


def _run(scene, monkeypatch, seed, roulette=True, level=integrator.SHADOW_LEVEL, rays=8192):
    _, mesh, mat, setups = scene
    monkeypatch.setattr(integrator, "SHADOW_ROULETTE", roulette)
    monkeypatch.setattr(integrator, "SHADOW_LEVEL", level)
    return W.trace(mesh, mat, W_IN, DET, target_rel_err=1e-9, max_rays=rays, seed=seed, chunk=1024,
                   setups=setups)


def _z(a, b):
    return ((a.beta - b.beta) / np.hypot(a.u_beta, b.u_beta)).ravel()


@pytest.mark.parametrize("factor", [1.0, 8.0])
def test_roulette_keeps_beta_within_standard_errors(scene, monkeypatch, factor):
    off = _run(scene, monkeypatch, seed=1, roulette=False, rays=16384)
    on = _run(scene, monkeypatch, seed=2, level=factor * integrator.SHADOW_LEVEL, rays=16384)
    z = _z(on, off)
    assert np.max(np.abs(z)) < 4.0, (scene[0], z)
    assert float(np.sqrt(np.mean(z ** 2))) < 2.0, (scene[0], z)
    # the roulette did play: far fewer shadow rays than candidates
    assert on.info["shadow_rays"] < 0.8 * on.info["shadow_candidates"], on.info


def test_roulette_traces_fewer_shadow_rays_on_the_same_paths(scene, monkeypatch):
    off = _run(scene, monkeypatch, seed=3, roulette=False)
    on = _run(scene, monkeypatch, seed=3)
    # the same paths: the same candidates, the same escaping light, fewer shadow rays and queries
    assert on.info["shadow_candidates"] == off.info["shadow_candidates"] > 0
    np.testing.assert_array_equal(on.reflected, off.reflected)
    assert on.info["shadow_rays"] < 0.8 * off.info["shadow_rays"], (on.info, off.info)
    assert on.info["shadow_queries"] < 0.8 * off.info["shadow_queries"], (on.info, off.info)
    assert off.info["shadow_rays"] <= off.info["shadow_candidates"]
    path_queries = [r.info["embree_rays"] - r.info["shadow_queries"] for r in (on, off)]
    assert path_queries[0] == path_queries[1]
    # every candidate kept: the run without roulette, bit for bit
    keep_all = _run(scene, monkeypatch, seed=3, level=0.0)
    np.testing.assert_array_equal(keep_all.beta, off.beta)
    np.testing.assert_array_equal(keep_all.u_beta, off.u_beta)
    assert keep_all.info["shadow_rays"] == off.info["shadow_rays"]


def test_roulettes_reported_error_holds_the_spread_over_seeds(scene, monkeypatch):
    """Twelve short runs with the roulette at twice its level: the variance of ``beta`` between them
    is what their ``u_beta`` says (the ratio's sampling spread with 11 degrees of freedom a detector:
    about +-0.3)."""
    runs = [_run(scene, monkeypatch, seed=20 + k, level=2.0 * integrator.SHADOW_LEVEL, rays=2048)
            for k in range(12)]
    b = np.array([r.beta[:, 0] for r in runs])
    u = np.array([r.u_beta[:, 0] for r in runs])
    ratio = float(np.mean(b.var(axis=0, ddof=1)) / np.mean(u ** 2))
    assert 0.4 < ratio < 2.2, (scene[0], ratio)
