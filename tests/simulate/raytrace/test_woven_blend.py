"""The woven Monte Carlo of a blend (``[[populations]]``, a mélange yarn): one population is the config without
``[[populations]]`` bit for bit; in single scattering a blend is the share-weighted mix of its populations traced
alone, within standard errors; its record re-weights to the traced run; populations the tracer cannot share a
surface or pile for are refused in one line. A small plain weave of Mie-scattering yarns, one wavelength, fixed
seeds."""

from __future__ import annotations

import numpy as np
import pytest

from simulate import fabric as fab
from simulate import products
from simulate import raytrace as W
from simulate.config import ConfigError, parse_config, weave_from_config
from simulate.geometry.mesh import mesh as weave_mesh

WOVEN = """
seed = 3
[fiber]
radius_um = 10.0
n_host = 1.5
[fiber.dye]
wavelength_nm = [400, 700]
mu_a_per_um = [0.005, 0.005]
[particles]
n = 2.0
radius_um = 0.2
volume_fraction = 0.01
[surface]
rms_slope = 0.35
[weave]
preset = "plain"
spacing_um = 300
width_um = 250
height_um = 100
points_per_span = 6
sides = 12
[structure]
kind = "woven"
"""

DARK = '[populations.fiber.dye]\nwavelength_nm = [400, 700]\nmu_a_per_um = [0.2, 0.2]\n'
WL = np.array([550.0])


def _blend(share: float, extra: str = "") -> str:
    return (WOVEN + f'[[populations]]\nname = "clear"\nshare = {share!r}\n'
            + f'[[populations]]\nname = "dark"\nshare = {1.0 - share!r}\n' + DARK + extra)


def _geometries() -> products.Geometries:
    return products.Geometries(np.array([0.0, 0.0, 45.0]), np.zeros(3), np.array([10.0, 40.0, 30.0]),
                               np.array([0.0, 0.0, 180.0]))


def _run(text: str, target: float = 0.3, record: dict | None = None) -> products.FabricEstimate:
    cfg = parse_config(text, "woven.toml")
    s = products.RunSettings(target=target, seed=3, threads=1, record=record)
    return products.evaluate("mc", cfg, cfg.fiber(WL), _geometries(), WL, s)


def test_one_population_is_the_woven_mc_without_populations_bit_for_bit():
    """The blend's path (each population's pile tables, mixed by share) with one population of share 1 is the
    config's own run at the same seed, bit for bit, and records its population."""
    a, b = _run(WOVEN), _run(WOVEN + '[[populations]]\nshare = 1\n')
    assert a.info["yarn_volume"] == b.info["yarn_volume"] == "pile"
    assert np.array_equal(a.beta, b.beta) and np.array_equal(a.u_beta, b.u_beta)
    assert b.model["populations"] == [{"name": "population 1", "share": 1.0}]


def test_a_two_population_woven_blends_single_scattering_is_the_mix_within_standard_errors():
    """Single scattering (``max_events = 1``: each ray meets one yarn, reflected from its surface or through its
    pile) is linear in the pile's exit table: the surface term is the populations' shared one, and the estimator
    is unbiased whatever reflect-or-enter probability the mixed table gives it, so the blend's expectation is
    exactly the share-weighted mix of the populations traced alone (with more yarn events a path would meet
    several yarns, each drawn afresh, and the mix of products is not the product of the mixes). The blend's
    mixed pile tables against the two populations traced alone on the same weave, seed and photons: within 3
    combined standard errors (taken as independent; the common seeds correlate them positively, which leans
    conservative)."""
    cfg = parse_config(_blend(0.4), "woven.toml")
    pops = products.population_walks(cfg, WL)
    mesh = weave_mesh(weave_from_config(cfg))
    g = _geometries()
    w_i, w_o = fab.directions_deg(g.theta_i, g.phi_i), fab.directions_deg(g.theta_o, g.phi_o)

    def run(populations=None, alone=None):
        fiber = pops[0][1] if alone is None else alone
        beta, u, info = W.fabric_beta(mesh, fiber, w_i, w_o, WL, target_rel_err=0.05, seed=0, threads=1,
                                      structure=cfg.structure, max_events=1, populations=populations)
        assert info["yarn_volume"] == "pile"
        return beta, u

    beta, u = run(populations=pops)
    ba, ua = run(alone=pops[0][1])
    bb, ub = run(alone=pops[1][1])
    expect = 0.4 * ba + 0.6 * bb
    se = np.sqrt(u ** 2 + (0.4 * ua) ** 2 + (0.6 * ub) ** 2)
    assert np.all(np.abs(beta - expect) <= 3.0 * se), (beta, expect, se)
    assert np.all(ba > 3.0 * bb)       # the populations are told apart at these errors
    assert np.all(np.abs(beta - ba) > 5.0 * se) and np.all(np.abs(beta - bb) > 5.0 * se)   # and so is the mix


def test_a_woven_blends_record_re_weights_to_the_traced_run():
    """The dye re-weighting of a recorded woven blend (a Monte Carlo fit's) walks the populations' pile halves
    and mixes them as the trace did: at the traced config it gives the traced result to rounding."""
    record: dict = {}
    traced = _run(_blend(0.4), record=record)
    beta, u, _ = products.reweighted_estimate(record, parse_config(_blend(0.4), "woven.toml"), WL)
    np.testing.assert_allclose(beta, traced.beta, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(u, traced.u_beta, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("extra, field", [
    ('[populations.fiber]\nradius_um = 6\n', "fiber.radius_um"),
    ('[populations.fiber]\nn_host = 1.4\n', "fiber.n_host"),
    ('[populations.surface]\nrms_slope = 0.2\n', "surface.rms_slope"),
])
def test_populations_the_woven_mc_cannot_share_are_refused_in_one_line(extra, field):
    cfg = parse_config(_blend(0.5, extra), "woven.toml")
    with pytest.raises(ConfigError) as e:
        products.check_blend(cfg, "mc")
    assert str(e.value).startswith(f"woven.toml: populations: the woven Monte Carlo traces one {field} for every "
                                   "population, got ") and "\n" not in str(e.value)
    products.check_blend(parse_config(_blend(0.5), "woven.toml"), "mc")     # a dye apart: taken


def test_the_command_refuses_such_a_woven_blend_with_one_line(tmp_path, capsys):
    """`simulate fabric --method mc` (and `auto`, which may choose it) before any work: exit 2, one line."""
    from fabric_optics.cli.simulate import main

    cfg = tmp_path / "woven.toml"
    cfg.write_text(_blend(0.5, '[populations.fiber]\nradius_um = 6\n'))
    plan = tmp_path / "tiny.toml"
    plan.write_text('[sample]\nname = "tiny"\n[wavelengths]\nlist_nm = [550]\n[geometry]\nincidence_deg = [0]\n'
                    'in_plane_deg = [10]\n')
    for method in ("mc", "auto"):
        out = tmp_path / f"out-{method}"
        code = main(["fabric", str(cfg), "--method", method, "--plan", str(plan), "--out", str(out), "--no-progress"])
        err = capsys.readouterr().err.strip()
        assert code == 2 and "\n" not in err, err
        assert "woven.toml: populations: the woven Monte Carlo traces one fiber.radius_um" in err
        assert not out.exists()
