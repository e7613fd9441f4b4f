"""Fiber populations (``[[populations]]``): one population is the config without them, bit for bit; a blend is
the share-weighted mix of its populations (exactly for the summation, within standard errors for the felt Monte
Carlo's single scattering); every bad field is one line naming it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from simulate import fabric as fab
from simulate import products
from simulate import raytrace as W
from simulate.config import ConfigError, parse_config, require_single_population
from simulate.geometry.felt import felt_mesh

FELT = """
seed = 2
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
[structure]
kind = "nonwoven"
felt_spread_deg = 15
layers = 4
"""

DARK = """
[populations.fiber.dye]
wavelength_nm = [400, 700]
mu_a_per_um = [0.2, 0.2]
"""


def _blend(share: float) -> str:
    return (FELT + f'[[populations]]\nname = "clear"\nshare = {share!r}\n'
            + f'[[populations]]\nname = "dark"\nshare = {1.0 - share!r}\n' + DARK)


def _geometries() -> products.Geometries:
    t_i = np.array([0.0, 0.0, 45.0])
    t_o = np.array([10.0, 40.0, 30.0])
    p_o = np.array([0.0, 0.0, 180.0])
    return products.Geometries(t_i, np.zeros(3), t_o, p_o)


WL = np.array([550.0])


def _run(method: str, text: str, target: float, seed: int = 2) -> products.FabricEstimate:
    cfg = parse_config(text, "felt.toml")
    s = products.RunSettings(target=target, seed=seed, threads=1)
    return products.evaluate(method, cfg, cfg.fiber(WL), _geometries(), WL, s)


def test_a_config_without_populations_reads_as_before_and_is_its_own_only_population():
    cfg = parse_config(FELT, "felt.toml")
    assert cfg.populations is None and cfg.population_configs() == [(1.0, cfg)]
    one = parse_config(FELT + '[[populations]]\nshare = 1\n', "felt.toml")
    assert one.populations is not None and one.populations[0].name == "population 1"
    (share, only), = one.population_configs()
    assert share == 1.0 and only.populations is None
    # the population's config is the config without [[populations]], field by field
    assert only == dataclasses.replace(cfg, text=one.text, sha256=one.sha256)


def test_a_population_overrides_the_fiber_and_keeps_the_rest():
    cfg = parse_config(_blend(0.25) + '[populations.surface]\ntransmission_rms_slope = 0.2\n'
                       '[populations.fiber]\nradius_um = 10.0\n', "felt.toml")
    (s0, a), (s1, b) = cfg.population_configs()
    assert (s0, s1) == (0.25, 0.75) and [p.name for p in cfg.populations] == ["clear", "dark"]
    assert a.dye == parse_config(FELT, "felt.toml").dye
    assert float(b.dye(550.0)) == pytest.approx(0.2) and b.transmission_rms_slope == 0.2
    assert a.transmission_rms_slope == 0.0 and b.particles == a.particles and b.rms_slope == a.rms_slope


def test_one_population_is_the_summation_and_the_felt_mc_without_populations_bit_for_bit():
    """The blend's code path (the summation's mix, the Monte Carlo's mixed tables) with one population of
    share 1 gives today's numbers at the same seed, bit for bit."""
    one = FELT + '[[populations]]\nshare = 1\n'
    for method, target in (("summation", 0.2), ("mc", 0.3)):
        a, b = _run(method, FELT, target), _run(method, one, target)
        assert np.array_equal(a.beta, b.beta) and np.array_equal(a.u_beta, b.u_beta), method
        assert b.model["populations"] == [{"name": "population 1", "share": 1.0}] or method == "summation"


def test_a_two_population_summation_is_the_share_weighted_mix_of_its_populations():
    """Exact: the summation is linear in its fiber's layer tables, so the blend at a seed equals its two
    populations, each traced alone at that seed, mixed by share."""
    dark_alone = FELT.replace("mu_a_per_um = [0.01, 0.01]", "mu_a_per_um = [0.2, 0.2]")
    clear, dark = _run("summation", FELT, 0.2), _run("summation", dark_alone, 0.2)
    mix = _run("summation", _blend(0.3), 0.2)
    assert not np.allclose(clear.beta, dark.beta, rtol=0.05)       # the populations differ
    np.testing.assert_allclose(mix.beta, 0.3 * clear.beta + 0.7 * dark.beta, rtol=1e-12, atol=0.0)
    assert [p["name"] for p in mix.model["populations"]] == ["clear", "dark"]


def test_the_felt_mc_mixes_its_populations_tables_by_share_exactly():
    cfg = parse_config(_blend(0.3), "felt.toml")
    s = products.RunSettings(target=0.3, seed=2, threads=1)
    fibers = [c.fiber(WL) for _, c in cfg.population_configs()]
    mixed = products.felt_population_tables(cfg, fibers[0], WL, s, (5, 10))
    grid = {"n_mu": 5, "n_phi": 10, "w_t_nodes": cfg.w_t_nodes()}
    halves = [W.table_halves(f, WL, W.table_photons(0.3) // 2, 2, 1, **grid) for f in fibers]
    for h in range(2):
        np.testing.assert_allclose(mixed[h].T, 0.3 * halves[0][h].T + 0.7 * halves[1][h].T, rtol=1e-12, atol=0.0)
        assert mixed[h].photons == halves[0][h].photons + halves[1][h].photons


def test_a_two_population_felts_single_scattering_is_the_mix_within_standard_errors():
    """The felt's first fiber event with the blend's mixed tables against the two populations traced alone on the
    same felts (single scattering, ``max_events = 1``), mixed by share: within 3 combined standard errors."""
    cfg = parse_config(_blend(0.4), "felt.toml")
    spec = cfg.structure
    target = 0.1
    s = products.RunSettings(target=target, seed=0, threads=1)
    (_, a), (_, b) = cfg.population_configs()
    fa, fb = a.fiber(WL), b.fiber(WL)
    mixed = products.felt_population_tables(cfg, fa, WL, s, (5, 10))
    grid = {"n_mu": 5, "n_phi": 10, "w_t_nodes": cfg.w_t_nodes()}
    meshes = (felt_mesh(spec, 10.0, seed=0), felt_mesh(spec, 10.0, seed=1))
    g = _geometries()
    w_i, w_o = fab.directions_deg(g.theta_i, g.phi_i), fab.directions_deg(g.theta_o, g.phi_o)

    def run(fiber, tables):
        return W.fabric_beta(meshes, fiber, w_i, w_o, WL, target_rel_err=target, seed=0, threads=1, tables=tables,
                             structure=spec, max_events=1)[:2]

    beta, u = run(fa, mixed)
    ba, ua = run(fa, W.table_halves(fa, WL, W.table_photons(target) // 2, 0, 1, **grid))
    bb, ub = run(fb, W.table_halves(fb, WL, W.table_photons(target) // 2, 0, 1, **grid))
    expect = 0.4 * ba + 0.6 * bb
    se = np.sqrt(u ** 2 + (0.4 * ua) ** 2 + (0.6 * ub) ** 2)
    assert np.all(np.abs(beta - expect) <= 3.0 * se), (beta, expect, se)
    assert np.all(ba > 1.2 * bb)       # the populations are told apart at these errors


BAD = [
    ('[[populations]]\nshare = 0.5\n', "felt.toml: populations shares must add up to 1, got 0.5 (0.5)"),
    ('[[populations]]\nname = "a"\n', "felt.toml: populations[0].share is required"),
    ('[[populations]]\nshare = 0\n', "felt.toml: populations[0].share must be a number > 0 and <= 1, got 0"),
    ('[[populations]]\nshare = 1.5\n', "felt.toml: populations[0].share must be a number > 0 and <= 1, got 1.5"),
    ('[[populations]]\nshare = "half"\n', 'felt.toml: populations[0].share must be a number > 0 and <= 1, got "half"'),
    ('populations = 3\n', "felt.toml: populations must be an array of tables ([[populations]], one per population), "
                          "got 3"),
    ('populations = []\n', "felt.toml: populations must be an array of tables ([[populations]], one per population), "
                           "got []"),
    ('[[populations]]\nshare = 1\nshar = 2\n', "felt.toml: populations[0].shar is not a known field (did you mean share?)"),
    ('[[populations]]\nshare = 1\n[populations.fiber]\nradius = 3\n',
     "felt.toml: populations[0].fiber.radius is not a known field (did you mean radius_um?)"),
    ('[[populations]]\nshare = 1\n[populations.fiber]\nradius_um = -3\n',
     "felt.toml: populations[0].fiber.radius_um must be a number > 0 and <= 10000, got -3"),
    ('[[populations]]\nshare = 1\n[populations.surface]\nrms_slope = 2\n',
     "felt.toml: populations[0].surface.rms_slope must be a number > 0 and <= 1, got 2"),
    ('[[populations]]\nshare = 1\n[populations.fiber.dye]\ncurve = "knots"\n',
     "felt.toml: populations[0].fiber.dye.wavelength_nm is required"),
    ('[[populations]]\nshare = 1\n[populations.particles]\nn = 2\n',
     "felt.toml: populations[0].particles.radius_um or particles.size: give exactly one"),
    ('[[populations]]\nname = "a"\nshare = 0.5\n[[populations]]\nname = "a"\nshare = 0.5\n',
     'felt.toml: populations[1].name repeats "a": give each population its own name'),
]


@pytest.mark.parametrize("extra, message", BAD, ids=[m[11:50] for _, m in BAD])
def test_every_bad_population_field_is_one_line_naming_it(extra, message):
    with pytest.raises(ConfigError) as e:
        # a top-level key goes before the config's first table
        parse_config(extra + FELT if extra.startswith("populations =") else FELT + extra, "felt.toml")
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_a_population_cannot_override_a_henyey_greenstein_medium():
    hg = FELT.replace("[fiber.dye]\nwavelength_nm = [400, 700]\nmu_a_per_um = [0.01, 0.01]\n", "").replace(
        "[particles]\nn = 2.0\nradius_um = 0.2\nvolume_fraction = 0.01\n", "[medium]\nmu_s = 0.5\nmu_a = 0.01\ng = 0.5\n")
    with pytest.raises(ConfigError, match=r"^felt.toml: populations\[0\].fiber.dye cannot be combined with \[medium\]"):
        parse_config(hg + '[[populations]]\nshare = 1\n' + DARK, "felt.toml")


def test_a_blend_is_refused_where_one_fiber_is_taken_with_one_line():
    cfg = parse_config(_blend(0.5), "felt.toml")
    with pytest.raises(ConfigError) as e:
        require_single_population(cfg, "simulate fit")
    assert str(e.value) == ("felt.toml: populations: simulate fit takes one fiber population, this config has 2 "
                            "(clear, dark); give one population or none")
    require_single_population(parse_config(FELT, "felt.toml"), "simulate fit")             # none: accepted
    require_single_population(parse_config(FELT + '[[populations]]\nshare = 1\n', "felt.toml"), "simulate fit")
    # the felt Monte Carlo traces one radius: populations that differ in it are refused, naming the field
    other = parse_config(_blend(0.5) + '[populations.fiber]\nradius_um = 6\n', "felt.toml")
    with pytest.raises(ConfigError, match=r"^felt.toml: populations: the felt Monte Carlo traces one fiber.radius_um"):
        products.felt_population_tables(other, other.population_configs()[0][1].fiber(WL), WL,
                                        products.RunSettings(target=0.3, seed=0, threads=1), (5, 10))


BAD_PROFILE = [
    ('dye_profile = "skin"\n', 'felt.toml: fiber.dye_profile must be one of uniform, ring, core, got "skin"'),
    ('dye_depth_um = 2\n', 'felt.toml: fiber.dye_depth_um is for a ring or core dye: give fiber.dye_profile = "ring" '
                           'or "core", or delete it'),
    ('dye_profile = "ring"\n', "felt.toml: fiber.dye_depth_um is required"),
    ('dye_profile = "ring"\ndye_depth_um = 10\n', "felt.toml: fiber.dye_depth_um must be a number > 0 and < 10, got 10"),
    ('dye_profile = "core"\ndye_depth_um = 0\n', "felt.toml: fiber.dye_depth_um must be a number > 0 and < 10, got 0"),
]


@pytest.mark.parametrize("extra, message", BAD_PROFILE, ids=[m[11:45] for _, m in BAD_PROFILE])
def test_every_bad_dye_profile_field_is_one_line_naming_it(extra, message):
    with pytest.raises(ConfigError) as e:
        parse_config(FELT.replace("n_host = 1.5\n", "n_host = 1.5\n" + extra), "felt.toml")
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_a_dye_profile_reaches_the_fiber_and_needs_a_dye_to_place():
    cfg = parse_config(FELT.replace("n_host = 1.5\n", 'n_host = 1.5\ndye_profile = "ring"\ndye_depth_um = 1.5\n'),
                       "felt.toml")
    fiber = cfg.fiber(WL)
    assert (fiber.dye_profile, fiber.dye_depth_um, fiber.dye_radius_um) == ("ring", 1.5, 8.5)
    assert parse_config(FELT, "felt.toml").fiber(WL).dye_profile == "uniform"
    # a population places its own dye
    blend = parse_config(_blend(0.5) + '[populations.fiber]\ndye_profile = "core"\ndye_depth_um = 3\n', "felt.toml")
    assert [c.fiber(WL).dye_profile for _, c in blend.population_configs()] == ["uniform", "core"]
    no_dye = FELT.replace("[fiber.dye]\nwavelength_nm = [400, 700]\nmu_a_per_um = [0.01, 0.01]\n", "")
    with pytest.raises(ConfigError, match=r"^felt.toml: fiber.dye_profile places the fiber's dye"):
        parse_config(no_dye.replace("n_host = 1.5\n", 'n_host = 1.5\ndye_profile = "ring"\ndye_depth_um = 1\n'),
                     "felt.toml")
    with pytest.raises(ConfigError, match=r"^felt.toml: populations\[0\].fiber.radius_um must exceed fiber.dye_depth_um"):
        parse_config(FELT.replace("n_host = 1.5\n", 'n_host = 1.5\ndye_profile = "ring"\ndye_depth_um = 5\n')
                     + '[[populations]]\nshare = 1\n[populations.fiber]\nradius_um = 4\n', "felt.toml")


def test_the_commands_refuse_a_blend_they_cannot_trace_with_one_line(tmp_path, capsys):
    """Before any work: `simulate fabric --method mc` with populations of two radii, `simulate fiber` with a blend."""
    from fabric_optics.cli.simulate import main

    cfg = tmp_path / "felt.toml"
    cfg.write_text(_blend(0.5) + '[populations.fiber]\nradius_um = 6\n')
    plan = tmp_path / "tiny.toml"
    plan.write_text('[sample]\nname = "tiny"\n[wavelengths]\nlist_nm = [550]\n[geometry]\nincidence_deg = [0]\n'
                    'in_plane_deg = [10]\n')
    code = main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(tmp_path / "out"),
                 "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "populations: the felt Monte Carlo traces one fiber.radius_um" in err
    assert not (tmp_path / "out").exists()
    code = main(["fiber", str(cfg), "--out", str(tmp_path / "fiber")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "populations: simulate fiber takes one fiber population" in err
