"""Reproducibility: identical numbers for 1 and 2 threads; independent random streams."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from simulate.montecarlo import run_cylinder, run_slab
from simulate.montecarlo.rng import stream_uniforms


@pytest.fixture(autouse=True)
def _two_threads():
    assert numba.config.NUMBA_NUM_THREADS >= 2        # the root conftest guarantees a pool of 2


def test_slab_identical_with_one_and_two_threads():
    kw = dict(mu_a=2.0, mu_s=40.0, g=0.8, n=1.4, thickness=0.1, photons=60_000, seed=99,
              batch_size=2_000, angular_bins=(6, 4), weight_threshold=0.05)
    a = run_slab(threads=1, **kw)
    b = run_slab(threads=2, **kw)
    assert a.as_dict() | {"seconds": 0} == b.as_dict() | {"seconds": 0}
    assert np.array_equal(a.angular.reflected, b.angular.reflected)
    assert np.array_equal(a.angular.u_transmitted, b.angular.u_transmitted)
    c = run_slab(threads=1, **(kw | {"seed": 100}))
    assert c.Rd != a.Rd  # the seed matters


def test_cylinder_identical_with_one_and_two_threads():
    kw = dict(mu_a=1.0, mu_s=20.0, g=0.7, n=1.557, radius=1.0, photons=40_000, seed=5,
              batch_size=1_000, angular_bins=(6, 3, 4))
    a = run_cylinder(threads=1, **kw)
    b = run_cylinder(threads=2, **kw)
    assert a.exited == b.exited and a.u_exited == b.u_exited and a.energy == b.energy
    assert np.array_equal(a.angular.exits, b.angular.exits)


def test_random_streams_are_reproducible_and_distinct():
    a = stream_uniforms(3, 0, 100_000)
    assert np.array_equal(a, stream_uniforms(3, 0, 100_000))
    b = stream_uniforms(3, 1, 100_000)
    c = stream_uniforms(4, 0, 100_000)
    assert not np.array_equal(a[:100], b[:100]) and not np.array_equal(a[:100], c[:100])
    for x in (a, b, c):
        assert np.all((x >= 0) & (x < 1))
        assert abs(x.mean() - 0.5) < 4 * np.sqrt(1 / 12 / x.size)
        hist = np.histogram(x, bins=20, range=(0, 1))[0]
        expected = x.size / 20
        assert np.sum((hist - expected) ** 2 / expected) < 45  # chi2, 19 dof, p ~ 1e-3
    # streams are uncorrelated with each other
    assert abs(np.corrcoef(a, b)[0, 1]) < 4 / np.sqrt(a.size)


def test_identical_whatever_the_rounds(monkeypatch):
    """execute() cuts batches into rounds of ~ROUND_SECONDS (the interrupt latency): rounds of one
    batch per thread and rounds as large as the buffers allow give the same sums."""
    from simulate.montecarlo import transport

    kw = dict(mu_a=2.0, mu_s=40.0, g=0.8, n=1.4, thickness=0.1, photons=40_000, seed=7,
              batch_size=2_000, angular_bins=(6, 4), weight_threshold=0.05)
    monkeypatch.setattr(transport, "ROUND_SECONDS", 1e-9)  # every round: one batch per thread
    a = run_slab(**kw)
    monkeypatch.setattr(transport, "ROUND_SECONDS", 1e9)
    monkeypatch.setattr(transport, "_FIRST_ROUND_BATCHES", 10**6)  # one round of everything
    b = run_slab(**kw)
    assert a.as_dict() | {"seconds": 0} == b.as_dict() | {"seconds": 0}
    assert np.array_equal(a.angular.reflected, b.angular.reflected)
