"""The accuracy control of the exit tables (simulate.fiber.farfield.controlled_halves, merged).

The quantity controlled is what a caller makes of the tables (here a fiber's far field over a few
directions, as the structured summation makes beta of them): the rounds must stop once ITS error
meets the target, and more photons must bring the error down as 1/sqrt(N).
"""

from __future__ import annotations

import math

import numpy as np

from simulate.fiber import Fiber
from simulate.fiber import farfield as FF
from simulate.media.medium import HGMedium
from simulate.montecarlo.accuracy import relative_error

W_T = (0.0, 0.5, 0.9)


def _fiber() -> Fiber:
    return Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=0.4, mu_a=0.02, g=0.5), roughness=0.3,
                 cell_width_deg=20)


W_IN = np.array([0.3, -0.2, math.sqrt(1 - 0.13)])
W_OUT = np.array([[0.1, 0.5, math.sqrt(1 - 0.26)], [-0.4, 0.1, math.sqrt(1 - 0.17)], [0.0, -0.7, math.sqrt(0.51)]])


def _beta_of(table: FF.ExitTable) -> np.ndarray:
    return table.far_field(W_IN, W_OUT)


def _table(per_row: int, seed: int) -> FF.ExitTable:
    return FF.exit_table(_fiber(), [550.0], w_t=W_T, photons_per_row=per_row, seed=seed, threads=1)


def test_merged_tables_have_the_error_of_their_photons_together():
    a, b = _table(3000, 1), _table(3000, 2)
    one = _table(6000, 3)           # independent: the same photons per row as a and b together
    m = FF.merged(a, b, 3000, 3000)
    lit = (one.u_T > 0) & (a.u_T > 0) & (b.u_T > 0)
    ratio = np.sqrt(np.mean(m.u_T[lit] ** 2) / np.mean(one.u_T[lit] ** 2))
    assert 0.9 < ratio < 1.1
    assert m.photons == a.photons + b.photons
    # the merged means agree with the independent table within their errors: the median |z| of a
    # normal variable is 0.674 (the median, as sparse bins' errors are themselves noisy)
    z = (m.T - one.T)[lit] / np.sqrt(m.u_T ** 2 + one.u_T ** 2)[lit]
    assert 0.55 < np.median(np.abs(z)) < 0.8


def test_rounds_stop_at_the_target_of_what_the_caller_computes():
    loose = FF.controlled_halves(_fiber(), [550.0], _beta_of, 0.5, per_row=100, seed=0, threads=1)
    assert len(loose[2]["rounds"]) == 1           # one round meets a loose target

    first = loose[2]["rounds"][0]["rel_err"]
    target = first / 3.0                           # needs ~9x the photons: more rounds
    beta, u, info = FF.controlled_halves(_fiber(), [550.0], _beta_of, target, per_row=100, seed=0, threads=1)
    rounds = info["rounds"]
    assert len(rounds) >= 2
    assert rounds[0]["rel_err"] == first           # round 0 is the same photons as the loose run's
    assert info["rel_err"] == relative_error(beta, u)
    assert info["rel_err"] <= target or len(rounds) == FF.MAX_ROUNDS
    # the error falls about as 1/sqrt(N) from the first round to the last
    n0, n1 = rounds[0]["photons_per_row"], rounds[-1]["photons_per_row"]
    expected = first * math.sqrt(n0 / n1)
    assert 0.5 * expected < rounds[-1]["rel_err"] < 2.0 * expected
    # and it stops near the target, not far past it (the last round is sized from the error measured)
    assert rounds[-1]["rel_err"] > 0.4 * target
