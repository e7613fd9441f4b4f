"""The accuracy controller (simulate.montecarlo.accuracy.run_controlled): it reaches the target and
stops just past it, and its stopping point does not depend on the threads.

"Needed" is what the run itself shows: with ``u ~ 1/sqrt(N)`` a run that ends at ``N`` photons
with error ``rel`` needed ``N (rel / target)^2`` photons for the target. The earlier controller
spent 29 % more than that on red-cotton's summation.
"""

from __future__ import annotations

import numpy as np
import pytest

from simulate import fiber as F
from simulate.fiber import routes
from simulate.media.medium import HGMedium
from simulate.montecarlo import accuracy as A

TARGET = 0.01
OVERSHOOT = 0.06
"""Allowed photons beyond the need, summed over the runs: SAFETY (3 %) and the noise of the error
estimate between rounds. Measured on this case (seed 4): 3.3 % now; the earlier controller
(1.1 x the need, rounds of at least 25 %) spent 8.0 % here and fails this test."""


def _record(monkeypatch):
    runs: list[list[tuple[int, float]]] = []
    real = A.run_controlled

    def recording(inp, estimate, target, max_photons, seed, threads, min_photons=A.FIRST_ROUND, progress=None):
        rounds: list[tuple[int, float]] = []
        run = real(inp, estimate, target, max_photons, seed, threads, min_photons,
                   lambda n, rel: rounds.append((n, rel)))
        runs.append(rounds)
        return run

    monkeypatch.setattr(routes, "run_controlled", recording)
    return runs


def _fiber_runs(threads):
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.3, mu_a=0.002, g=0.6), 0.3, 10.0)
    t = np.radians([0.0, 30.0, 60.0, 20.0, 45.0, 70.0])
    w_in = np.column_stack([np.zeros_like(t), -np.sin(t), np.cos(t)])
    w_out = np.column_stack([np.full(t.size, 0.2), np.sin(t[::-1]) * 0.9, np.cos(t[::-1])])
    w_out /= np.linalg.norm(w_out, axis=1)[:, None]
    return F.volume_brdf(fib, w_in, w_out, [550.0], target_rel_err=TARGET, seed=4, threads=threads)


@pytest.fixture(scope="module")
def one_thread():
    """The six runs on one thread and the rounds each played: both tests below read the same run."""
    with pytest.MonkeyPatch.context() as mp:
        runs = _record(mp)
        result = _fiber_runs(threads=1)
    return result, [list(r) for r in runs]


def test_runs_reach_the_target_and_stop_just_past_it(one_thread):
    _, runs = one_thread
    assert len(runs) == 6
    done = needed = 0.0
    for rounds in runs:
        n, rel = rounds[-1]
        assert rel <= TARGET                                  # reached
        assert all(r > TARGET for _, r in rounds[:-1])        # did not run on past a met target
        done += n
        needed += n * (rel / TARGET) ** 2
    assert sum(len(r) > 1 for r in runs) >= 4                 # the test exercises the extrapolation
    assert done <= (1 + OVERSHOOT) * needed, (done, needed)


def test_stopping_point_does_not_depend_on_threads(monkeypatch, one_thread):
    import numba

    assert numba.config.NUMBA_NUM_THREADS >= 2        # the root conftest guarantees a pool of 2
    a, rounds_a = one_thread
    runs = _record(monkeypatch)
    b = _fiber_runs(threads=2)
    assert runs == rounds_a
    assert a.R.tobytes() == b.R.tobytes() and a.photons == b.photons


@pytest.mark.parametrize("history, expect", [
    ([(50_000, 0.0200)], 2_000),                       # at the target: one batch (the floor)
    ([(50_000, 0.0240)], 26_000),                      # 1.44 x: straight to 1.03 x the need, in batches
    ([(50_000, 0.0800)], 150_000),                     # 16 x: first to the geometric mean (4 x)
    ([(10_000, 0.5)], 80_000),                         # a wild early estimate: capped at 8 N
    ([(50_000, 0.08), (200_000, 0.02)], 6_000),        # decay measured as 1/N: need 200 000, the floor
    ([(50_000, 0.03), (100_000, 0.0300)], 132_000),    # no decay seen: the 1/sqrt(N) law, 225 000 x 1.03
    ([(100_000, 0.03)], 20_000),                       # capped by the budget (120 000)
])
def test_next_round(history, expect):
    budget = 120_000 if history == [(100_000, 0.03)] else 10**9
    assert A.next_round(history, 0.02, budget) == expect
