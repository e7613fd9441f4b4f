"""The structured summation's walk in the disk cache (simulate.structwalk.walk.walk_structure + simulate.fiber.tablecache):
a hit is the walk, bit for bit; the key follows what the walk depends on and not the dye or the facets; a broken
entry is walked again and rewritten.

Each test has its own cache directory (``FABRIC_OPTICS_CACHE_DIR``); the walks are tiny (one wavelength, three
absorption nodes, the fit's smallest photons per row).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fabric_optics.paths import toml_dumps
from simulate.config import load_config, parse_config
from simulate.fiber import tablecache
from simulate.fiber.absorption import absorption_nodes
from simulate.structwalk import walk as fit_structure

WL1 = np.array([550.0])
NODES = absorption_nodes(1.0, 3)
TARGET = 0.1          # photons_per_row(0.1) = 2000, the fit's floor


def _config(**changes):
    """The green felt with ``changes`` (dotted TOML paths -> values)."""
    import tomllib

    doc = tomllib.loads(load_config("green-felt").text)
    for path, value in changes.items():
        section, name = path.split(".")
        doc[section][name] = value
    return parse_config(toml_dumps(doc), "felt-cache-test.toml")


def _nodye(config):
    return dataclasses.replace(config, dye=None).fiber(WL1)


def _walk(config, seed=5, cache=True):
    return fit_structure.walk_structure(_nodye(config), config, WL1, NODES, target_rel_err=TARGET, seed=seed,
                                        threads=1, cache=cache)


def _key(config, **kw):
    kw.setdefault("seed", 5)
    kw.setdefault("target_rel_err", TARGET)
    return fit_structure.walk_key(_nodye(config), config, WL1, NODES, **kw)


def _same(a, b):
    assert len(a.G) == len(b.G) == 2
    for x, y in zip(a.G, b.G, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)
    assert a.scatterings == b.scatterings
    assert [g.tolist() for g in a.groups] == [g.tolist() for g in b.groups]
    assert a.photons == b.photons


def test_a_hit_is_the_fresh_walk_bit_for_bit(cache_dir):
    config = _config()
    fresh = _walk(config, cache=False)            # walked, nothing stored
    assert fresh.cache == "off" and not tablecache.entries(cache_dir)
    first = _walk(config)                        # walked and stored
    assert first.cache == "miss" and len(tablecache.entries(cache_dir)) == 2   # one entry per half (one chunk)
    again = _walk(config)                        # read
    assert again.cache == "hit"
    _same(fresh, first)
    _same(fresh, again)
    # the evaluation on top of it is the same too (the facet sum of the read layer tables)
    facets = fit_structure.facets_of(config)
    w = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, np.sqrt(0.75)]])
    wo = np.array([[0.3, 0.1, np.sqrt(0.9)], [-0.5, 0.0, np.sqrt(0.75)]])
    np.testing.assert_array_equal(fresh.table("k", facets, w, wo).R, again.table("k", facets, w, wo).R)
    # the optics (Mie) of a walk read from the cache are computed only when asked for, and are the walk's
    assert again._optics is None
    np.testing.assert_array_equal(again.optics.mu_s, fresh.optics.mu_s)


def test_the_key_follows_the_walk_not_the_dye_or_the_facets(cache_dir):
    config = _config()
    base = _key(config)
    # what the walk depends on: the scatterers, the closure's packing, the photons, the seed, the half, ...
    changed = {
        "volume fraction": _key(_config(**{"particles.volume_fraction": 0.01})),
        "packing fraction": _key(_config(**{"structure.packing_fraction": 0.5})),
        "layers": _key(_config(**{"structure.layers": 3})),
        "photons": _key(config, target_rel_err=0.003),     # 6000 photons per row instead of 2000
        "seed": _key(config, seed=6),
        "other half": _key(config, half=1),
        "re-weighted from another walk": fit_structure.walk_key(
            _nodye(config), config, WL1, NODES, target_rel_err=TARGET, seed=5,
            reference=_nodye(_config(**{"particles.volume_fraction": 0.01}))),
        "nodes": fit_structure.walk_key(_nodye(config), config, WL1, absorption_nodes(2.0, 3),
                                        target_rel_err=TARGET, seed=5),
        "wavelengths": fit_structure.walk_key(_nodye(config), config, WL1 + 10.0, NODES, target_rel_err=TARGET,
                                              seed=5),
    }
    assert len(set(changed.values()) | {base}) == len(changed) + 1, changed
    # what it does not depend on: the dye (the walk is white), the facets (felt spread), the threads
    dyed = _config(**{"fiber.dye": {"curve": "knots", "wavelength_nm": [400.0, 700.0], "log10_per_um": [-1.0, 0.2]}})
    assert dyed.dye is not None and dyed.dye(WL1)[0] != config.dye(WL1)[0]
    assert _key(dyed) == base
    assert _key(_config(**{"structure.felt_spread_deg": 45.0})) == base


def test_the_key_leaves_out_the_monte_carlo_felt_s_own_fields(cache_dir):
    """The crimp and the needle-punched population are the felt Monte Carlo's only (the summation's felt has
    straight fibers in the plane): configs differing only in them share the walk; a field the walk reads
    (the packing fraction, the layers) still changes the key."""
    base = _key(_config())
    mc_only = {"structure.felt_crimp_percent": 13.0, "structure.felt_crimp_per_cm": 9.0,
               "structure.felt_crimp_plane": "random", "structure.felt_normal_fraction": 0.2,
               "structure.felt_normal_spread_deg": 30.0}
    for path, value in mc_only.items():
        changed = _config(**{path: value})
        assert getattr(changed.structure, path.split(".")[1]) == value
        assert _key(changed) == base, path
    crimped = _config(**mc_only)
    assert _key(crimped) == base
    assert _key(_config(**{**mc_only, "structure.packing_fraction": 0.5})) != base
    assert _key(_config(**{**mc_only, "structure.layers": 3})) != base


def test_a_corrupt_or_partial_entry_is_walked_again_and_rewritten(cache_dir, caplog):
    config = _config()
    first = _walk(config)
    entries = [p for _, _, p in tablecache.entries(cache_dir)]
    assert len(entries) == 2
    good = {p: p.read_bytes() for p in entries}
    # one entry truncated (a killed writer), the other with a flipped byte in its payload
    entries[0].write_bytes(good[entries[0]][: len(good[entries[0]]) // 3])
    damaged = bytearray(good[entries[1]])
    damaged[-100] ^= 0xFF
    entries[1].write_bytes(bytes(damaged))
    with caplog.at_level("WARNING"):
        again = _walk(config)
    assert again.cache == "miss"
    assert sum("corrupt" in r.getMessage() for r in caplog.records) == 2
    _same(first, again)
    for p in entries:                     # rewritten whole
        assert p.read_bytes() == good[p]
    assert _walk(config).cache == "hit"


def test_an_entry_of_the_wrong_shape_is_walked_again(cache_dir, caplog):
    """A valid file under the key whose arrays do not fit (not a checksum failure): ignored, walked, rewritten."""
    config = _config()
    key = _key(config)
    tablecache.store(key, {"G": np.zeros((2, 2)), "photons": np.int64(1), "scatterings": np.zeros(1),
                           "group_sizes": np.ones(1, np.int64), "group_index": np.zeros(1, np.int64)})
    with caplog.at_level("WARNING"):
        walk = _walk(config)
    assert walk.cache == "miss"               # half 0 walked again, half 1 was never stored
    assert any("unexpected arrays" in r.getMessage() for r in caplog.records)
    assert tablecache.load(key)["G"].shape == walk.G[0].shape
    assert _walk(config).cache == "hit"


def test_walk_wavelengths_keep_the_ends_and_at_most_20_nm():
    np.testing.assert_array_equal(fit_structure.walk_wavelengths(np.arange(390.0, 711.0, 10.0)),
                                  np.arange(390.0, 711.0, 20.0))
    twenty = np.arange(390.0, 711.0, 20.0)
    np.testing.assert_array_equal(fit_structure.walk_wavelengths(twenty), twenty)
    np.testing.assert_array_equal(fit_structure.walk_wavelengths(np.arange(400.0, 421.0, 5.0)), [400.0, 420.0])
    np.testing.assert_array_equal(fit_structure.walk_wavelengths(np.arange(400.0, 431.0, 5.0)),
                                  [400.0, 415.0, 430.0])                 # 20 nm would lose the end: 15
    np.testing.assert_array_equal(fit_structure.walk_wavelengths(np.arange(400.0, 431.0, 10.0)),
                                  np.arange(400.0, 431.0, 10.0))         # no stride keeps both ends
    uneven = np.array([400.0, 410.0, 430.0, 440.0])
    np.testing.assert_array_equal(fit_structure.walk_wavelengths(uneven), uneven)


@pytest.mark.slow
def test_a_walk_at_20_nm_read_at_10_nm_equals_a_walk_at_10_nm(cache_dir):
    """The model at every 10 nm from a walk at every 20 nm (linear in the wavelength at each absorption node)
    equals the walk at every 10 nm within their Monte Carlo errors, without bias."""
    from simulate import fabric as fab

    config = _config()
    wl5 = np.arange(500.0, 541.0, 10.0)
    wl3 = fit_structure.walk_wavelengths(wl5)
    assert wl3.tolist() == [500.0, 520.0, 540.0]
    nodye = dataclasses.replace(config, dye=None).fiber(wl5)
    nodes = absorption_nodes(1.0, 4)
    walks = [fit_structure.walk_structure(nodye, config, wl, nodes, target_rel_err=TARGET, seed=2, threads=None)
             for wl in (wl5, wl3)]
    th = np.array([0.0, 30.0, 45.0, 60.0, 60.0, 30.0])
    to = np.array([20.0, 10.0, 45.0, 60.0, 30.0, 50.0])
    po = np.array([0.0, 180.0, 180.0, 180.0, 0.0, 90.0])
    w_i, w_o = fab.directions_deg(th, np.zeros(6)), fab.directions_deg(to, po)
    facets = fit_structure.facets_of(config)
    full = walks[0].table("k", facets, w_i, w_o)
    read = walks[1].table("k", facets, w_i, w_o, wl5)
    assert read.R.shape == full.R.shape and read.wavelengths_nm.tolist() == wl5.tolist()
    sigma = np.sqrt(full.u_R ** 2 + read.u_R ** 2) + 1e-12 * np.abs(full.R)
    z = (read.R - full.R) / sigma
    assert float(np.max(np.abs(z))) < 5.0, z
    assert abs(float(np.mean(z))) < 4.0 / np.sqrt(z.size) + 0.3
    np.testing.assert_allclose(read.R, full.R, rtol=0.1)
