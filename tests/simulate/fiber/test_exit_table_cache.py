"""The summation's exit tables in the disk cache (simulate.fiber.farfield.exit_table + simulate.fiber.tablecache):
a hit is the walk bit for bit, the key follows the fiber (its dye too: this table is not white), the photons and
the seed, and a corrupt entry is walked again and rewritten."""

from __future__ import annotations

import dataclasses

import numpy as np

from simulate.fiber import Fiber, tablecache
from simulate.fiber import farfield as FF
from simulate.media.medium import HGMedium

W_T = (0.0, 0.5, 0.9)


def _fiber(mu_a: float = 0.02, mu_s: float = 0.4) -> Fiber:
    return Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=mu_s, mu_a=mu_a, g=0.5), roughness=0.3,
                 cell_width_deg=20)


def _table(fiber=None, per_row=500, seed=1, cache=True):
    return FF.exit_table(_fiber() if fiber is None else fiber, [550.0, 600.0], w_t=W_T, photons_per_row=per_row,
                         seed=seed, threads=1, cache=cache)


def _same(a, b):
    for name in ("T", "u_T", "k"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)
    assert a.photons == b.photons


def test_a_hit_is_the_walk_and_the_key_follows_its_inputs(cache_dir):
    fresh = _table(cache=False)
    assert not tablecache.entries(cache_dir)
    stored = _table()
    assert len(tablecache.entries(cache_dir)) == 1
    read = _table()
    assert len(tablecache.entries(cache_dir)) == 1
    _same(fresh, stored)
    _same(fresh, read)
    # the same fiber through the medium cache of controlled_halves: the same key
    assert FF.exit_table_key(FF.cached(_fiber()), [550.0, 600.0], W_T, (9, 18), 500, 1, 7) == \
        FF.exit_table_key(_fiber(), [550.0, 600.0], W_T, (9, 18), 500, 1, 7)
    base = FF.exit_table_key(_fiber(), [550.0, 600.0], W_T, (9, 18), 500, 1, 7)
    others = [FF.exit_table_key(_fiber(mu_a=0.03), [550.0, 600.0], W_T, (9, 18), 500, 1, 7),   # absorption (dye)
              FF.exit_table_key(_fiber(mu_s=0.5), [550.0, 600.0], W_T, (9, 18), 500, 1, 7),    # scattering
              FF.exit_table_key(dataclasses.replace(_fiber(), radius_um=11.0), [550.0, 600.0], W_T, (9, 18), 500,
                                1, 7),
              FF.exit_table_key(_fiber(), [550.0, 610.0], W_T, (9, 18), 500, 1, 7),
              FF.exit_table_key(_fiber(), [550.0, 600.0], (0.0, 0.5), (9, 18), 500, 1, 7),
              FF.exit_table_key(_fiber(), [550.0, 600.0], W_T, (9, 18), 600, 1, 7),
              FF.exit_table_key(_fiber(), [550.0, 600.0], W_T, (9, 18), 500, 2, 7)]
    assert len(set(others) | {base}) == len(others) + 1


def test_a_corrupt_entry_is_walked_again_and_rewritten(cache_dir, caplog):
    first = _table()
    (_, _, path), = tablecache.entries(cache_dir)
    good = path.read_bytes()
    path.write_bytes(good[: len(good) // 2])
    with caplog.at_level("WARNING"):
        again = _table()
    assert any("corrupt" in r.getMessage() for r in caplog.records)
    _same(first, again)
    assert path.read_bytes() == good


def test_no_cache_when_disabled(cache_dir, monkeypatch):
    monkeypatch.setenv(tablecache.ENV_DISABLE, "1")
    _table()
    assert not tablecache.entries(cache_dir)
