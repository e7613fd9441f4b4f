"""simulate fit: recovery with coverage, dye re-weighting, errors before work, CLI, resume, identifiability."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.spec import parse_free
from fabric_optics.fitting.state import STATE_NAME
from fabric_optics.fitting.uncertainty import jacobian
from fabric_optics.paths import toml_dumps
from gonio.data import read_dataset, write_dataset
from simulate import fiber as fib
from simulate.config import load_config, parse_config
from simulate.fiber.absorption import absorption_nodes, absorption_table

from .conftest import WAVELENGTHS, measurement, model_measurement, sibling


def test_absorption_table_interpolates_between_nodes_from_the_same_photons(red_cotton):
    """A table read between nodes equals a table holding that absorption as a node (same photons)."""
    wl = np.array([450.0, 650.0])
    nodye = dataclasses.replace(red_cotton, dye=None).fiber(wl)
    out = fib.range_outputs([0.0], [1.0], [-math.pi], [math.pi], nodye.half_width)
    win = np.array([[0.0, 0.0, 1.0]])
    nodes = absorption_nodes(2.0)
    tab = absorption_table(nodye, win, out, wl, nodes, method="beam", target_rel_err=0.1, seed=3, max_photons=20_000)
    for star in (0.002, 0.05, 0.4):
        nodes2 = np.sort(np.r_[nodes, star])
        tab2 = absorption_table(nodye, win, out, wl, nodes2, method="beam", photons=tab.photons, seed=3)
        exact = tab2.R[0, :, int(np.flatnonzero(nodes2 == star)[0])]
        R, u = tab(np.full(2, star))
        np.testing.assert_allclose(R[0], exact, rtol=3e-3)
        assert np.all(u[0] > 0)
    with pytest.raises(ValueError, match="outside"):
        tab(np.full(2, 3.0))


def test_model_dye_change_does_not_walk_again(base_problem):
    p = base_problem
    p.model(p.start)
    walks = p.counters.walks
    x = p.start.copy()
    x[0] *= 1.3  # the 520 nm band's peak
    beta0, _ = p.model(p.start)
    beta1, _ = p.model(x)
    assert p.counters.walks == walks
    assert not np.allclose(beta0, beta1)


def test_recovery_within_reported_uncertainties_over_seeds(base_problem):
    """Synthesised measurements (mock-level noise) at known parameters are fitted back within u."""
    x_true = np.array([1.4, 0.25])
    z = []
    for seed in range(4):
        problem = sibling(base_problem, model_measurement(base_problem, x_true, noise_seed=100 + seed))
        result = run_fit(problem, noise_draws=16)
        assert result.objective < result.objective_start
        assert np.all(result.u > 0)
        z.append((result.x - x_true) / result.u)
        assert np.all(np.abs(result.correlation) <= 1.0 + 1e-9)
    z = np.array(z)
    assert np.all(np.abs(z) < 3.5), z
    # the Monte Carlo part of u cannot scatter the fit here (same photons): coverage is conservative
    assert float(np.sqrt(np.mean(z ** 2))) < 1.6, z


def test_no_noise_fits_the_true_point_exactly(base_problem):
    x_true = np.array([0.8, 0.42])
    problem = sibling(base_problem, model_measurement(base_problem, x_true, noise_seed=None))
    result = run_fit(problem, noise_draws=8)
    np.testing.assert_allclose(result.x, x_true, rtol=2e-3)
    assert result.objective < 1e-8


def test_objective_is_compares_nrmse_and_colour(base_problem):
    from compare.comparison import compare_datasets

    problem = sibling(base_problem, model_measurement(base_problem, [1.4, 0.25], noise_seed=1))
    beta, u = problem.model(problem.start)
    sim = problem.dataset(beta, u, "x")
    c = compare_datasets(problem.measured, [sim])
    name = next(iter(c.frames))
    r = problem.residuals(problem.start)
    colour = c.colour.simulated[name]
    expected = c.overall[name].nrmse ** 2 + colour.dh ** 2 + colour.ds ** 2
    assert float(r @ r) == pytest.approx(expected, rel=1e-12)


def test_flat_direction_is_warned(red_cotton):
    """A band with zero peak: its centre changes nothing and is named as not identifiable."""
    assert "center_nm = 490, width_nm = 32, peak_per_um = 0.62" in red_cotton.text  # the preset's band
    text = red_cotton.text.replace("center_nm = 490, width_nm = 32, peak_per_um = 0.62",
                                   "center_nm = 490, width_nm = 32, peak_per_um = 0.0")
    config = parse_config(text, "flat.toml")
    free = parse_free(["fiber.dye.bands[1].center_nm,fiber.dye.bands[0].peak_per_um=0.3:3"], config)
    probe = FitProblem(config, measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None), free,
                       target_rel_err=0.05, seed=2)
    problem = sibling(probe, model_measurement(probe, [490.0, 1.2], noise_seed=4))
    result = run_fit(problem, noise_draws=8, max_evaluations=10)
    assert any("not identifiable" in w and "bands[1].center_nm" in w for w in result.warnings)
    assert not any("bands[0].peak_per_um" in w for w in result.warnings)


@pytest.mark.parametrize("spec, message", [
    ("particles.volume_fractoin", "unknown parameter"),
    ("surface.rms_slope=0.5:0.9", "outside its bounds"),
    ("surface.rms_slope=0.9:0.5", "LOW < HIGH"),
    ("surface.rms_slope=a:b", "LOW < HIGH"),
    ("name", "not a number"),
    ("method.target_rel_err", "run setting"),
    ("rms_slope,surface.rms_slope", "named twice"),
])
def test_parse_free_errors(red_cotton, spec, message):
    with pytest.raises(FitError, match=message):
        parse_free([spec], red_cotton)


def test_parse_free_aliases_and_default_bounds(red_cotton):
    free = parse_free(["dye-peaks", "volume_fraction", "radius", "rms_slope"], red_cotton)
    names = [p.name for p in free]
    assert names == ["fiber.dye.baseline_per_um", "fiber.dye.bands[0].peak_per_um",
                     "fiber.dye.bands[1].peak_per_um", "particles.volume_fraction",
                     "particles.size.median_radius_um", "surface.rms_slope"]
    kinds = {p.name: p.kind for p in free}
    assert kinds["particles.volume_fraction"] == "walk" and kinds["surface.rms_slope"] == "surface"
    assert all(p.low <= p.start <= p.high for p in free)
    table_dye = parse_config("[fiber]\nradius_um = 5\nn_host = 1.5\n[fiber.dye]\nwavelength_nm = [400, 700]\n"
                             "mu_a_per_um = [0.1, 0.0]\n[medium]\nmu_s = 1\nmu_a = 0\ng = 0\n"
                             "[surface]\nrms_slope = 0.3\n".replace("[fiber.dye]\nwavelength_nm = [400, 700]\n"
                                                                    "mu_a_per_um = [0.1, 0.0]\n", ""), "t.toml")
    with pytest.raises(FitError, match="absent"):
        parse_free(["dye"], table_dye)


def test_fitted_config_round_trips(red_cotton, base_problem):
    import tomllib

    doc = tomllib.loads(red_cotton.text)
    assert tomllib.loads(toml_dumps(doc)) == doc
    text = base_problem.fitted_toml(np.array([1.3, 0.3]), "note")
    cfg = parse_config(text, "fitted.toml")
    assert cfg.dye is not None and cfg.dye.params["bands"][0]["peak_per_um"] == 1.3
    assert cfg.rms_slope == 0.3


# ------------------------------------------------------------------------------------------
# the command line


def _write_measurement(tmp_path, base_problem, x_true=(1.4, 0.25), seed=7):
    ds = model_measurement(base_problem, x_true, noise_seed=seed)
    write_dataset(ds, tmp_path / "measured")
    return tmp_path / "measured"


@pytest.mark.parametrize("free, message", [
    ("particles.nope", "unknown parameter"),
    ("surface.rms_slope=0.5:0.9", "outside its bounds"),
])
def test_cli_errors_before_any_work(tmp_path, capsys, base_problem, free, message):
    measured = _write_measurement(tmp_path, base_problem)
    code = main(["fit", "red-cotton", str(measured), "--free", free, "--out", str(tmp_path / "fit")])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "fit").exists()


def test_cli_refuses_a_measurement_without_the_normal_neighbours(tmp_path, capsys):
    from .conftest import geometry_table

    g = geometry_table()
    g = g[g["theta_i"] > 0].reset_index(drop=True)  # no normal incidence: no normalisation point
    write_dataset(measurement(lambda gg, wl: np.full((len(gg), wl.size), 0.3), 1, geometries=g),
                  tmp_path / "m")
    code = main(["fit", "red-cotton", str(tmp_path / "m"), "--free", "rms_slope", "--out", str(tmp_path / "f")])
    err = capsys.readouterr().err
    assert code == 2 and "normal" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "f").exists()


def test_cli_end_to_end_and_resume(tmp_path, capsys, monkeypatch, base_problem):
    from fabric_optics.fitting import search

    # the uncertainty from 8 noise draws, not 64: asserted here is that it is there (u > 0), not its value
    monkeypatch.setitem(search.run_fit.__kwdefaults__, "noise_draws", 8)
    measured = _write_measurement(tmp_path, base_problem)
    out = tmp_path / "fit"
    args = ["fit", "red-cotton", str(measured), "--free", "fiber.dye.bands[0].peak_per_um=0.3:3,rms_slope=0.1:0.8",
            "--out", str(out), "--seed", "5", "--target-rel-err", "0.1", "--no-progress"]
    assert main(args + ["--max-evaluations", "12"]) == 0
    state = json.loads((out / STATE_NAME).read_text())
    doc = json.loads((out / "fit.json").read_text())
    assert doc["fitted"]["nrmse"] < doc["start"]["nrmse"]
    assert doc["info"]["evaluations"] <= 12  # the budget of the search in all (help text)
    assert len(doc["correlation"]) == 2 and all(p["u"] > 0 for p in doc["parameters"])
    cfg = load_config(out / "fitted.toml")
    assert cfg.rms_slope == pytest.approx(doc["parameters"][1]["value"])
    assert read_dataset(out / "fitted").kind == "simulated"
    assert (out / "report" / "report.html").is_file()
    # resume from the last accepted point: starts where the state is and never gets worse
    assert main(args + ["--resume"]) == 0
    doc2 = json.loads((out / "fit.json").read_text())
    assert doc2["info"]["resumed"] is True
    assert doc2["objective"]["fitted"] <= state["objective"] + 1e-12
    # another problem in the same directory is refused on resume
    capsys.readouterr()
    other = ["fit", "red-cotton", str(measured), "--free", "rms_slope=0.1:0.8", "--out", str(out), "--resume",
             "--no-progress"]
    assert main(other) == 2
    assert "different fit" in capsys.readouterr().err


@pytest.mark.parametrize("method, state, extra, message", [
    ("classic", "fit-state.json", ["--resume"], "different fit"),
    ("mc", "mc-state.json", ["--resume"], "different fit"),
    ("classic", "fit-state.json", [], "not empty"),
    ("classic", None, ["--resume"], "nothing to resume"),
])
def test_cli_refusals_come_before_any_table(tmp_path, capsys, monkeypatch, method, state, extra, message):
    """A refused fit (another fit's state on --resume, an existing output without --force, nothing to
    resume) says so in one line, exit 2, without walking a photon or evaluating the model."""
    from fabric_optics.fitting import problem as fit_problem
    from fabric_optics.fitting import spacemapping as fit_mc
    from simulate.structwalk import walk as fit_structure

    def no_work(*a, **k):
        raise AssertionError("expensive work before the refusal")

    monkeypatch.setattr(fit_problem, "absorption_table", no_work)
    monkeypatch.setattr(fit_structure, "walk_structure", no_work)
    monkeypatch.setattr(FitProblem, "model", no_work)
    monkeypatch.setattr(fit_mc, "run_monte_carlo", no_work)
    write_dataset(measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None), tmp_path / "measured")
    out = tmp_path / "fit"
    out.mkdir()
    if state:
        schema = "simulate-fit-mc-state/1" if method == "mc" else "simulate-fit-state/1"
        (out / state).write_text(json.dumps({"schema": schema, "identity": "another fit", "x": [0.3],
                                             "objective": 1.0, "iterations": []}))
    code = main(["fit", "red-cotton", str(tmp_path / "measured"), "--free", "rms_slope=0.1:0.8", "--out", str(out),
                 "--method", method, "--no-progress"] + extra)
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.slow
def test_recovery_of_a_walked_parameter(red_cotton):
    """The volume fraction (photons walked again, common random numbers) is recovered within u."""
    free = parse_free(["volume_fraction=0.02:0.1"], red_cotton)
    probe = FitProblem(red_cotton, measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None), free,
                       target_rel_err=0.05, seed=9, wavelengths_nm=WAVELENGTHS)
    problem = sibling(probe, model_measurement(probe, [0.035], noise_seed=11))
    result = run_fit(problem, noise_draws=16, max_evaluations=8)
    assert abs(result.x[0] - 0.035) < 3.5 * result.u[0]
    assert problem.counters.walks >= 2


def test_objective_uses_compare_prepared_once_with_the_same_figures(base_problem):
    """The fit's residuals (compare.residual, prepared once) equal those of a full compare_datasets run
    of the model written as a dataset, for the measurement and for a noise draw of it."""
    from tests.fabric_optics.fitting.conftest import model_measurement, sibling

    x0 = np.array([p.start for p in base_problem.free])
    measured = model_measurement(base_problem, x0 * np.array([1.3, 0.8]), noise_seed=3)
    problem = sibling(base_problem, measured)
    noisy = model_measurement(base_problem, x0 * np.array([1.3, 0.8]), noise_seed=4)
    for x in (x0, x0 * np.array([0.7, 1.2])):
        beta, u = problem.model(x)
        for target in (None, noisy):
            full = problem.residuals_of(problem.compare(problem.dataset(beta, u, "trial"), target))
            fast = problem.residuals(x, measured=target)
            np.testing.assert_allclose(fast, full, rtol=1e-9, atol=1e-12)
    assert problem.residual_model() is problem.residual_model()  # prepared once


def test_noise_draws_that_cannot_be_normalised_are_left_out(base_problem, caplog):
    """A measured value within ~1 u of zero at normal incidence (a simulated measurement in a strongly
    absorbed band, as the red felt's 400 nm): some data draws have no positive normal/normal value.
    The fit still ends with finite uncertainties from the other draws and says how many it left out."""
    import logging

    from gonio.data import make_dataset

    x_true = np.array([1.4, 0.25])
    meas = model_measurement(base_problem, x_true, noise_seed=None)
    table = meas.table.copy()
    weak = (table["theta_i"] == 0.0) & (table["wavelength_nm"] == WAVELENGTHS[0])
    table.loc[weak, "u_beta"] = 3.0 * table.loc[weak, "beta"]
    problem = sibling(base_problem, make_dataset(table, meas.meta))
    with caplog.at_level(logging.WARNING, logger="fabric_optics.fitting.driver"):
        result = run_fit(problem, noise_draws=8, max_evaluations=20)
    assert any("noise draws left out" in r.getMessage() for r in caplog.records)
    assert np.all(np.isfinite(result.u)) and np.all(result.u > 0)
    np.testing.assert_allclose(result.x, x_true, rtol=2e-3)


def test_without_measurement_uncertainty_u_is_scaled_by_the_residual(base_problem):
    """Known Gaussian noise (sigma 0.004 on every beta, fixed seed) but u_beta written as 0, as an RGL file's
    import: the noise level estimated from the residual recovers sigma within its sampling error (sqrt(1/(2 dof)))
    and u equals the u propagated from the true sigma (the same data stated with u_beta = sigma, the same noise
    draws) within it (before, the data part was 0: only the Monte Carlo part was left). The plain s^2 (J^T J)^-1, which
    treats the residuals as independent, gives a third to a half of it here (the per-wavelength normalisation
    correlates them)."""
    from fabric_optics.fitting.uncertainty import RESIDUAL_DRAWS_RULE, residual_covariance

    x_true = np.array([1.4, 0.25])
    sigma = 0.004
    beta, _ = base_problem.model(x_true)
    noisy = beta + np.random.default_rng(11).standard_normal(beta.shape) * sigma
    stated = measurement(lambda g, wl: noisy, None, geometries=base_problem.geometries)
    stated.table["u_beta"] = sigma
    bare = measurement(lambda g, wl: noisy, None, geometries=base_problem.geometries)
    bare.table["u_beta"] = 0.0
    draws = 32
    ref = run_fit(sibling(base_problem, stated), noise_draws=draws)
    problem = sibling(base_problem, bare)
    got = run_fit(problem, noise_draws=draws)
    rule = got.info["uncertainty"]
    assert rule["data"] == "residual" and rule["rule"] == RESIDUAL_DRAWS_RULE and rule["draws"] == draws
    assert ref.info["uncertainty"]["data"] == "u_beta"
    dof = len(problem.measured.table) - 2
    tol = 3.0 * math.sqrt(0.5 / dof) + 0.02          # sigma's sampling error; 0.02 for the draws' nonlinearity
    assert abs(rule["sigma_beta"] / sigma - 1.0) < tol, rule["sigma_beta"]
    np.testing.assert_allclose(got.u_data, ref.u_data, rtol=tol)
    assert np.all(np.isfinite(got.u_data) & (got.u_data > 0))
    assert any("scaled by the residual" in w for w in got.warnings)
    # the independent-residual rule falls short of the true u here
    r = problem.residuals(got.x)
    J = jacobian(problem, got.x, r, problem.residuals)
    cov, _ = residual_covariance(J, r)
    assert np.all(np.sqrt(np.diag(cov)) < 0.7 * ref.u_data)


def test_a_parameter_at_its_bound_has_no_uncertainty_number(base_problem, tmp_path):
    """The truth beyond the RMS slope's upper bound: reported "at its upper bound", u null in fit.json."""
    from fabric_optics.fitting.outputs import write_outputs

    problem = sibling(base_problem, model_measurement(base_problem, (1.4, 0.6), noise_seed=2),
                      free=parse_free(["fiber.dye.bands[0].peak_per_um=0.3:3,rms_slope=0.1:0.4"], base_problem.config))
    result = run_fit(problem, noise_draws=4, max_evaluations=60)
    assert result.info["u_status"] == ["", "at its upper bound"]
    doc = write_outputs(problem, result, tmp_path)
    slope = doc["parameters"][1]
    assert slope["u"] is None and slope["u_status"] == "at its upper bound"
    assert doc["parameters"][0]["u"] > 0
    assert "at its upper bound: no uncertainty" in (tmp_path / "fitted.toml").read_text()


def test_absolute_fit_includes_the_level(base_problem):
    """--absolute (level_weight 1) appends sqrt(w_l) ln k_Y to the residuals, k_Y the level compare reports;
    on a measurement 0.8 times the model's level the absolute fit moves towards the level (the shape-only fit
    ignores it: its k_Y stays 0.8)."""
    from compare.comparison import compare_datasets

    x_true = np.array([1.4, 0.25])
    beta, _ = base_problem.model(x_true)
    darker = measurement(lambda g, wl: 0.8 * beta, None, geometries=base_problem.geometries)
    shape_only = sibling(base_problem, darker)
    absolute = sibling(base_problem, darker, level_weight=1.0)
    r = absolute.residuals(x_true)
    assert r.size == shape_only.residuals(x_true).size + 1
    sim = absolute.dataset(*absolute.model(x_true), "x")
    c = compare_datasets(darker, [sim])
    k_y = c.level(next(iter(c.frames))).k
    assert k_y == pytest.approx(0.8, rel=1e-6) and r[-1] == pytest.approx(math.log(k_y), rel=1e-9)
    plain = run_fit(shape_only, noise_draws=2, max_evaluations=60, invert_start=False)
    level = run_fit(absolute, noise_draws=2, max_evaluations=60, invert_start=False)
    fig_plain = shape_only.residual_model().evaluate(shape_only.model(plain.x)[0])
    fig_level = absolute.residual_model().evaluate(absolute.model(level.x)[0])
    assert abs(math.log(fig_plain.level) - math.log(0.8)) < 0.02
    assert abs(math.log(fig_level.level)) < 0.5 * abs(math.log(fig_plain.level))
