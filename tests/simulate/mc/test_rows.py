"""Many runs in one kernel call (:func:`simulate.montecarlo.rows.execute_rows`) are the runs one by one.

The reference is the one-run path every other estimator uses (:func:`transport.execute` with the
source in the run's inputs): each row's scalar and bin sums must be bit-identical to it, whatever
the threads and however the jobs are cut in rounds. The BSSRDF rows and the yarn tables built on
it (several rows, nodes and both halves in one call) must equal their one-call-per-row build.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fiber.bssrdf import row_sources, rows_inputs
from simulate.fiber.spectral import group_walk, spectral_optics, wavelength_groups
from simulate.media.medium import HGMedium
from simulate.montecarlo import transport as TR
from simulate.montecarlo.accuracy import mean_and_error
from simulate.montecarlo.rows import execute_rows
from simulate.raytrace import yarn as Y


def _fiber() -> F.Fiber:
    return F.Fiber(10.0, 1.5, HGMedium(mu_s=0.6, mu_a=0.02, g=0.6), 0.3, 30.0)


def _inputs(fib, wl=(500.0, 600.0)):
    optics = spectral_optics(fib, np.array(wl))
    group = wavelength_groups(optics)[0]
    medium, walk_phase, targets = group_walk(fib, optics, group, white=True)
    grid = (fib.cell_count("test"), 2, 20.0, 3, 4)
    return rows_inputs(fib, grid, medium, walk_phase, targets, TR.make_control())


def _one_by_one(inp, sources, seeds, photons, threads, batch):
    out = [TR.execute(inp._replace(source=src), photons, int(s), threads, batch) for src, s in zip(sources, seeds, strict=True)]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])


@pytest.mark.parametrize("threads", [1, 2])
def test_rows_in_one_call_are_bit_identical_to_one_call_each(threads, monkeypatch):
    fib = _fiber()
    inp = _inputs(fib)
    dpsi = 2.0 * math.pi / fib.cell_count("test")
    sources = np.concatenate([row_sources(0.0, [0, 1, 2], dpsi), row_sources(0.6, [0, 3], dpsi)])
    seeds = np.array([3, 11, 7919, 5, 104729], dtype=np.int64)
    photons, batch = 2500, 1000             # 3 batches a run, the last one short
    ref_s, ref_b = _one_by_one(inp, sources, seeds, photons, threads, batch)
    # rounds of 1 job: a cut between every pair of jobs changes nothing either
    from simulate.montecarlo import rows as R
    monkeypatch.setattr(R, "ROUND_SECONDS", 1e-9)
    s, b, _ = execute_rows(inp, sources, seeds, photons, threads, batch)
    assert s.shape == ref_s.shape and b.shape == ref_b.shape
    assert s.tobytes() == ref_s.tobytes()
    assert b.tobytes() == ref_b.tobytes()
    assert np.all(s[:, 0] == photons)      # every run launched its photons
    assert np.any(b[:, :, 0] > 0)


@pytest.mark.parametrize("threads", [1, 2])
def test_means_into_a_strided_view_are_the_bins_means_bit_for_bit(threads, monkeypatch):
    """``execute_rows(..., means=view)`` (the fit's walk: no ``[R, n_bins, 2]`` array) writes
    ``bins[r, :, 0] / photons`` into a strided view of a larger table, bit for bit, with several batches a
    run cut over rounds of one job (the sums held in the view between rounds) and leaves the rest alone."""
    from simulate.montecarlo import rows as R

    fib = _fiber()
    inp = _inputs(fib)
    dpsi = 2.0 * math.pi / fib.cell_count("test")
    sources = np.concatenate([row_sources(0.0, [0, 1, 2], dpsi), row_sources(0.6, [1], dpsi)])
    seeds = np.array([4, 9, 7919, 31], dtype=np.int64)
    photons, batch = 2500, 1000             # 3 batches a run, the last one short
    s_ref, b_ref, _ = execute_rows(inp, sources, seeds, photons, threads, batch)
    n_psi, n_v, n_mu, n_phi, n_spec = fib.cell_count("test"), 2, 3, 4, inp.spec_mu.shape[0]
    big = np.full((2, len(seeds), n_psi, n_v, n_mu, n_phi, n_spec + 3), -7.0)
    view = big[1, :, :, :, :, :, 1:1 + n_spec]          # not contiguous: the channel slice of a wider table
    monkeypatch.setattr(R, "ROUND_SECONDS", 1e-9)
    s, b, _ = execute_rows(inp, sources, seeds, photons, threads, batch, means=view)
    assert b is None and s.tobytes() == s_ref.tobytes()
    want = (b_ref[:, :, 0] / photons).reshape(view.shape)
    assert np.any(want > 0) and view.tobytes() == np.ascontiguousarray(want).tobytes()
    assert np.all(big[0] == -7.0) and np.all(big[1][..., 0] == -7.0) and np.all(big[1][..., 1 + n_spec:] == -7.0)
    with pytest.raises(ValueError, match="means must be"):
        execute_rows(inp, sources, seeds, photons, threads, batch, means=view[:, :1])


def test_rows_of_different_seeds_or_sources_differ():
    """The rows are really different runs (a driver that ran row 0 for every job would fail here)."""
    fib = _fiber()
    inp = _inputs(fib)
    dpsi = 2.0 * math.pi / fib.cell_count("test")
    sources = np.concatenate([row_sources(0.0, [0], dpsi)] * 2 + [row_sources(0.0, [2], dpsi)])
    s, b, _ = execute_rows(inp, sources, np.array([1, 2, 1]), 2000, 2, 1000)
    assert b[0].tobytes() != b[1].tobytes()
    assert b[0].tobytes() != b[2].tobytes()


def test_table_halves_equal_each_half_built_row_by_row():
    """The joint build of both halves (every node, row and half of a group in one call) is bit-identical
    to the tables built one row per kernel call with the seeds the old loop gave them."""
    fib = _fiber()
    wl = [500.0, 600.0]
    kw = dict(w_t_nodes=(0.0, 0.5), n_v=1, n_mu=3, n_phi=4)
    a, b = W.table_halves(fib, wl, 1500, seed=2, threads=2, cache=False, **kw)
    nodes, n_psi, dpsi, ks = Y._grid(fib, kw["w_t_nodes"])
    optics = spectral_optics(fib, np.array(wl))
    grid = (n_psi, 1, 2.0 * fib.radius_um, 3, 4)
    for table, seed in ((a, 2), (b, 2 + Y.HALF_SEED_STEP)):
        for j, w_t in enumerate(nodes):
            for group in wavelength_groups(optics):
                medium, walk_phase, targets = group_walk(fib, optics, group, white=True)
                inp = rows_inputs(fib, grid, medium, walk_phase, targets, TR.make_control())
                for r, src in enumerate(row_sources(float(w_t), ks, dpsi)):
                    _, bins, _ = TR.execute(inp._replace(source=src), 1500, seed + 104729 * j + 7919 * r, 1, 2000)
                    mean, _ = mean_and_error(bins, 1500)      # the table keeps the means only
                    n_cells = table.T.shape[2]
                    assert table.T[j, r][:, group].tobytes() == mean.reshape(n_cells, group.size).tobytes()
    assert a.T.sum() > 0 and a.T.tobytes() != b.T.tobytes()
    one = W.yarn_table(fib, wl, photons_per_row=1500, seed=2, threads=1, cache=False, **kw)
    assert one.T.tobytes() == a.T.tobytes() and one.photons == a.photons


def test_held_table_with_only_the_walks_phase_functions_is_bit_identical():
    """A held-scattering table (the pile's) computes the Mie phase functions of its groups' middle
    wavelengths only (:func:`simulate.raytrace.yarn._walk_optics`); every other wavelength's is never read:
    the table equals the one built with all of them."""
    from simulate.media.medium import MieMedium

    medium = MieMedium(n_host=1.5, particle_n=2.0, particle_k=0.0, radius_um=0.2, volume_fraction=0.01,
                       mu_a_host_per_um=0.002)
    fib = F.Fiber(10.0, 1.5, medium, 0.3, 30.0)
    wl = np.array([450.0, 470.0, 600.0, 620.0, 640.0])
    kw = dict(w_t_nodes=(0.0, 0.5), n_v=1, n_mu=3, n_phi=4, photons_per_row=1000, seed=4, threads=2, cache=False,
              held_log_mu_s=0.05)
    walk = Y._walk_optics(fib, wl, 0.05)
    full = spectral_optics(fib, wl)
    refs = [int(g[len(g) // 2]) for g in Y.held_groups(full, 0.05)]
    assert 1 < len(refs) < wl.size                     # some phase functions are left out
    for i in range(wl.size):
        same = np.array_equal(walk.phases[i].table, full.phases[i].table)
        assert same == (i in refs)
    assert np.array_equal(walk.mu_s, full.mu_s) and np.array_equal(walk.g, full.g)
    a = W.yarn_table(fib, wl, optics=full, **kw)
    b = W.yarn_table(fib, wl, **kw)
    assert a.T.sum() > 0
    assert a.T.tobytes() == b.T.tobytes()
    assert a.c_bar.tobytes() == b.c_bar.tobytes() and a.tau.tobytes() == b.tau.tobytes()
