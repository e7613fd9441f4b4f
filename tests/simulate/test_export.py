"""`simulate export`: a fabric model -> RGL .bsdf -> `gonio import rgl-bsdf` and Mitsuba 3, against the
model itself (classic model: cheap and deterministic for a fixed seed)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fabric_optics.cli.gonio import main as gonio_main
from fabric_optics.cli.simulate import main as simulate_main
from gonio.data import read_dataset
from gonio.data.bsdf_export import STATED_TABULATION_ERROR, export_bsdf, random_pairs, tabulation_error
from gonio.data.colour import spectrum_to_rgb
from gonio.data.formats.rgl_bsdf import read_rgl_bsdf
from simulate.config import load_config
from simulate.export import export_model, model_brdf

WL = np.array([450.0, 550.0, 650.0])
RGB_WL = np.arange(400.0, 701.0, 20.0)
TARGET = 0.03


@pytest.fixture(scope="module")
def classic(tmp_path_factory):
    """The classic model at three wavelengths, its spectral export and its linear-sRGB export."""
    cfg = load_config("red-cotton")
    d = tmp_path_factory.mktemp("export")
    spectral, rgb = d / "classic.bsdf", d / "classic_rgb.bsdf"
    # the files from the model callables (export_model, its spectral and --rgb paths, is
    # exercised by the CLI tests): one fiber Monte Carlo per wavelength set; RGB through the
    # linear sRGB matrix
    beta_rgb_wl, _ = model_brdf(cfg, "classic", RGB_WL, target_rel_err=TARGET, seed=0)
    mat = np.stack([spectrum_to_rgb(RGB_WL, e) for e in np.eye(RGB_WL.size)], axis=1)

    def rgb_beta(wi, wo):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return beta_rgb_wl(wi, wo) @ mat.T
    export_bsdf(rgb_beta, rgb, description="red cotton classic, linear sRGB")
    beta, _ = model_brdf(cfg, "classic", WL, target_rel_err=TARGET, seed=0)

    def quiet(wi, wo):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return beta(wi, wo)
    export_bsdf(quiet, spectral, wavelengths_nm=WL, description="red cotton classic")
    return {"spectral": spectral, "rgb": rgb, "beta": quiet, "rgb_beta": rgb_beta, "dir": d}


def _rel(got, ref):
    rel = np.abs(got - ref) / ref
    return float(np.sqrt(np.mean(rel ** 2))), float(rel.max())


def test_round_trip_through_gonio_import(classic, tmp_path):
    """export -> `gonio import rgl-bsdf --plan red-cotton` -> the model's values at the plan's
    geometries (incidence 0/30/45/60, observation -60..70 deg), within the stated error."""
    out = tmp_path / "imported"
    assert gonio_main(["import", "rgl-bsdf", str(classic["spectral"]), "--plan", "red-cotton",
                       "--out", str(out)]) == 0
    t = read_dataset(out).table
    geo = t[t.wavelength_nm == 550.0]
    from gonio.data.geometry import direction
    wi = direction(geo.theta_i.values, geo.phi_i.values)
    wo = direction(geo.theta_o.values, geo.phi_o.values)
    ref = classic["beta"](wi, wo)
    got = np.stack([t[t.wavelength_nm == w].beta.values for w in WL], axis=-1)
    rms, mx = _rel(got, ref)
    bound = STATED_TABULATION_ERROR[80.0]
    assert rms < bound["rms"] and mx < bound["max"]


@pytest.mark.parametrize("theta_max", [60.0, 80.0])
def test_tabulation_error_at_random_pairs(classic, theta_max):
    err = tabulation_error(classic["beta"], classic["spectral"], n_pairs=2000, seed=1, theta_max_deg=theta_max)
    bound = STATED_TABULATION_ERROR[theta_max]
    assert err["rms"] < bound["rms"] and err["p95"] < bound["p95"] and err["max"] < bound["max"]


def test_mitsuba_eval_agrees_with_the_model(classic):
    """Mitsuba 3 (scalar_spectral) loads the export; its eval at 1200 random pairs is the model's
    beta within the stated tabulation error, and equals the project's reader to float32 accuracy."""
    pytest.importorskip("mitsuba")
    from compare.render import mitsuba_eval

    wi, wo = random_pairs(np.random.default_rng(11), 1200, 80.0)
    ev = mitsuba_eval(classic["spectral"], wi, wo)
    got = np.pi * ev / wo[:, 2:]
    rms, mx = _rel(got, classic["beta"](wi, wo))
    bound = STATED_TABULATION_ERROR[80.0]
    assert rms < bound["rms"] and mx < bound["max"]
    np.testing.assert_allclose(ev, read_rgl_bsdf(classic["spectral"]).eval_cos(wi, wo), rtol=2e-4, atol=1e-7)


def test_mitsuba_rgb_export_is_the_models_colour(classic):
    """scalar_rgb on the RGB export: the red channel is the model's (its spectrum through the
    linear sRGB matrix), at 1000 random pairs."""
    pytest.importorskip("mitsuba")
    from compare.render import mitsuba_eval

    wi, wo = random_pairs(np.random.default_rng(12), 1000, 60.0)
    ref = classic["rgb_beta"](wi, wo)
    got = np.pi * mitsuba_eval(classic["rgb"], wi, wo) / wo[:, 2:]
    rms, mx = _rel(got[:, 0], ref[:, 0])         # red: the bright channel of red cotton
    assert rms < STATED_TABULATION_ERROR[60.0]["rms"] and mx < STATED_TABULATION_ERROR[60.0]["max"]
    assert np.all(got[:, 0] > got[:, 1])          # and it is red


#: A valid sampler's p-value is uniform on [0, 1]: it falls below this 0.1 % of the time (the table
#: the sampler draws from is itself Monte Carlo output, so the draw is fixed only up to that noise);
#: a wrong density gives p < 1e-6 (test_sampling_test_detects_a_wrong_density).
P_VALID = 1e-3


@pytest.mark.parametrize("theta_i", [0.0, 35.0, 60.0, 75.0])
def test_mitsuba_sample_is_a_valid_importance_sampler(classic, theta_i):
    """Chi-square of 100 000 sampled directions (20 x 40 cells of cos(theta), phi) against Mitsuba's
    pdf and against the eval-derived density; sample weights are eval / pdf."""
    pytest.importorskip("mitsuba")
    from compare.render import sampling_chi2

    both = sampling_chi2(classic["rgb"], theta_i, n_samples=100_000, seed=int(theta_i), against=("pdf", "eval"))
    for against, r in both.items():
        assert r["p_value"] > P_VALID, (against, r)
        assert r["weight_rel_err_max"] < 1e-4 and r["invalid_fraction"] < 0.01


def test_one_draw_scored_both_ways_equals_two_draws(classic):
    """Scoring one draw against pdf and eval gives each test exactly as a draw of its own would (same seed)."""
    pytest.importorskip("mitsuba")
    from compare.render import sampling_chi2

    small = dict(n_samples=3000, n_cos=6, n_phi=8, sub=2, seed=5)
    both = sampling_chi2(classic["rgb"], 35.0, against=("pdf", "eval"), **small)
    assert set(both) == {"pdf", "eval"}
    for against in ("pdf", "eval"):
        assert both[against] == sampling_chi2(classic["rgb"], 35.0, against=against, **small)
    assert both["pdf"]["chi2"] != both["eval"]["chi2"]      # two densities, not one scored twice
    with pytest.raises(ValueError, match="against"):
        sampling_chi2(classic["rgb"], 35.0, against=("pdf", "cdf"), **small)


def test_sampling_test_detects_a_wrong_density(classic):
    """The chi-square helper rejects a sampler checked against another incidence's density (the same
    sampler against its own density at 60 deg passes: test_mitsuba_sample_is_a_valid_importance_sampler)."""
    pytest.importorskip("mitsuba")
    from compare import render

    # sample at 60 deg, compare with the density at 0 deg by rotating the histogram's reference
    orig = render.load_measured

    def shifted(path):
        mi, bsdf, wl = orig(path)

        class Wrong:
            def sample(self, ctx, si, u1, u2):
                return bsdf.sample(ctx, si, u1, u2)

            def eval(self, ctx, si, v):
                return bsdf.eval(ctx, si, v)

            def pdf(self, ctx, si, v):
                si2 = mi.SurfaceInteraction3f()
                si2.wi = mi.Vector3f(0.0, 0.0, 1.0)
                return bsdf.pdf(ctx, si2, v)
        return mi, Wrong(), wl
    render.load_measured = shifted
    try:
        bad = render.sampling_chi2(classic["rgb"], 60.0, n_samples=50_000, against="pdf")
    finally:
        render.load_measured = orig
    assert bad["p_value"] < 1e-6


def test_cli_export_and_refusals(tmp_path, capsys):
    out = tmp_path / "c.bsdf"
    assert simulate_main(["export", "red-cotton", "--method", "classic", "--out", str(out), "--wavelengths",
                          "450:650:100", "--resolution", "16", "--incidences", "6", "--target-rel-err", "0.05",
                          "--check", "200", "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert "tabulation error at 200 pairs" in said
    tab = read_rgl_bsdf(out)
    assert tab.is_spectral and list(tab.wavelengths_nm) == [450.0, 550.0, 650.0]
    assert tab.theta_i_deg.size == 6
    assert simulate_main(["export", "red-cotton", "--method", "classic", "--out", str(tmp_path / "rgb.bsdf"),
                          "--rgb", "--wavelengths", "400:700:50", "--resolution", "16", "--incidences", "6",
                          "--target-rel-err", "0.05", "--no-progress"]) == 0
    rgb = read_rgl_bsdf(tmp_path / "rgb.bsdf")
    assert not rgb.is_spectral and "linear sRGB" in rgb.description
    red = rgb.beta(0.0, 0.0, 20.0, 180.0)
    assert red[0] > 2 * red[1] and red[0] > 2 * red[2]             # red cotton is red (coarse 50 nm bands)
    assert simulate_main(["export", "red-cotton", "--method", "classic", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    bad = simulate_main(["export", "red-cotton", "--method", "classic", "--out", str(tmp_path / "d.bsdf"),
                         "--wavelengths", "400-700"])       # an argument error: argparse's status
    assert bad == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "START:STOP:STEP" in err


@pytest.mark.slow
@pytest.mark.parametrize("method", ["summation", "mc"])
def test_monte_carlo_models_export_on_reduced_budgets(tmp_path, method):
    """The summation and woven Monte Carlo models export on a small budget (8 x 8 values, 3
    incidences, 10 % Monte Carlo error: 76 s and 40 s here); the file reads back, and at normal
    incidence (a node) it is the model's value within noise plus the coarse tabulation (25 %)."""
    cfg = load_config("red-cotton")
    wl = np.array([650.0])
    res = export_model(cfg, method, tmp_path / f"{method}.bsdf", wavelengths_nm=wl, res=8, incidences=3,
                       target_rel_err=0.1, seed=0, threads=2)
    assert res.evaluations <= 2 * (8 + 3 * 8 * 8)      # two azimuths, only the needed pairs
    tab = read_rgl_bsdf(tmp_path / f"{method}.bsdf")
    wi = np.array([[0.0, 0.0, 1.0]] * 3)
    wo = np.array([[np.sin(a), 0.0, np.cos(a)] for a in np.radians([20.0, 35.0, 50.0])])
    beta, _ = model_brdf(cfg, method, wl, target_rel_err=0.1, seed=1, threads=2)
    ref = 0.5 * (beta(wi, wo) + beta(wi, wo @ np.array([[np.cos(np.pi / 4), -np.sin(np.pi / 4), 0],
                                                         [np.sin(np.pi / 4), np.cos(np.pi / 4), 0],
                                                         [0, 0, 1.0]]).T))
    got = np.pi * tab.eval_cos(wi, wo) / wo[:, 2:]
    np.testing.assert_allclose(got, ref, rtol=0.25)


def test_cli_anisotropic_export(tmp_path, classic):
    """--anisotropic 4: incidence azimuths stored; the (isotropic) classic model comes back the same
    at an incidence azimuth between the stored ones as along x."""
    out = tmp_path / "a.bsdf"
    assert simulate_main(["export", "red-cotton", "--method", "classic", "--out", str(out), "--wavelengths",
                          "450:650:100", "--anisotropic", "4", "--azimuths", "3", "--resolution", "24",
                          "--incidences", "8", "--target-rel-err", str(TARGET), "--seed", "0", "--no-progress"]) == 0
    tab = read_rgl_bsdf(out)
    assert not tab.isotropic and tab.reduction == 4 and tab.phi_i_deg.size == 3
    wi, wo = random_pairs(np.random.default_rng(4), 500, 50.0)
    got = np.pi * tab.eval_cos(wi, wo) / wo[:, 2:]
    rel = np.abs(got - classic["beta"](wi, wo)) / classic["beta"](wi, wo)
    assert np.sqrt(np.mean(rel ** 2)) < 0.05
