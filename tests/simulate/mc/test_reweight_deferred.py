"""Spectral re-weighting without a vertex estimator: the weights are brought up to date every few
collisions and at exits (kernel docstring, "deferred re-weighting"), and roulette is decided then.

One white walk (no absorption) with an exit tally re-weights to three targets -- other absorption,
other scattering coefficient, other phase function -- and must give each target's reflectance and
transmittance as a walk in that target itself does (an index-mismatched slab: long histories,
internal reflections, many updates and roulette on the re-weighted weights).
"""

from __future__ import annotations

import math

import numpy as np

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import run_slab
from simulate.montecarlo import tallies as T
from simulate.montecarlo.accuracy import mean_and_error
from simulate.montecarlo.scatter import phase_arrays
from simulate.montecarlo.transport import SpectralTargets, execute, make_control, make_inputs

N, D, PHOTONS = 1.5, 5.0, 200_000
WALK = (0.0, 1.0, 0.5)                                          # mu_a, mu_s, g of the white walk
TARGETS = [(0.05, 1.0, 0.5), (0.2, 0.8, 0.5), (0.02, 1.3, 0.7)]  # absorption; scattering; phase too


def test_white_walk_reweighted_at_exits_equals_walks_in_each_target():
    medium = np.zeros(K.N_MEDIUM)
    medium[[K.M_MU_A, K.M_MU_S, K.M_G, K.M_N]] = WALK[0], WALK[1], WALK[2], N
    medium[K.M_PHASE] = K.PHASE_HG
    walk_phase = phase_arrays(g=WALK[2])
    targets = SpectralTargets(mu_a=np.array([t[0] for t in TARGETS]), mu_s=np.array([t[1] for t in TARGETS]),
                              phases=[phase_arrays(g=t[2]) for t in TARGETS],
                              same_phase=np.array([t[2] == WALK[2] for t in TARGETS]))
    inp = make_inputs(G.SLAB, np.array([D]), np.array([0.0, 0.0, 0.0, 1.0]), medium, walk_phase, make_control(),
                      T.SLAB_DIRECTIONS, np.array([1.0, 1.0]), T.V_NONE, None, targets)
    assert inp.reweight and inp.phase_ratio
    scal, bins, _ = execute(inp, PHOTONS, 11, 1, 10_000)
    assert scal[T.S_SCATTERINGS] / PHOTONS > 2 * K.REWEIGHT_EVERY   # several deferred updates per history
    mean, u = mean_and_error(bins, PHOTONS)
    n_spec = len(TARGETS)
    for l, (mu_a, mu_s, g) in enumerate(TARGETS):
        ref = run_slab(mu_a, mu_s, g=g, n=N, thickness=D, photons=PHOTONS, seed=20 + l, threads=1)
        for face, (value, err) in enumerate(((ref.Rd, ref.u_Rd), (ref.Tt, ref.u_Tt))):
            row = face * n_spec + l
            z = (mean[row] - value) / math.hypot(u[row], err)
            assert abs(z) < 4.0, (l, face, mean[row], value, z)
