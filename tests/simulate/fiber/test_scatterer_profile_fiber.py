"""Scatterers in a skin or a core, from the config to the fiber's exit tables: the fields read and refused in one
line, the fiber's walk placing its scatterers (the exit table's limits), the cache keys that keep tables of
different placements apart, and the routes that cannot walk a placement refusing it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from simulate.config import ConfigError, parse_config
from simulate.fiber import Fiber, tablecache
from simulate.fiber import farfield as FF
from simulate.fiber.spectral import group_walk, spectral_optics
from simulate.media.medium import HGMedium, MieMedium
from simulate.montecarlo import kernel as K
from simulate.montecarlo.transport import ParameterError

CONFIG = """
[fiber]
radius_um = 10.0
n_host = 1.5
[fiber.dye]
wavelength_nm = [400, 700]
mu_a_per_um = [0.01, 0.01]
[particles]
n = 2.0
radius_um = 0.2
volume_fraction = 0.01
[surface]
rms_slope = 0.35
"""

WL = np.array([550.0])


def _with(extra: str) -> str:
    return CONFIG.replace("n_host = 1.5\n", "n_host = 1.5\n" + extra)


BAD = [
    ('scatterer_profile = "ring"\n',
     'cfg.toml: fiber.scatterer_profile must be one of uniform, skin, core, got "ring"'),
    ('scatterer_depth_um = 2\n', 'cfg.toml: fiber.scatterer_depth_um is for scatterers in a skin or a core: give '
                                 'fiber.scatterer_profile = "skin" or "core", or delete it'),
    ('scatterer_profile = "skin"\n', "cfg.toml: fiber.scatterer_depth_um is required"),
    ('scatterer_profile = "skin"\nscatterer_depth_um = 10\n',
     "cfg.toml: fiber.scatterer_depth_um must be a number > 0 and < 10, got 10"),
    ('scatterer_profile = "core"\nscatterer_depth_um = -1\n',
     "cfg.toml: fiber.scatterer_depth_um must be a number > 0 and < 10, got -1"),
]


@pytest.mark.parametrize("extra, message", BAD, ids=[m[9:50] for _, m in BAD])
def test_every_bad_scatterer_profile_field_is_one_line_naming_it(extra, message):
    with pytest.raises(ConfigError) as e:
        parse_config(_with(extra), "cfg.toml")
    assert str(e.value).startswith(message) and "\n" not in str(e.value), str(e.value)


def test_the_profile_reaches_the_fiber_and_every_population():
    cfg = parse_config(_with('scatterer_profile = "skin"\nscatterer_depth_um = 2.5\n'), "cfg.toml")
    fiber = cfg.fiber(WL)
    assert (fiber.scatterer_profile, fiber.scatterer_depth_um, fiber.scatterer_radius_um) == ("skin", 2.5, 7.5)
    assert (fiber.dye_profile, parse_config(CONFIG, "cfg.toml").fiber(WL).scatterer_profile) == ("uniform", "uniform")
    blend = parse_config(_with('scatterer_profile = "core"\nscatterer_depth_um = 3\n')
                         + '[[populations]]\nshare = 0.5\n[[populations]]\nshare = 0.5\n[populations.fiber]\n'
                           'radius_um = 8\n', "cfg.toml")
    assert [(c.fiber(WL).scatterer_profile, c.fiber(WL).scatterer_radius_um)
            for _, c in blend.population_configs()] == [("core", 7.0), ("core", 5.0)]
    with pytest.raises(ConfigError, match=r"^cfg.toml: populations\[0\].fiber.radius_um must exceed "
                                          r"fiber.scatterer_depth_um \(5\)"):
        parse_config(_with('scatterer_profile = "skin"\nscatterer_depth_um = 5\n')
                     + '[[populations]]\nshare = 1\n[populations.fiber]\nradius_um = 4\n', "cfg.toml")


@pytest.mark.parametrize("fields, name", [({"scatterer_profile": "ring"}, "scatterer_profile"),
                                          ({"scatterer_profile": "skin"}, "scatterer_depth_um"),
                                          ({"scatterer_profile": "core", "scatterer_depth_um": 5.0},
                                           "scatterer_depth_um")])
def test_the_fiber_refuses_a_bad_placement_naming_the_field(fields, name):
    with pytest.raises(ParameterError, match=f"^Fiber: {name}"):
        Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=1.0, mu_a=0.0, g=0.5), roughness=0.3, **fields)


def _fiber(**fields) -> Fiber:
    return Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=0.6, mu_a=0.02, g=0.7), roughness=0.3,
                 cell_width_deg=30.0, **fields)


def test_the_walk_places_the_scatterers_and_the_dye_independently():
    fiber = _fiber(scatterer_profile="skin", scatterer_depth_um=1.5, dye_profile="core", dye_depth_um=0.5)
    medium, _, targets = group_walk(fiber, spectral_optics(fiber, WL), np.array([0]), white=True)
    assert (medium[K.M_SCAT_PROFILE], medium[K.M_SCAT_RADIUS]) == (K.SCAT_SKIN, 3.5)
    assert (medium[K.M_DYE_PROFILE], medium[K.M_DYE_RADIUS]) == (K.DYE_CORE, 4.5)
    assert targets.mu_a_dye is not None and medium[K.M_MU_A] == 0.0
    plain, _, _ = group_walk(_fiber(), spectral_optics(_fiber(), WL), np.array([0]), white=True)
    assert plain[K.M_SCAT_PROFILE] == K.SCAT_UNIFORM


def _albedo(fiber: Fiber) -> np.ndarray:
    table = FF.exit_table(fiber, WL, w_t=(0.0, 0.5), bins=(3, 6), photons_per_row=3000, seed=4, threads=1,
                          cache=False)
    return table.T.sum(axis=(2, 3, 4))[..., 0]       # every row's exited weight per photon


def test_the_exit_table_walks_the_placement_and_its_limits():
    """A skin reaching almost to the axis, or a core under an almost vanishing clear skin, is the uniform fiber's
    table (the same streams: the rare null collisions in the tiny clear part aside); a thin skin of scatterers
    lets more light out (its paths are shorter: less absorbed on the way)."""
    uniform = _albedo(_fiber())
    np.testing.assert_allclose(_albedo(_fiber(scatterer_profile="skin", scatterer_depth_um=5.0 - 1e-7)), uniform,
                               rtol=1e-6)
    np.testing.assert_allclose(_albedo(_fiber(scatterer_profile="core", scatterer_depth_um=1e-7)), uniform,
                               rtol=1e-6)
    thin = _albedo(_fiber(scatterer_profile="skin", scatterer_depth_um=0.5))
    assert np.all(thin.sum(axis=1) > 1.05 * uniform.sum(axis=1)), (thin, uniform)     # over the lit rows


def test_the_exit_table_key_follows_the_placement(cache_dir):
    args = (WL, (0.0, 0.5), (3, 6), 3000, 4, 7)
    keys = {FF.exit_table_key(f, *args) for f in (
        _fiber(), _fiber(scatterer_profile="skin", scatterer_depth_um=1.0),
        _fiber(scatterer_profile="skin", scatterer_depth_um=2.0), _fiber(scatterer_profile="core", scatterer_depth_um=1.0))}
    assert len(keys) == 4 and None not in keys
    # a table stored for a skin is not read for the uniform fiber
    skin = _fiber(scatterer_profile="skin", scatterer_depth_um=0.5)
    FF.exit_table(skin, WL, w_t=(0.0, 0.5), bins=(3, 6), photons_per_row=500, seed=4, threads=1)
    assert len(tablecache.entries(cache_dir)) == 1
    FF.exit_table(dataclasses.replace(skin, scatterer_profile="uniform", scatterer_depth_um=0.0), WL, w_t=(0.0, 0.5),
                  bins=(3, 6), photons_per_row=500, seed=4, threads=1)
    assert len(tablecache.entries(cache_dir)) == 2


def test_routes_that_cannot_walk_a_placement_refuse_it_in_one_line():
    from simulate.fiber import range_outputs, volume_brdf

    skin = _fiber(scatterer_profile="skin", scatterer_depth_um=1.0)
    out = range_outputs([0.0], [1.0], [-3.0], [3.0], skin.half_width)
    with pytest.raises(ParameterError, match="scatterer profile"):
        volume_brdf(skin, np.array([[0.0, 0.0, 1.0]]), None, WL, method="nee", outputs=out, target_rel_err=0.2)
    absorbing = dataclasses.replace(skin, medium=MieMedium(n_host=1.5, particle_n=2.0, particle_k=0.1, radius_um=0.2,
                                                           volume_fraction=0.01))
    with pytest.raises(ParameterError, match=r"^Fiber: scatterer_profile 'skin' takes particles that do not absorb"):
        spectral_optics(absorbing, WL)
