"""The shadow roulette played on each candidate's bound (simulate.raytrace.integrator, ``SHADOW_BOUND``).

With a fiber material the tracer decides a next-event candidate's shadow ray from a bound of its
contribution (the ray's largest spectral weight times the table cell's largest value times its scale)
and forms the spectral contribution only for the candidates kept. That is an estimator other than
the roulette on the contributions' own sizes (``SHADOW_BOUND = False``); both are unbiased. Checked on a
small felt with a three-wavelength table whose cells differ between the wavelengths (so the bound is
loose and the two estimators differ), fixed seeds:

- every candidate kept (a level of 0): the deferred contributions are those the shading forms, bit for bit;
- the same seed at the default level: the same paths, the same candidates, ``beta`` apart by the
  roulette's noise only;
- independent seeds, one long run each, at the default level and at eight times it: ``beta`` of the
  two estimators within a few combined standard errors at every detector and wavelength;
- the bound's reported error holds the spread over seeds.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry.felt import felt_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace import integrator


def _dirs(theta_deg, phi_deg=0.0):
    t = np.radians(np.atleast_1d(theta_deg))
    p = np.radians(np.broadcast_to(phi_deg, t.shape))
    return np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@pytest.fixture(scope="module")
def scene():
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.3, 10.0)
    grey = W.yarn_table(fib, [550.0], photons_per_row=3000, seed=12, threads=1)
    # three wavelengths whose cells differ: each cell's value times a factor per wavelength in [0.05, 1]
    # (a table like a coloured fiber's, where a cell's largest value bounds the others loosely)
    rng = np.random.default_rng(7)
    T = grey.T[..., [0, 0, 0]] * rng.uniform(0.05, 1.0, grey.T.shape[:3] + (3,))
    table = dataclasses.replace(grey, T=T, wavelengths_nm=np.array([450.0, 550.0, 650.0]))
    mesh = felt_mesh(ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=4), 10.0, seed=0)
    return mesh, W.FiberSurface(table, 0.35, 1.5), {}


W_IN = _dirs(40.0, 10.0)[0]
DET = _dirs([0.0, 20.0, 45.0, 60.0, 35.0], [0.0, 190.0, 10.0, 100.0, 200.0])


def _run(scene, monkeypatch, seed, bound, level=integrator.SHADOW_LEVEL, rays=8192):
    mesh, mat, setups = scene
    monkeypatch.setattr(integrator, "SHADOW_BOUND", bound)
    monkeypatch.setattr(integrator, "SHADOW_LEVEL", level)
    return W.trace(mesh, mat, W_IN, DET, target_rel_err=1e-9, max_rays=rays, seed=seed, chunk=1024,
                   setups=setups)


def _z(a, b):
    return ((a.beta - b.beta) / np.hypot(a.u_beta, b.u_beta)).ravel()


def test_deferred_contributions_are_the_shadings_and_the_bound_is_loose(scene, monkeypatch):
    sizes = _run(scene, monkeypatch, seed=3, bound=False, level=0.0)
    bound = _run(scene, monkeypatch, seed=3, bound=True, level=0.0)
    # every candidate kept: the same sums of the same products
    np.testing.assert_array_equal(bound.beta, sizes.beta)
    np.testing.assert_array_equal(bound.u_beta, sizes.u_beta)
    assert bound.info["shadow_candidates"] == sizes.info["shadow_candidates"] > 0
    # at the default level both play the roulette on the same paths; the bound is at least the size,
    # so it keeps more candidates -- and not all of them (the roulette did play)
    sizes = _run(scene, monkeypatch, seed=3, bound=False)
    bound = _run(scene, monkeypatch, seed=3, bound=True)
    np.testing.assert_array_equal(bound.reflected, sizes.reflected)
    assert bound.info["shadow_candidates"] == sizes.info["shadow_candidates"]
    assert sizes.info["shadow_rays"] < bound.info["shadow_rays"] < 0.8 * bound.info["shadow_candidates"]
    z = _z(bound, sizes)
    assert not np.array_equal(bound.beta, sizes.beta)      # another estimator
    assert np.max(np.abs(z)) < 2.0, z                      # the same paths: only the roulette's noise apart


@pytest.mark.parametrize("factor", [1.0, 8.0])
def test_bound_and_sizes_agree_within_standard_errors(scene, monkeypatch, factor):
    level = factor * integrator.SHADOW_LEVEL
    sizes = _run(scene, monkeypatch, seed=1, bound=False, level=level, rays=32768)
    bound = _run(scene, monkeypatch, seed=2, bound=True, level=level, rays=32768)
    z = _z(bound, sizes)
    assert np.max(np.abs(z)) < 3.5, z
    assert float(np.sqrt(np.mean(z ** 2))) < 1.6, z
    assert float(np.mean(bound.beta)) > 0.0


def test_bounds_reported_error_holds_the_spread_over_seeds(scene, monkeypatch):
    """Twelve short runs at twice the level: the variance of ``beta`` between them is what their ``u_beta``
    says (the ratio's sampling spread with 11 degrees of freedom a bin: about +-0.3)."""
    runs = [_run(scene, monkeypatch, seed=40 + k, bound=True, level=2.0 * integrator.SHADOW_LEVEL, rays=2048)
            for k in range(12)]
    b = np.array([r.beta for r in runs])
    u = np.array([r.u_beta for r in runs])
    ratio = float(np.mean(b.var(axis=0, ddof=1)) / np.mean(u ** 2))
    assert 0.4 < ratio < 2.2, ratio
