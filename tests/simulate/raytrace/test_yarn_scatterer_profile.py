"""Scatterers in a skin or a core through the yarn tables (the felt and woven Monte Carlo): the table walks the
placement, its cache key holds it (a uniform fiber's key is the one it always had), and a felt config with a skin
runs through ``simulate fabric --method mc``."""

from __future__ import annotations

import dataclasses

import numpy as np

from fabric_optics.cli.simulate import main
from gonio.data.dataset import read_dataset
from simulate import fiber as F
from simulate import raytrace as W
from simulate.fiber import tablecache as tc
from simulate.media.medium import HGMedium
from simulate.raytrace import yarn as Y

_SMALL = dict(w_t_nodes=(0.0, 0.5), n_v=1, n_mu=2, n_phi=4)


def _fiber(**placement) -> F.Fiber:
    return F.Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=0.6, mu_a=0.02, g=0.7), roughness=0.3,
                   cell_width_deg=30.0, **placement)


def _exits(fiber: F.Fiber) -> np.ndarray:
    """Each row's exit weight per photon of a small uncached table."""
    table = W.yarn_table(fiber, [550.0], photons_per_row=2000, seed=3, threads=1, cache=False, **_SMALL)
    return table.T.sum(axis=2)[..., 0]


def test_the_yarn_table_walks_the_placement_and_its_limits():
    """A skin reaching almost to the axis, or a core under an almost vanishing clear skin, is the uniform fiber's
    table (the same streams; the rare null collisions in the tiny clear part aside); a thin skin of scatterers lets
    more light out over the lit rows (shorter paths, less absorbed)."""
    uniform = _exits(_fiber())
    np.testing.assert_allclose(_exits(_fiber(scatterer_profile="skin", scatterer_depth_um=5.0 - 1e-7)), uniform,
                               rtol=1e-6)
    np.testing.assert_allclose(_exits(_fiber(scatterer_profile="core", scatterer_depth_um=1e-7)), uniform, rtol=1e-6)
    thin = _exits(_fiber(scatterer_profile="skin", scatterer_depth_um=0.5))
    assert np.all(thin.sum(axis=1) > 1.05 * uniform.sum(axis=1)), (thin, uniform)     # over the lit rows


def test_the_key_holds_the_placement_and_a_uniform_fibers_inputs_are_unchanged(monkeypatch):
    seen: list[dict] = []
    real = tc.content_key

    def spying(kind, inputs, modules):
        seen.append(dict(inputs))
        return real(kind, inputs, modules)

    monkeypatch.setattr(tc, "content_key", spying)
    fibers = [_fiber(), _fiber(scatterer_profile="skin", scatterer_depth_um=1.0),
              _fiber(scatterer_profile="skin", scatterer_depth_um=2.0),
              _fiber(scatterer_profile="core", scatterer_depth_um=1.0)]
    keys = {Y.table_key(f, [550.0], **_SMALL) for f in fibers}
    assert len(keys) == 4
    # the uniform fiber's inputs are exactly those of a key without placements: existing caches stay valid
    assert set(seen[0]) == {"radius_um", "n_host", "cell_width_deg", "medium", "wavelengths_nm", "w_t_nodes", "grid",
                            "photons_per_row", "seed"}
    assert [s.get("scatterer_profile") for s in seen] == [None, ("skin", 1.0), ("skin", 2.0), ("core", 1.0)]


def test_a_stored_skin_table_is_not_read_for_the_uniform_fiber(cache_dir):
    skin = _fiber(scatterer_profile="skin", scatterer_depth_um=0.5)
    kw = dict(_SMALL, photons_per_row=500, seed=4, threads=1)
    assert W.yarn_table(skin, [550.0], **kw).cache == "miss"
    uniform = W.yarn_table(dataclasses.replace(skin, scatterer_profile="uniform", scatterer_depth_um=0.0), [550.0],
                           **kw)
    assert uniform.cache == "miss" and len(tc.entries(cache_dir)) == 2
    again = W.yarn_table(skin, [550.0], **kw)
    assert again.cache == "hit"
    assert again.T.tobytes() != uniform.T.tobytes()


FELT = """
seed = 2
[fiber]
radius_um = 10.0
n_host = 1.5
scatterer_profile = "{profile}"
{depth}
[medium]
mu_s = 0.8
mu_a = 0.05
g = 0.5
[surface]
rms_slope = 0.35
[structure]
kind = "nonwoven"
felt_spread_deg = 15
layers = 4
"""

PLAN = """
[sample]
name = "tiny"
[wavelengths]
list_nm = [550]
[geometry]
incidence_deg = [0]
in_plane_deg = [10, 40]
"""


def test_a_felt_config_with_a_skin_runs_the_monte_carlo(tmp_path, capsys):
    """``simulate fabric --method mc`` on a felt whose fibers hold their scatterers in a 2 um skin: it runs, its
    fibers' tables are the skin's, not the uniform fiber's: at the same seed (the same felt, the same streams) the
    two runs differ by many standard errors (the skin holds 36 % of the section; its fibers scatter less light back
    and pass more through their clear cores, deeper into the absorbing felt)."""
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    profile = "skin"
    beta = {}
    for name, depth in ((profile, "scatterer_depth_um = 2.0"), ("uniform", "")):
        cfg = tmp_path / f"{name}.toml"
        cfg.write_text(FELT.format(profile=name, depth=depth))
        out = tmp_path / name
        assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out),
                     "--target-rel-err", "0.2", "--no-progress", "--threads", "1"]) == 0
        capsys.readouterr()
        table = read_dataset(out).table
        assert len(table) == 2 and np.all(np.isfinite(table["beta"])) and np.all(table["beta"] > 0)
        beta[name] = table.sort_values("theta_o")[["beta", "u_beta"]].to_numpy(float)
    change = beta[profile][:, 0] - beta["uniform"][:, 0]
    assert np.all(np.abs(change) > 5.0 * np.hypot(beta[profile][:, 1], beta["uniform"][:, 1])), (beta, change)
