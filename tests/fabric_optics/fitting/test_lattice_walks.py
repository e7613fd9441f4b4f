"""The structured fit's walked parameters read between lattice walks (fabric_optics.fitting.problem.FitProblem.lattice_corners):
walks only at lattice points, each once, and the blend equals a walk at the value itself within errors."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fabric_optics.fitting.problem import STRUCTURED_LATTICE_STEP as LATTICE_STEP
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.spec import parse_free
from simulate.fiber.absorption import absorption_nodes
from simulate.structwalk import walk as fit_structure

from .test_fit_structure import _felt, _measured

WL1 = np.array([550.0])


def _problem(free=("volume_fraction",)):
    config = _felt(volume_fraction=0.02)
    return FitProblem(config, _measured(0.3, wavelengths=WL1), parse_free(list(free), config), method="summation",
                      target_rel_err=0.1, seed=4)


def test_corners_and_weights():
    problem = _problem(["volume_fraction", "radius"])
    s_vf, s_r = (p.start for p in problem.free)
    assert problem.lattice_corners((s_vf, s_r)) == [((round(s_vf, 12), round(s_r, 12)), 1.0)]
    v = s_vf * math.exp(0.25 * LATTICE_STEP)        # a quarter of a cell up; the radius on its point
    r = s_r * math.exp(-0.5 * LATTICE_STEP)         # half a cell down
    corners = problem.lattice_corners((v, r))
    assert len(corners) == 4
    assert sum(w for _, w in corners) == pytest.approx(1.0)
    got = {(round(math.log(a / s_vf) / LATTICE_STEP), round(math.log(b / s_r) / LATTICE_STEP)): w
           for (a, b), w in corners}
    assert got == pytest.approx({(0, -1): 0.75 * 0.5, (0, 0): 0.75 * 0.5, (1, -1): 0.25 * 0.5, (1, 0): 0.25 * 0.5})
    # the blend reproduces log v (and log r) exactly: linear in log v
    assert sum(w * math.log(a) for (a, _), w in corners) == pytest.approx(math.log(v))
    assert sum(w * math.log(b) for (_, b), w in corners) == pytest.approx(math.log(r))


@pytest.mark.slow
def test_between_lattice_points_equals_a_walk_there():
    problem = _problem()
    start = problem.free[0].start
    v = start * math.exp(0.5 * LATTICE_STEP)
    blend = problem.table(problem.config_at(np.array([v])))
    assert problem.counters.walks == 2 and problem.counters.reweights == 0          # the two lattice points, nothing else
    again = problem.table(problem.config_at(np.array([start * math.exp(0.3 * LATTICE_STEP)])))
    assert problem.counters.walks == 2                                     # same cell: no walk
    assert not np.allclose(again.R, blend.R)
    # a walk at v itself (the same streams: common random numbers)
    config = problem.config_at(np.array([v]))
    nodye = dataclasses.replace(dataclasses.replace(config, dye=None).fiber(WL1), roughness=problem._roughness)
    walk = fit_structure.walk_structure(nodye, config, WL1, absorption_nodes(problem.nu_max, problem.nodes),
                                        target_rel_err=0.1, seed=4)
    fresh = walk.table("k", problem._facets_of(config), problem.w_i, problem.w_o)
    # at 10 % per walk the walks at neighbouring lattice points differ by their noise (a change of mu_s moves the
    # paths, docs/physics.md 6.5), and u is each walk's two-halves estimate (one degree of freedom: heavy
    # tails), so the robust figures are read: no bias, and the typical deviation that of the noise
    sigma = np.sqrt(blend.u_R ** 2 + fresh.u_R ** 2) + 1e-12
    z = (blend.R - fresh.R) / sigma
    assert float(np.median(np.abs(z))) < 1.5, np.median(np.abs(z))
    rel = (blend.R - fresh.R) / fresh.R
    assert abs(float(np.mean(rel))) < 0.01, np.mean(rel)
