"""Scattering parameters from the same walk: the likelihood-ratio re-weighting of a walk to
another particle volume fraction equals a fresh walk within standard errors; a change past the
variance bound walks again."""

from __future__ import annotations

import dataclasses
import math
import tomllib

import numpy as np
import pytest

from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.spec import parse_free
from fabric_optics.paths import toml_dumps
from simulate import fiber as fib
from simulate.config import parse_config
from simulate.fiber.absorption import absorption_nodes, absorption_table
from simulate.fiber.spectral import phase_chi2, reweight_exponent, spectral_optics
from simulate.montecarlo.scatter import phase_arrays

from .conftest import WAVELENGTHS, measurement


def _nodye(config, **particles):
    doc = tomllib.loads(config.text)
    doc["particles"].update(particles)
    c = parse_config(toml_dumps(doc), "x.toml")
    return dataclasses.replace(c, dye=None).fiber(WAVELENGTHS)


def test_reweighted_walk_equals_a_fresh_walk_within_standard_errors(red_cotton):
    f0 = _nodye(red_cotton)
    f1 = _nodye(red_cotton, volume_fraction=0.055)  # +10 %: within the bound
    w_in = np.array([[0.0, 0.0, 1.0]])
    outputs = fib.range_outputs([0.0], [1.0], [-math.pi], [math.pi], f0.half_width)
    nodes = absorption_nodes(3.0, 4)
    kw = dict(method="beam", target_rel_err=0.01)
    ref = absorption_table(f0, w_in, outputs, WAVELENGTHS, nodes, seed=5, **kw)
    rw = absorption_table(f1, w_in, outputs, WAVELENGTHS, nodes, seed=5, photons=ref.photons, reference=f0, **kw)
    fresh = absorption_table(f1, w_in, outputs, WAVELENGTHS, nodes, seed=77, photons=ref.photons, **kw)
    z = (rw.R - fresh.R) / np.hypot(rw.u_R, fresh.u_R)
    z_ref = (ref.R - fresh.R) / np.hypot(ref.u_R, fresh.u_R)
    assert np.sqrt(np.mean(z ** 2)) < 1.5 and np.max(np.abs(z)) < 4.0
    assert abs(np.mean(z_ref)) > 2.0  # the change is seen (one sign): re-weighting is not a no-op
    assert np.median(rw.u_R / ref.u_R) < 2.0  # the bound allows a doubled standard error at most


def test_variance_bound_grows_with_the_change(red_cotton):
    f0 = _nodye(red_cotton)
    o0 = spectral_optics(f0, WAVELENGTHS)
    groups = [np.arange(WAVELENGTHS.size)]
    n = np.array([50.0])
    expo = [reweight_exponent(o0, spectral_optics(_nodye(red_cotton, volume_fraction=v), WAVELENGTHS), groups, n)
            for v in (0.05, 0.055, 0.065)]
    assert expo[0] < expo[1] < expo[2]
    # a pure mu_s change of ratio r: N (r - 1)^2 exactly (same phase: no chi-square term)
    hg = phase_arrays(g=0.5)
    from simulate.fiber.spectral import SpectralOptics

    a = SpectralOptics(np.array([1.0]), np.array([0.0]), np.array([0.5]), [hg])
    b = SpectralOptics(np.array([1.2]), np.array([0.0]), np.array([0.5]), [hg])
    assert reweight_exponent(a, b, [np.array([0])], np.array([10.0])) == pytest.approx(10 * 0.2 ** 2)
    # chi-square of two HG functions against numerical quadrature of int p^2/p0 dmu - 1
    mu = np.linspace(-1, 1, 200001)

    def hg_pdf(g):  # per unit mu
        return 0.5 * (1 - g * g) / (1 + g * g - 2 * g * mu) ** 1.5

    exact = np.trapezoid(hg_pdf(0.6) ** 2 / hg_pdf(0.5), mu) - 1.0
    assert phase_chi2(phase_arrays(g=0.5), phase_arrays(g=0.6), cells=4096) == pytest.approx(exact, rel=0.02)


def test_fit_problem_reweights_near_and_walks_far(red_cotton):
    flat = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)
    free = parse_free(["volume_fraction=0.01:0.25"], red_cotton)
    p = FitProblem(red_cotton, flat, free, method="classic", target_rel_err=0.1, seed=3, nodes=4,
                   wavelengths_nm=WAVELENGTHS)
    b0 = p.model(np.array([0.05]))[0]
    assert (p.counters.walks, p.counters.reweights) == (1, 0)
    b1 = p.model(np.array([0.0525]))[0]  # +5 %: the paths of the walk at its lattice point (the start)
    assert (p.counters.walks, p.counters.reweights) == (1, 1)
    assert not np.array_equal(b0, b1)
    p.model(np.array([0.09]))  # x1.8: a new lattice point 0.05 e^0.6 is walked, then re-weighted to 0.09
    assert (p.counters.walks, p.counters.reweights) == (2, 2)
    p.model(np.array([0.0945]))  # the same lattice point: re-weighted only
    assert (p.counters.walks, p.counters.reweights) == (2, 3)
    assert p.lattice((0.0945,)) == (round(0.05 * math.exp(0.6), 12),)
    # deterministic in the parameters: evaluated again after other points, the same values
    p._tables.clear()
    np.testing.assert_array_equal(p.model(np.array([0.0525]))[0], b1)
    assert p.counters.walks == 2  # the lattice walk is kept


def test_a_change_past_the_bound_is_walked_itself(red_cotton, monkeypatch):
    from fabric_optics.fitting import problem as fit_problem

    monkeypatch.setattr(fit_problem, "LATTICE_STEP", 1.0)  # lattice points e-fold apart: too far to re-weight
    flat = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)
    p = FitProblem(red_cotton, flat, parse_free(["volume_fraction=0.01:0.25"], red_cotton), method="classic",
                   target_rel_err=0.1, seed=3, nodes=4, wavelengths_nm=WAVELENGTHS)
    p.model(np.array([0.05]))
    p.model(np.array([0.07]))  # lattice point 0.05: x1.4 is past the bound -> a walk of its own
    assert (p.counters.walks, p.counters.reweights) == (2, 0)
    assert p.last_exponent[0] - p.last_exponent[1] > math.log(4.0)
