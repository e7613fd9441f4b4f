"""The structured summation's surface term on a lattice in the RMS slope (FitProblem.surface_term): exact at the
lattice points, the linear blend in log rms_slope between them (close to the exact term), and computed only at
the lattice points, so a Jacobian's two RMS-slope columns inside one cell compute no surface term; the terms are
those of the config each evaluation is given (a surface sum built once per structure and host index)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fabric_optics.fitting.problem import SURFACE_LATTICE_STEP, FitProblem
from fabric_optics.fitting.spec import parse_free
from simulate.fabric.surfacesum import SurfaceSum
from simulate.structwalk import walk as fit_structure

from .test_fit_structure import _felt, _measured


def _problem():
    config = _felt()
    problem = FitProblem(config, _measured(0.3), parse_free(["rms_slope"], config), method="summation",
                         target_rel_err=0.1, seed=3)
    assert problem.structured
    return problem


def _exact(problem, rms_slope: float) -> np.ndarray:
    config = dataclasses.replace(problem.config, rms_slope=rms_slope)
    return fit_structure.surface_beta(config, problem._facets_of(config), problem.w_i, problem.w_o)


def test_the_surface_term_is_exact_on_the_lattice_and_blended_between(monkeypatch):
    problem = _problem()
    r0 = float(problem.config.rms_slope)
    calls: list[float] = []
    real = SurfaceSum.beta

    def counted(self, rms_slope):
        calls.append(float(rms_slope))
        return real(self, rms_slope)

    monkeypatch.setattr(SurfaceSum, "beta", counted)
    at_start = problem.surface_term(problem.config_at(np.array([r0])))
    np.testing.assert_array_equal(at_start, _exact(problem, r0))
    calls.clear()
    # a point 30 % into the cell above the start: the blend of the cell's two ends, linear in log rms_slope
    r = r0 * math.exp(0.3 * SURFACE_LATTICE_STEP)
    blended = problem.surface_term(problem.config_at(np.array([r])))
    hi = r0 * math.exp(SURFACE_LATTICE_STEP)
    assert calls == [round(hi, 12)]                      # the start's end is memoised, the other computed once
    np.testing.assert_allclose(blended, 0.7 * at_start + 0.3 * _exact(problem, hi), rtol=1e-12, atol=0.0)
    # close to the exact term at that slope: far below the walks' Monte Carlo error (a few %)
    exact = _exact(problem, r)
    assert not np.array_equal(blended, exact)
    assert float(np.sqrt(np.mean((blended - exact) ** 2))) < 1e-3 * float(np.mean(np.abs(exact)))
    # a central difference inside the cell (the Jacobian's RMS-slope columns) computes no surface table
    calls.clear()
    for v in (r * (1 - 1e-3), r * (1 + 1e-3)):
        problem.surface_term(problem.config_at(np.array([v])))
    assert calls == []


def test_a_fit_problems_surface_term_follows_the_config_it_is_given():
    """FitProblem keeps a surface sum per structure and host index: after one was built, a config with another
    host index or felt spread gets its own term, equal to the uncached one, and the first config's term is
    unchanged when asked again."""
    config = _felt(spread=10.0)
    problem = FitProblem(config, _measured(0.3), parse_free(["rms_slope"], config), method="summation",
                         target_rel_err=0.1, seed=3)

    def uncached(cfg, m):
        at = dataclasses.replace(cfg, rms_slope=m)
        return fit_structure.surface_beta(at, fit_structure.facets_of(at), problem.w_i, problem.w_o)

    first = problem._surface_at(config, 0.25)
    np.testing.assert_array_equal(first, uncached(config, 0.25))
    index = dataclasses.replace(config, n_host=1.6)
    spread = dataclasses.replace(config, structure=dataclasses.replace(config.structure, felt_spread_deg=25.0))
    for cfg in (index, spread):
        got = problem._surface_at(cfg, 0.25)
        assert not np.array_equal(got, first)
        np.testing.assert_array_equal(got, uncached(cfg, 0.25))
    np.testing.assert_array_equal(problem._surface_at(config, 0.3), uncached(config, 0.3))
    np.testing.assert_array_equal(problem._surface_at(config, 0.25), first)
