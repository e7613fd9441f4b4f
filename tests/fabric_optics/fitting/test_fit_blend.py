"""simulate fit of a blend: the populations' dyes and shares freed by name, the share recovered, one population
equal to the fit without populations, a share the data cannot see reported so, and every bad name refused."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.spec import SHARE_MIN, FreeParameter, parse_free, shares_at
from fabric_optics.fitting.start import knots_config
from fabric_optics.paths import toml_dumps
from gonio.data import write_dataset
from simulate.config import load_config, parse_config

from .conftest import WAVELENGTHS, geometry_table, measurement, model_measurement

MAGENTA = {"curve": "gaussian-bands", "baseline_per_um": 0.002,
           "bands": [{"center_nm": 530.0, "width_nm": 40.0, "peak_per_um": 0.5}]}
CYAN = {"curve": "gaussian-bands", "baseline_per_um": 0.002,
        "bands": [{"center_nm": 640.0, "width_nm": 40.0, "peak_per_um": 0.3}]}


def blend_text(populations: list[dict], base: str = "red-cotton", **top) -> str:
    doc = tomllib.loads(load_config(base).text)
    doc["populations"] = populations
    doc.update(top)
    return toml_dumps(doc)


def blend(populations: list[dict], **top):
    return parse_config(blend_text(populations, **top), "blend.toml")


def two(share=0.3, dye_a=MAGENTA, dye_b=CYAN):
    return blend([{"name": "magenta", "share": share, "fiber": {"dye": dye_a}},
                  {"name": "cyan", "share": 1.0 - share, "fiber": {"dye": dye_b}}])


FLAT = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)


# ------------------------------------------------------------------------------------------
# the names


def test_population_names_expand_to_their_paths_and_kinds():
    free = parse_free(["populations.magenta.share,populations.cyan.dye-peaks"], two())
    assert [(p.name, p.kind) for p in free] == [
        ("populations[0].share", "share"),
        ("populations[1].fiber.dye.baseline_per_um", "dye"),
        ("populations[1].fiber.dye.bands[0].peak_per_um", "dye")]
    # two populations: the one free share may take all but SHARE_MIN of the other
    assert (free[0].low, free[0].high) == (SHARE_MIN, pytest.approx(1.0 - SHARE_MIN))
    # the index names the same population as the name
    assert parse_free(["populations[1].share"], two())[0].name == "populations[1].share"


def test_knots_give_each_population_its_own_knots():
    cfg = knots_config(two(), WAVELENGTHS, 6)
    a, b = (p.dye for p in cfg.populations)
    assert a.curve == b.curve == "knots"
    np.testing.assert_allclose(a(np.array([530.0])), MAGENTA["bands"][0]["peak_per_um"] + 0.002, rtol=0.2)
    assert not np.allclose(a.params["log10_per_um"], b.params["log10_per_um"])
    names = [p.name for p in parse_free(["populations.cyan.dye"], cfg)]
    assert names == [f"populations[1].fiber.dye.log10_per_um[{k}]" for k in range(6)]


def test_shares_of_three_populations_the_fixed_ones_take_the_remainder():
    dye = CYAN
    cfg = blend([{"name": "a", "share": 0.2, "fiber": {"dye": dye}}, {"name": "b", "share": 0.2, "fiber": {"dye": dye}},
                 {"name": "c", "share": 0.6, "fiber": {"dye": dye}}])
    free = parse_free(["populations.a.share"], cfg)
    # the fixed populations' default room split among the free shares: 0.2 + (0.8 - 2 SHARE_MIN)
    assert free[0].high == pytest.approx(1.0 - 2 * SHARE_MIN)
    s = shares_at(cfg, free, np.array([0.5]))
    assert s == pytest.approx({0: 0.5, 1: 0.5 * 0.25, 2: 0.5 * 0.75})
    both = parse_free(["populations.a.share,populations.b.share"], cfg)
    assert sum(p.high for p in both) <= 1.0 - SHARE_MIN + 1e-12
    problem = FitProblem(cfg, FLAT, both, method="classic", target_rel_err=0.2, seed=1)
    fitted = parse_config(problem.fitted_toml(np.array([0.1, 0.3]), "x"), "f.toml")
    assert [p.share for p in fitted.populations] == pytest.approx([0.1, 0.3, 0.6])


RING = {"name": "ring", "share": 0.5, "fiber": {"dye": MAGENTA, "dye_profile": "ring", "dye_depth_um": 2.0}}


@pytest.mark.parametrize("config, free, message", [
    (two(), "populations.yellow.share", "no population named 'yellow' (populations: 'magenta', 'cyan'"),
    (blend([{"name": "only", "share": 1.0, "fiber": {"dye": MAGENTA}}]), "populations.only.share",
     "the config has one population, whose share is 1"),
    (load_config("red-cotton"), "populations.x.dye", "the config has no [[populations]]"),
    (two(), "populations.magenta.dye_depth_um", "has a uniform dye, which has no depth"),
    (two(), "populations.magenta.share,populations.cyan.share", "leave one population's share out of --free"),
    (two(), "populations.magenta.fiber.radius_um", "a fit frees a population's dye, share and dye_depth_um"),
    (two(), "dye", "every population of the blend has a dye of its own"),
    (blend([{"name": "a", "share": 0.5}, {"name": "b", "share": 0.5, "fiber": {"dye": CYAN}}]), "populations.a.dye",
     "population 'a' has no dye of its own"),
    (two(), "populations.magenta.share=0:0.5", "a share's lower bound must be above 0"),
    (two(), "populations.magenta.share=0.1:1", "the free shares' upper bounds add up to 1"),
])
def test_bad_population_names_are_refused_in_one_line(config, free, message):
    with pytest.raises(FitError) as exc:
        parse_free([free], config)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_a_populations_own_dye_depth_is_named_and_refused_with_what_to_do():
    """The fit walks one fiber's paths for every population: a population's own depth or placement is refused, the
    depth the populations share (the config's) is freed as fiber.dye_depth_um (tests/fabric_optics/fitting/
    test_fit_depth.py)."""
    cfg = blend([RING, {"name": "plain", "share": 0.5, "fiber": {"dye": CYAN}}])
    free = parse_free(["populations.ring.dye_depth_um"], cfg)
    assert free[0].kind == "walk" and free[0].name == "populations[0].fiber.dye_depth_um"
    with pytest.raises(FitError, match="population 'ring' places its dye otherwise than \\[fiber\\]"):
        FitProblem(cfg, FLAT, free, method="classic")
    with pytest.raises(FitError, match="population 'ring' places its dye otherwise than \\[fiber\\]"):
        FitProblem(cfg, FLAT, parse_free(["populations.plain.dye"], cfg), method="classic")
    # a top cell's summation (no [structure]) scores by next events: refused for any placed dye
    doc = tomllib.loads(blend_text([RING, {"name": "plain", "share": 0.5, "fiber": {"dye": CYAN}}]))
    del doc["structure"]
    flat = parse_config(toml_dumps(doc), "blend.toml")
    with pytest.raises(FitError, match="fiber.dye_profile = 'ring': the summation of a config without \\[structure\\]"):
        FitProblem(flat, FLAT, parse_free(["populations.plain.dye"], flat), method="summation")
    inherits = blend([{"name": "a", "share": 0.5, "fiber": {"dye": MAGENTA}}, {"name": "b", "share": 0.5}],
                     fiber={**tomllib.loads(load_config("red-cotton").text)["fiber"], "dye_profile": "ring",
                            "dye_depth_um": 1.0})
    with pytest.raises(FitError, match="takes fiber.dye_depth_um of the config"):
        parse_free(["populations.a.dye_depth_um"], inherits)
    own = blend([{"name": "a", "share": 0.5, "fiber": {"dye": MAGENTA, "dye_profile": "ring", "dye_depth_um": 1.0}},
                 {"name": "b", "share": 0.5}],
                fiber={**tomllib.loads(load_config("red-cotton").text)["fiber"], "dye_profile": "ring", "dye_depth_um": 1.0})
    with pytest.raises(FitError, match="free the depth they share, fiber.dye_depth_um") as exc:
        FitProblem(own, FLAT, parse_free(["populations.a.dye_depth_um"], own), method="classic")
    assert "\n" not in str(exc.value)


def test_a_blend_of_populations_with_other_scattering_is_refused():
    cfg = blend([{"name": "thin", "share": 0.5, "fiber": {"dye": MAGENTA, "radius_um": 5.0}},
                 {"name": "thick", "share": 0.5, "fiber": {"dye": CYAN}}])
    with pytest.raises(FitError, match="'thin' and 'thick' differ in fiber.radius_um"):
        FitProblem(cfg, FLAT, parse_free(["populations.thin.dye"], cfg), method="classic")


def test_cli_refuses_a_bad_population_name_before_any_work(tmp_path, capsys):
    (tmp_path / "blend.toml").write_text(blend_text([{"name": "magenta", "share": 0.3, "fiber": {"dye": MAGENTA}},
                                                     {"name": "cyan", "share": 0.7, "fiber": {"dye": CYAN}}]))
    write_dataset(FLAT, tmp_path / "m")
    code = main(["fit", str(tmp_path / "blend.toml"), str(tmp_path / "m"), "--free", "populations.red.share",
                 "--out", str(tmp_path / "f")])
    err = capsys.readouterr().err
    assert code == 2 and "no population named 'red'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "f").exists()


# ------------------------------------------------------------------------------------------
# the model and the fits


#: six wavelengths at 20 nm (the fewest with compare's colour terms) and the incidences 0 and 30 deg to 45 deg: the
#: summation's walk of a few seconds
WL6 = np.arange(480.0, 581.0, 20.0)
#: the start blend: a band within WL6 in each population's dye (500 and 570 nm), other peaks and shares than the truth
START = dict(share=0.5, dye_a={**MAGENTA, "bands": [{"center_nm": 500.0, "width_nm": 30.0, "peak_per_um": 1.0}]},
             dye_b={**CYAN, "bands": [{"center_nm": 570.0, "width_nm": 30.0, "peak_per_um": 0.6}]})
FREE3 = ("populations.magenta.share,populations.magenta.fiber.dye.bands[0].peak_per_um=0.05:3,"
         "populations.cyan.fiber.dye.bands[0].peak_per_um=0.05:3")


def _measured6(beta: np.ndarray | float, geometries, noise_seed: int | None = None):
    beta = np.broadcast_to(np.asarray(beta, float), (len(geometries), WL6.size)).copy()
    u = 0.011 * np.abs(beta) + 1e-5
    if noise_seed is not None:
        beta = beta + np.random.default_rng(noise_seed).standard_normal(beta.shape) * u
    g = geometries
    rep = g.loc[g.index.repeat(WL6.size)].reset_index(drop=True)
    table = dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"], phi_o=rep["phi_o"],
                 wavelength_nm=np.tile(WL6, len(g)), beta=beta.ravel(), u_beta=u.ravel(),
                 n=np.ones(beta.size, dtype=int))
    from gonio.data import make_dataset, new_meta

    return make_dataset(table, new_meta("measured", {"name": "synthetic blend"}))


def _geometries():
    g = geometry_table()
    return g[(g["theta_i"] < 45) & (g["theta_o"].abs() <= 45)].reset_index(drop=True)


def _summation(config, measured, free: str, walked=None):
    p = FitProblem(config, measured, parse_free([free], config), method="summation", target_rel_err=0.3, seed=3,
                   wavelengths_nm=WL6)
    if walked is not None:
        p.share_walks(walked)     # the same fiber's scattering: the same walk
    return p


@pytest.fixture(scope="module")
def walked():
    """The summation of the start blend on the small plan, walked once for the module's summation tests."""
    p = _summation(two(**START), _measured6(0.3, _geometries()), FREE3)
    p.model(p.start)
    return p


def test_the_blend_model_is_the_share_mix_of_its_populations(walked):
    """The summation's blend: the share-weighted mix of each population's model alone (as simulate fabric mixes)."""
    flat = walked.measured
    p = _summation(two(), flat, "populations.magenta.share", walked)
    beta, u = p.model(np.array([0.3]))
    parts = []
    red = tomllib.loads(load_config("red-cotton").text)
    for dye in (MAGENTA, CYAN):
        one = parse_config(toml_dumps({**red, "fiber": {**red["fiber"], "dye": dye}}), "one.toml")
        parts.append(_summation(one, flat, "rms_slope", walked).model(np.array([one.rms_slope])))
    np.testing.assert_allclose(beta, 0.3 * parts[0][0] + 0.7 * parts[1][0], rtol=1e-12)
    np.testing.assert_allclose(u, 0.3 * parts[0][1] + 0.7 * parts[1][1], rtol=1e-12)
    assert walked.counters.walks == 1 and p.counters.walks == 0     # one walk serves every population


@pytest.mark.slow
def test_a_blend_fit_recovers_the_share_from_the_summation(walked):
    """A measurement made by the summation from a known blend (shares 0.3/0.7, two dyes of bands at 500 and 570 nm,
    mock-level noise) is fitted from shares 0.5/0.5 and another peak of the second dye: the share comes back within
    3 of its reported u, and the start's share lies beyond that."""
    beta, _ = walked.model(np.array([0.3, 1.0, 0.9]))
    free = "populations.magenta.share,populations.cyan.fiber.dye.bands[0].peak_per_um=0.05:3"
    problem = _summation(two(**START), _measured6(beta, walked.geometries, noise_seed=11), free, walked)
    result = run_fit(problem, noise_draws=16, max_evaluations=60)
    assert result.objective < result.objective_start
    assert result.info["u_status"] == ["", ""] and 0 < result.u[0] < 0.05, result.u
    assert abs(result.x[0] - 0.3) < 3 * result.u[0], (result.x, result.u)
    assert abs(result.x[1] - 0.9) < 3 * result.u[1], (result.x, result.u)
    assert abs(result.x[0] - 0.5) > 3 * result.u[0]         # the start's share is told apart


def test_one_population_by_its_name_is_the_fit_without_populations_bit_for_bit(red_cotton):
    """``--free populations.NAME.dye`` of a one-population config is ``--free dye`` of the config without it."""
    plain = knots_config(red_cotton, WAVELENGTHS, 5)
    doc = tomllib.loads(plain.text)
    doc["populations"] = [{"name": "only", "share": 1.0, "fiber": {"dye": doc["fiber"]["dye"]}}]
    one = parse_config(toml_dumps(doc), "one.toml")
    measured = measurement(lambda g, wl: np.full((len(g), wl.size), 0.2) + 0.001 * wl[None, :] / 7, 4)
    results = []
    for cfg, free in ((plain, "dye"), (one, "populations.only.dye")):
        problem = FitProblem(cfg, measured, parse_free([free], cfg), method="classic", target_rel_err=0.1, seed=4,
                             hold_colour=True)
        results.append(run_fit(problem, noise_draws=8, max_evaluations=60))
    a, b = results
    assert np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u, equal_nan=True)
    assert a.objective == b.objective and a.info["start_note"] == b.info["start_note"]
    assert not np.array_equal(a.x, a.start)        # the fit moved: the equality is of two searches


def test_a_share_the_data_cannot_see_is_not_identifiable(tmp_path, capsys):
    """Two identical populations: their share changes nothing, and fit.json and the command line say so."""
    same = [{"name": "a", "share": 0.4, "fiber": {"dye": MAGENTA}}, {"name": "b", "share": 0.6, "fiber": {"dye": MAGENTA}}]
    (tmp_path / "same.toml").write_text(blend_text(same))
    cfg = load_config(tmp_path / "same.toml")
    truth = FitProblem(cfg, FLAT, parse_free(["rms_slope"], cfg), method="classic", target_rel_err=0.15, seed=2)
    write_dataset(model_measurement(truth, [0.3], noise_seed=6), tmp_path / "m")
    out = tmp_path / "fit"
    code = main(["fit", str(tmp_path / "same.toml"), str(tmp_path / "m"), "--method", "classic", "--free",
                 "populations.a.share,rms_slope=0.1:0.8", "--max-evaluations", "20", "--target-rel-err", "0.15",
                 "--seed", "2", "--no-progress", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 0
    doc = json.loads((out / "fit.json").read_text())
    share = next(p for p in doc["parameters"] if p["name"] == "populations[0].share")
    slope = next(p for p in doc["parameters"] if p["name"] == "surface.rms_slope")
    assert share["u"] is None and share["u_status"] == "not identifiable"
    assert slope["u_status"] == "" and slope["u"] > 0
    line = next(ln for ln in printed.splitlines() if ln.startswith("populations[0].share = "))
    assert "not identifiable" in line
    fitted = load_config(out / "fitted.toml")
    assert sum(p.share for p in fitted.populations) == pytest.approx(1.0, abs=1e-9)


def test_the_mc_fit_surrogate_mixes_a_blend_as_the_summation(walked):
    """The Monte Carlo fit's surrogate (the summation, corrected) takes a blend: with no correction it is the
    coarse model's mix (the surrogate alone, on the walked cotton)."""
    from fabric_optics.fitting.spacemapping import MCFitProblem, Surrogate

    cfg = two()
    free = [FreeParameter("populations[0].share", 0.3, SHARE_MIN, 1 - SHARE_MIN, "share")]
    base = MCFitProblem(cfg, walked.measured, free, method="mc", target_rel_err=0.3, seed=3, wavelengths_nm=WL6)
    base.share_walks(walked)
    s = Surrogate(base, np.array([0.3]), (1.0, 0.0, 0.0))
    beta, _ = s.model(np.array([0.45]))
    ref, _ = base.model(np.array([0.45]))
    np.testing.assert_array_equal(beta, ref)
    assert base.counters.walks == 0


def test_the_mc_fit_refuses_a_blend_the_woven_monte_carlo_cannot_trace():
    """The woven Monte Carlo traces a blend whose populations share one surface term: one of two reflection slopes
    is refused before any walk, in one line naming the field."""
    from fabric_optics.fitting.spacemapping import MCFitProblem

    cfg = blend([{"name": "magenta", "share": 0.3, "fiber": {"dye": MAGENTA}, "surface": {"rms_slope": 0.2}},
                 {"name": "cyan", "share": 0.7, "fiber": {"dye": CYAN}}])         # red cotton: woven
    with pytest.raises(FitError, match="^--method mc: .*populations: the woven Monte Carlo traces one "
                                       "surface.rms_slope for every population") as e:
        MCFitProblem(cfg, FLAT, parse_free(["populations.magenta.share"], cfg), method="mc")
    assert "\n" not in str(e.value)


def test_a_field_a_population_overrides_is_not_freed_in_the_config():
    cfg = blend([{"name": "a", "share": 0.5, "fiber": {"dye": MAGENTA}, "surface": {"rms_slope": 0.25}},
                 {"name": "b", "share": 0.5, "fiber": {"dye": CYAN}, "surface": {"rms_slope": 0.25}}])
    with pytest.raises(FitError, match="population 'a' sets its own surface.rms_slope, which this field of the config "
                                       "would not move"):
        parse_free(["rms_slope"], cfg)
    assert parse_free(["volume_fraction"], cfg)[0].kind == "walk"       # one the populations take from the config
