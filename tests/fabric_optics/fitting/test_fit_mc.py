"""simulate fit --method mc (fabric_optics.fitting.mc): output space mapping of the felt Monte Carlo through the structured
summation -- the correction rule, recovery of a known dye from a Monte Carlo measurement, interrupt and resume,
bad input."""

from __future__ import annotations

import json
import tomllib
from itertools import pairwise

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.fitting import spacemapping as fit_mc
from fabric_optics.fitting import state as fit_state
from fabric_optics.fitting.spacemapping import MCFitProblem, correction, run_mc_fit
from fabric_optics.fitting.spec import parse_free
from fabric_optics.fitting.state import MC_RUNS_DIR, MC_STATE, MCRun
from fabric_optics.paths import toml_dumps
from gonio.data import make_dataset, new_meta, write_dataset
from simulate.config import load_config, parse_config

from .conftest import geometry_table

#: six wavelengths at 20 nm (one exit-table chunk; the fewest for compare's colour terms)
WL6 = np.arange(480.0, 581.0, 20.0)
FREE = "fiber.dye.log10_per_um[0]=-3:0,fiber.dye.log10_per_um[1]=-3:0"


def _felt(d0: float, d1: float):
    """The green-felt preset with a two-knot dye (log10 absorption at 400 and 700 nm)."""
    doc = tomllib.loads(load_config("green-felt").text)
    doc["fiber"]["dye"] = {"curve": "knots", "wavelength_nm": [400.0, 700.0], "log10_per_um": [d0, d1]}
    return parse_config(toml_dumps(doc), "felt-test.toml")


def _measured(beta, u, geometries, wavelengths):
    rep = geometries.loc[geometries.index.repeat(wavelengths.size)].reset_index(drop=True)
    table = dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"], phi_o=rep["phi_o"],
                 wavelength_nm=np.tile(wavelengths, len(geometries)), beta=np.ravel(beta), u_beta=np.ravel(u),
                 n=np.ones(np.size(beta), dtype=int))
    return make_dataset(table, new_meta("measured", {"name": "synthetic felt"}))


def _flat(wavelengths):
    g = geometry_table()
    return _measured(np.full((len(g), wavelengths.size), 0.3), np.full((len(g), wavelengths.size), 0.003), g,
                     wavelengths)


def test_correction_makes_the_surrogate_equal_the_monte_carlo():
    s = np.array([[1.0, 0.5, 0.01, 0.0],       # peak 1: 0.01 and 0 are below 5 % of it -> additive
                  [0.2, 0.2, 0.2, 0.2]])
    mc = np.array([[0.8, 0.6, 0.03, 0.02],
                   [0.1, 0.3, 0.2, 0.4]])
    c, d = correction(s, mc)
    np.testing.assert_allclose(s * c + d, mc, rtol=0, atol=1e-15)
    np.testing.assert_allclose(c, [[0.8, 1.2, 1.0, 1.0], [0.5, 1.5, 1.0, 2.0]])
    np.testing.assert_allclose(d, [[0.0, 0.0, 0.02, 0.02], [0.0, 0.0, 0.0, 0.0]], atol=1e-15)
    # the surrogate keeps the summation's trend: a summation twice as large doubles the multiplicative entries
    np.testing.assert_allclose((2 * s) * c + d, [[1.6, 1.2, 0.04, 0.02], [0.2, 0.6, 0.4, 0.8]], atol=1e-15)


@pytest.mark.slow
def test_recovery_of_a_dye_from_the_monte_carlo_itself():
    """A measurement made by the felt Monte Carlo at a known two-knot dye (+1 % noise; its u_beta the Monte
    Carlo's and the noise's) is fitted back, from a start 0.3 away, within 3.5 reported standard uncertainties,
    and the Monte Carlo's objective falls to within the Monte Carlo's noise of the truth's: no higher than
    the truth's own objective under the noise of three independent seeds (the fit's runs share seed 4 with
    the measurement, so at the truth itself they would reproduce it to the 1 % noise; another seed's run
    at the truth scatters its objective over 0.002-0.014 here, so a fall to a tenth of the start's 0.024
    is below that noise). (~60 s on 2 loaded cores: the summation's walk is ~half.)"""
    x_true = np.array([-0.5, -2.5])
    truth = _felt(*x_true)
    probe = MCFitProblem(truth, _flat(WL6), parse_free([FREE], truth), target_rel_err=0.2, seed=4, wavelengths_nm=WL6)
    ref = fit_mc.run_monte_carlo(probe, x_true)
    rng = np.random.default_rng(3)
    beta = ref.beta * (1.0 + 0.01 * rng.standard_normal(ref.beta.shape))
    u = np.sqrt(ref.u_beta ** 2 + (0.01 * ref.beta) ** 2) + 1e-5
    measured = _measured(beta, u, probe.geometries, WL6)
    start = _felt(-0.8, -2.2)
    problem = MCFitProblem(start, measured, parse_free([FREE], start), target_rel_err=0.2, seed=4, wavelengths_nm=WL6)
    lines: list[str] = []
    result = run_mc_fit(problem, max_runs=4, noise_draws=16, echo=lines.append)
    info = result.info
    assert len(lines) == info["mc_runs"] >= 2 and problem.counters.walks == 1      # one summation walk for every iteration
    assert result.objective < result.objective_start
    at_truth = [fit_mc.run_monte_carlo(MCFitProblem(start, measured, parse_free([FREE], start), target_rel_err=0.2,
                                                    seed=s, wavelengths_nm=WL6), x_true).objective for s in (5, 6, 7)]
    assert result.objective <= max(at_truth) < result.objective_start, (result.objective, at_truth)
    z = (result.x - x_true) / result.u
    assert np.all(np.abs(z) < 3.5), (result.x, result.u)
    assert np.all(result.u_mc > 0) and np.all(result.u_data > 0)
    assert np.all(np.abs(result.x - start_x(start)) > 3.0 * result.u)  # it moved off the start
    it = info["iterations"]
    assert [i["k"] for i in it] == list(range(len(it))) and it[info["best_run"]]["objective"] == result.objective


def start_x(config) -> np.ndarray:
    return np.array(tomllib.loads(config.text)["fiber"]["dye"]["log10_per_um"], float)


def _stand_in(calls: list, beta_of, colour: bool = False):
    """A deterministic stand-in for the Monte Carlo, counted in ``calls``: ``beta_of(problem, x, s)`` from the
    plain summation ``s`` at ``x`` (no correction, no Monte Carlo trend term), scored as a run (``colour``: with
    its hue and saturation differences, as a real run; else NaN)."""
    def run(problem, x, *, progress=False):
        calls.append(np.asarray(x, float).copy())
        s, u = problem.model(beta_of.at(problem, x) if hasattr(beta_of, "at") else x)   # the plain summation
        beta = beta_of(problem, x, s)
        fig = problem.residual_model().evaluate(beta, u)
        r = fig.vector(problem.colour_weight)
        dh, ds = (float(fig.dh), float(fig.ds)) if colour else (float("nan"), float("nan"))
        return MCRun(np.asarray(x, float).copy(), beta, u, 0.01, 1, 0.01, float(r @ r), float(fig.nrmse), dh, ds)
    return run


def _fake_fine(calls: list):
    """The summation with a geometry-dependent 20 % tilt and an offset (so the correction is not 1)."""
    def beta_of(problem, x, s):
        return 0.9 * s * (1.0 + 0.2 * np.linspace(-1.0, 1.0, s.shape[0])[:, None]) + 0.002
    return _stand_in(calls, beta_of)


def _resume_problem(shared=None):
    start = _felt(-0.9, -2.1)
    truth = _felt(-0.5, -2.5)
    probe = shared or MCFitProblem(truth, _flat(WL6), parse_free([FREE], truth), target_rel_err=0.5, seed=2,
                                   wavelengths_nm=WL6)
    beta, u = probe.model(np.array([-0.5, -2.5]))
    measured = _measured(beta, 0.01 * beta + 1e-5, probe.geometries, WL6)
    problem = MCFitProblem(start, measured, parse_free([FREE], start), target_rel_err=0.5, seed=2, wavelengths_nm=WL6)
    problem.share_walks(probe)
    return problem, probe


def test_interrupted_iteration_resumes_from_its_checkpoint(tmp_path, monkeypatch):
    """Ctrl-C in the second Monte Carlo run: the first run and its proposal are on disk; --resume does not run
    them again and ends where an uninterrupted fit ends."""
    import fabric_optics.fitting.search as fit_module

    calls: list = []
    monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_fine(calls))
    ref_problem, probe = _resume_problem()
    reference = run_mc_fit(ref_problem, out=tmp_path / "ref", max_runs=3, noise_draws=2, inner_evaluations=30, echo=lambda s: None)
    n_ref = len(calls)
    assert n_ref >= 2

    calls.clear()
    real_fine = fit_mc.run_monte_carlo

    def interrupted(problem, x, *, progress=False):
        if len(calls) == 1:
            raise KeyboardInterrupt
        return real_fine(problem, x, progress=progress)

    monkeypatch.setattr(fit_mc, "run_monte_carlo", interrupted)
    out = tmp_path / "fit"
    with pytest.raises(KeyboardInterrupt):
        run_mc_fit(_resume_problem(probe)[0], out=out, max_runs=3, noise_draws=2, inner_evaluations=30, echo=lambda s: None)
    state = json.loads((out / MC_STATE).read_text())
    assert len(state["iterations"]) == 1 and "proposal" in state["iterations"][0]
    assert (out / MC_RUNS_DIR / "run-0.npz").is_file()
    assert "1 finished Monte Carlo run(s) and 1 proposal(s)" in fit_state.left_behind(out)

    calls.clear()
    monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_fine(calls))
    monkeypatch.setattr(fit_module, "search_fit", _no_surrogate_fit_for_run_0(fit_module.search_fit,
                                                                           start_x(_felt(-0.9, -2.1))))
    problem = _resume_problem(probe)[0]
    lines: list[str] = []
    resumed = run_mc_fit(problem, out=out, resume=True, max_runs=3, noise_draws=2, inner_evaluations=30, echo=lines.append)
    assert len(calls) == n_ref - 1                      # run 0 read, not run again
    assert "read from the checkpoint" in lines[0]
    assert resumed.info["iterations"][0]["cached"] and resumed.info["mc_runs"] == reference.info["mc_runs"]
    np.testing.assert_allclose(resumed.x, reference.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resumed.objective, reference.objective, rtol=1e-12)


def _no_surrogate_fit_for_run_0(search_fit, x0):
    """search_fit that fails if asked to fit from run 0's point again (its proposal is in the state)."""
    def checked(problem, **kw):
        assert not np.allclose(problem.start, x0), "the proposal of run 0 was fitted again"
        return search_fit(problem, **kw)
    return checked


def test_resume_of_another_fit_or_of_nothing_is_refused(tmp_path):
    start = _felt(-0.9, -2.1)
    problem = MCFitProblem(start, _flat(WL6), parse_free([FREE], start), target_rel_err=0.2, seed=2,
                           wavelengths_nm=WL6)     # refused before any photon: no walk
    with pytest.raises(fit_mc.FitError, match="nothing to resume"):
        run_mc_fit(problem, out=tmp_path, resume=True)
    (tmp_path / MC_STATE).write_text(json.dumps({"schema": fit_state.MC_SCHEMA, "identity": "x", "iterations": []}))
    with pytest.raises(fit_mc.FitError, match="belongs to a different fit"):
        run_mc_fit(problem, out=tmp_path, resume=True)


@pytest.mark.parametrize("args, message", [
    (["--max-runs", "1"], "--method mc needs at least 2 Monte Carlo runs"),
    (["--resume"], "nothing to resume"),
    (["--free", "structure.warp_twist_deg"], "does nothing for the config's structure kind 'nonwoven'"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    write_dataset(_flat(WL6), tmp_path / "m")
    argv = ["fit", "green-felt", str(tmp_path / "m"), "--method", "mc", "--out", str(tmp_path / "f"),
            "--no-progress"]
    if "--free" not in args:
        argv += ["--free", "dye"]
    code = main(argv + args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_noise_draws_that_cannot_be_normalised_are_left_out_not_fatal(monkeypatch, caplog):
    """A loose Monte Carlo (u_beta as large as beta) puts some of the uncertainty's noise draws at a normal
    value <= 0: the fit still ends, leaves those draws out and says how many (it used to stop with a
    CompareError after every run had been made)."""
    calls: list = []
    fake = _fake_fine(calls)

    def noisy(problem, x, *, progress=False):
        run = fake(problem, x, progress=progress)
        run.u_beta = 1.0 * np.abs(run.beta) + 1e-3
        return run

    monkeypatch.setattr(fit_mc, "run_monte_carlo", noisy)
    problem = _resume_problem()[0]
    with caplog.at_level("WARNING", logger="fabric_optics.fitting.mc"):
        result = run_mc_fit(problem, max_runs=2, noise_draws=16, inner_evaluations=20, echo=lambda s: None)
    assert np.all(np.isfinite(result.u)) and np.all(result.u_mc > 0)
    left_out = [r.getMessage() for r in caplog.records if "left out of the uncertainty" in r.getMessage()]
    assert left_out and int(left_out[0].split()[0]) > 0


def test_a_part_whose_draws_are_all_refused_is_reported_not_estimated(monkeypatch):
    """Every Monte Carlo noise draw refused (u_beta 50x beta: each draw has some normal value <= 0): its
    part of the uncertainty is NaN (null in fit.json), u is the data part alone, and a warning says so
    (it used to report u_mc = 0, as if the Monte Carlo added no uncertainty)."""
    calls: list = []
    fake = _fake_fine(calls)

    def very_noisy(problem, x, *, progress=False):
        run = fake(problem, x, progress=progress)
        run.u_beta = 50.0 * np.abs(run.beta) + 1.0
        return run

    monkeypatch.setattr(fit_mc, "run_monte_carlo", very_noisy)
    problem = _resume_problem()[0]
    result = run_mc_fit(problem, max_runs=2, noise_draws=8, inner_evaluations=20, echo=lambda s: None)
    assert np.all(np.isnan(result.u_mc))
    assert np.all(np.isfinite(result.u_data)) and np.all(result.u_data > 0)
    assert np.array_equal(result.u, result.u_data)
    notes = [n for n in result.warnings if "the Monte Carlo part could not be estimated" in n]
    assert len(notes) == 1 and "lower bound" in notes[0]


def test_uncertainty_parts_combines_known_parts_and_flags_unknown_ones():
    from fabric_optics.fitting.uncertainty import uncertainty_parts

    a = np.array([[4.0, 1.0], [1.0, 9.0]])
    b = np.array([[1.0, 0.0], [0.0, 16.0]])
    cov, u, ud, um, notes = uncertainty_parts(a, b)
    assert np.allclose(u, [np.sqrt(5.0), 5.0]) and np.allclose(ud, [2.0, 3.0]) and np.allclose(um, [1.0, 4.0])
    assert notes == []
    cov, u, ud, um, notes = uncertainty_parts(np.full((2, 2), np.nan), b)
    assert np.allclose(u, [1.0, 4.0]) and np.all(np.isnan(ud)) and np.allclose(cov, b)
    assert len(notes) == 1 and "the data part could not be estimated" in notes[0]


# -- parameters only the Monte Carlo sees (the rough boundary for transmitted light) ---------------------------

FREE_FINE = FREE + ",surface.transmission_rms_slope"
T_TRUE = 0.3


def _rough_felt(d0: float, d1: float, t: float):
    doc = tomllib.loads(_felt(d0, d1).text)
    doc["surface"]["transmission_rms_slope"] = t
    return parse_config(toml_dumps(doc), "felt-test.toml")


def _fake_rough(calls: list):
    """A stand-in Monte Carlo that depends on the boundary's slope ``t``, which the summation does not see:
    the summation tilted across the geometries by ``1.5 (t - 0.3)``."""
    def beta_of(problem, x, s):
        j = [p.name for p in problem.free].index("surface.transmission_rms_slope")
        return 0.9 * s * (1.0 + 1.5 * (x[j] - T_TRUE) * np.linspace(-1.0, 1.0, s.shape[0])[:, None]) + 0.002
    return _stand_in(calls, beta_of)


def _rough_problem(shared=None):
    truth = _rough_felt(-0.5, -2.5, T_TRUE)
    probe = shared or MCFitProblem(truth, _flat(WL6), parse_free([FREE_FINE], truth), target_rel_err=0.5, seed=2,
                                   wavelengths_nm=WL6)
    calls: list = []
    beta = _fake_rough(calls)(probe, np.array([-0.5, -2.5, T_TRUE])).beta
    measured = _measured(beta, 0.01 * beta + 1e-5, probe.geometries, WL6)
    start = _rough_felt(-0.7, -2.3, 0.15)
    problem = MCFitProblem(start, measured, parse_free([FREE_FINE], start), target_rel_err=0.5, seed=2,
                           wavelengths_nm=WL6)
    problem.share_walks(probe)
    return problem, probe


def test_a_parameter_only_the_monte_carlo_sees_is_fitted_by_its_own_trend(tmp_path, monkeypatch):
    """The boundary's slope is invisible to the summation, so the zero-order correction alone would never move
    it; with the Monte Carlo's finite-difference trend (one extra run per centre) the fit walks it from 0.15 to
    the measurement's 0.3 through the trust region, every run counted in --max-evaluations and checkpointed.
    An interrupted fit resumes without running any checkpointed run (the trend runs included) again."""
    calls: list = []
    monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_rough(calls))
    problem, probe = _rough_problem()
    assert [p.kind for p in problem.free] == ["dye", "dye", "fine"]
    lines: list[str] = []
    result = run_mc_fit(problem, out=tmp_path / "ref", max_runs=8, noise_draws=4, inner_evaluations=80,
                        echo=lines.append)
    info = result.info
    assert abs(result.x[2] - T_TRUE) < 0.01, result.x
    np.testing.assert_allclose(result.x[:2], [-0.5, -2.5], atol=0.02)
    assert info["mc_runs"] == len(calls) == len(lines) <= 8 and info["fine_trend_runs"] >= 2
    assert sum("trend in surface.transmission_rms_slope" in line for line in lines) == info["fine_trend_runs"]
    state = json.loads((tmp_path / "ref" / MC_STATE).read_text())
    fine_files = [f["file"] for it in state["iterations"] for f in (it.get("fine_runs") or {}).values()]
    assert len(fine_files) == info["fine_trend_runs"]
    assert all((tmp_path / "ref" / MC_RUNS_DIR / f).is_file() for f in fine_files)
    # a trust region: no step of the slope longer than FINE_TRUST of its finite-difference step
    xs = [np.array(it["x"]) for it in info["iterations"]]
    for a, b in pairwise(xs):
        assert abs(b[2] - a[2]) <= fit_mc.FINE_TRUST * max(fit_mc.FINE_STEP * a[2], fit_mc.FINE_STEP_SPAN) + 1e-12
    assert any("lower bound" in w and "transmission_rms_slope" in w for w in result.warnings)

    # interrupted at the trend run of the second centre, then resumed
    n_ref = len(calls)
    calls.clear()
    fake = _fake_rough(calls)

    def interrupted(problem, x, *, progress=False):
        if len(calls) == 3:
            raise KeyboardInterrupt
        return fake(problem, x, progress=progress)

    monkeypatch.setattr(fit_mc, "run_monte_carlo", interrupted)
    out = tmp_path / "fit"
    with pytest.raises(KeyboardInterrupt):
        run_mc_fit(_rough_problem(probe)[0], out=out, max_runs=8, noise_draws=4, inner_evaluations=80,
                   echo=lambda s: None)
    calls.clear()
    monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_rough(calls))
    resumed = run_mc_fit(_rough_problem(probe)[0], out=out, resume=True, max_runs=8, noise_draws=4,
                         inner_evaluations=80, echo=lambda s: None)
    assert len(calls) == n_ref - 3                      # run 0, its trend run and run 1 read, not run again
    np.testing.assert_allclose(resumed.x, result.x, rtol=0, atol=1e-9)


def test_the_summation_fit_refuses_a_parameter_only_the_monte_carlo_sees(tmp_path, capsys):
    write_dataset(_flat(WL6), tmp_path / "m")
    code = main(["fit", "green-felt-mc", str(tmp_path / "m"), "--method", "summation", "--out", str(tmp_path / "f"),
                 "--no-progress", "--free", "dye,surface.transmission_rms_slope_around"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "only the Monte Carlo sees the rough boundary" in err and "--method mc" in err
    assert len(err.strip().splitlines()) == 1, err


class _Mirrored:
    """The summation evaluated at the reflection's RMS slope mirrored about 0.25."""

    @staticmethod
    def at(problem, x):
        j = [p.name for p in problem.free].index("surface.rms_slope")
        xm = np.asarray(x, float).copy()
        xm[j] = 0.5 - xm[j]
        return xm

    def __call__(self, problem, x, s):
        return 0.9 * s + 0.002


def _fake_opposite(calls: list):
    """A stand-in Monte Carlo whose trend in the reflection's RMS slope is the summation's reversed (so the
    summation's trend alone walks the wrong way)."""
    return _stand_in(calls, _Mirrored())


@pytest.mark.slow   # two space-mapping fits against a stand-in Monte Carlo (about 70 s); the fine-trend path
#                     is also run by test_a_parameter_only_the_monte_carlo_sees_is_fitted_by_its_own_trend
def test_mc_trend_takes_a_parameter_s_trend_from_the_monte_carlo_where_the_summation_s_disagrees(monkeypatch):
    """The stand-in Monte Carlo's RMS slope acts as the summation's mirrored about 0.25: a measurement made at 0.32
    is fitted back from 0.28 only when the slope's trend comes from Monte Carlo runs (--mc-trend); with the
    summation's trend the fit moves the other way or not at all."""
    free = "fiber.dye.log10_per_um[0]=-3:0,surface.rms_slope=0.1:0.45"
    truth = _rough_felt(-0.5, -2.5, 0.0)
    doc = tomllib.loads(truth.text)
    doc["surface"]["rms_slope"] = 0.32
    truth = parse_config(toml_dumps(doc), "felt-test.toml")
    probe = MCFitProblem(truth, _flat(WL6), parse_free([free], truth), target_rel_err=0.5, seed=2, wavelengths_nm=WL6)
    beta = _fake_opposite([])(probe, np.array([-0.5, 0.32])).beta
    measured = _measured(beta, 0.01 * beta + 1e-5, probe.geometries, WL6)
    doc["surface"]["rms_slope"] = 0.28
    doc["fiber"]["dye"]["log10_per_um"] = [-0.6, -2.5]
    start = parse_config(toml_dumps(doc), "felt-test.toml")
    results = {}
    for trend in ((), ("surface.rms_slope",)):
        calls: list = []
        monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_opposite(calls))
        problem = MCFitProblem(start, measured, parse_free([free], start), target_rel_err=0.5, seed=2,
                               wavelengths_nm=WL6, mc_trend=trend)
        problem.share_walks(probe)
        results[trend] = run_mc_fit(problem, max_runs=8, noise_draws=4, inner_evaluations=80,
                                    echo=lambda s: None)
    with_trend = results[("surface.rms_slope",)]
    assert abs(with_trend.x[1] - 0.32) < 0.005, with_trend.x
    assert with_trend.info["fine_trend_runs"] >= 1
    assert abs(results[()].x[1] - 0.32) > 0.03, results[()].x
    assert results[()].info["fine_trend_runs"] == 0


def test_mc_trend_names_a_free_parameter_and_needs_the_monte_carlo(tmp_path, capsys):
    write_dataset(_flat(WL6), tmp_path / "m")
    base = ["fit", "green-felt-mc", str(tmp_path / "m"), "--out", str(tmp_path / "f"), "--no-progress", "--free", "dye"]
    for extra, message in ((["--method", "mc", "--mc-trend", "radius"], "--mc-trend radius: not a free"),
                           (["--method", "summation", "--mc-trend", "dye"], "--mc-trend is for --method mc")):
        code = main(base + extra)
        err = capsys.readouterr().err
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


# -- the colour start: the Monte Carlo fit's dye from the measured colour --------------------------------------

FREE4 = ",".join(f"fiber.dye.log10_per_um[{k}]=-3.5:0.3" for k in range(4))


def _felt4(values):
    doc = tomllib.loads(load_config("green-felt").text)
    doc["fiber"]["dye"] = {"curve": "knots", "wavelength_nm": [480.0, 513.333, 546.667, 580.0],
                           "log10_per_um": list(values)}
    return parse_config(toml_dumps(doc), "felt-test.toml")


def _fake_tinted(calls: list, colour: bool = False):
    """A stand-in Monte Carlo whose colour is not the summation's at the same dye: the summation tilted across
    the wavelengths by +-25 % (and 10 % lower), so the Monte Carlo fit must read the colour through the
    corrected surrogate, not through the plain summation."""
    def beta_of(problem, x, s):
        return 0.9 * s * (1.0 + 0.25 * np.linspace(-1.0, 1.0, s.shape[1])[None, :]) + 0.001
    return _stand_in(calls, beta_of, colour)


X4_TRUE = np.array([-3.0, -2.5, -0.6, -0.3])
X4_START = [-0.3, -0.6, -2.5, -3.0]


@pytest.fixture(scope="module")
def felt4_probe():
    """The felt's structured summation at the 4-knot truth (walked once for the tests below)."""
    truth = _felt4(X4_TRUE)
    return MCFitProblem(truth, _flat(WL6), parse_free([FREE4], truth), target_rel_err=0.5, seed=2,
                        wavelengths_nm=WL6)


def test_the_summation_fit_starts_its_dye_from_the_measured_colour(felt4_probe):
    """The structured summation's colour start: knots inverted from a measurement of another colour have the
    measured hue and saturation at the colour geometry (the start's own knots are far off)."""
    from fabric_optics.fitting.problem import FitProblem
    from fabric_optics.fitting.start import inverted_start

    beta, _ = felt4_probe.model(X4_TRUE)
    measured = _measured(beta, 0.01 * beta + 1e-5, felt4_probe.geometries, WL6)
    start = _felt4(X4_START)
    problem = FitProblem(start, measured, parse_free([FREE4], start), method="summation", target_rel_err=0.5,
                         seed=2, wavelengths_nm=WL6)
    problem.share_walks(felt4_probe)
    fig0 = problem.residual_model().evaluate(problem.model(problem.start)[0])
    assert abs(fig0.dh) > 0.1
    x0, note = inverted_start(problem, problem.start)
    assert "inverted" in note
    fig = problem.residual_model().evaluate(problem.model(x0)[0])
    assert abs(fig.dh) < 0.01 and abs(fig.ds) < 0.03, (fig.dh, fig.ds)
    assert problem.counters.walks == 0                              # read from the shared walk


def test_the_monte_carlo_fit_starts_its_dye_from_the_measured_colour(monkeypatch, felt4_probe):
    """A measurement of another colour (the long wavelengths absorbed, the start absorbs the short ones): the
    surrogate fit starts from the colour inverted through the surrogate, and the fit reaches the colour
    tolerance within 3 Monte Carlo runs (the start's included)."""
    from fabric_optics.fitting.spec import COLOUR_TOLERANCE

    calls: list = []
    monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_tinted(calls))
    x_true = X4_TRUE
    probe = felt4_probe
    beta = _fake_tinted([])(probe, x_true).beta
    measured = _measured(beta, 0.01 * beta + 1e-5, probe.geometries, WL6)
    start = _felt4(X4_START)
    problem = MCFitProblem(start, measured, parse_free([FREE4], start), target_rel_err=0.5, seed=2,
                           wavelengths_nm=WL6)
    problem.share_walks(probe)
    result = run_mc_fit(problem, max_runs=3, noise_draws=2, inner_evaluations=80, echo=lambda s: None)
    runs = result.info["iterations"]
    fig0 = problem.residual_model().evaluate(result.model_start[0])
    assert abs(fig0.dh) > 0.1                              # the start is another colour (else nothing is shown)
    assert "inverted" in runs[0]["proposal"]["start_note"]
    fig = problem.residual_model().evaluate(result.model_fit[0])
    dh_max, ds_max = COLOUR_TOLERANCE
    assert abs(fig.dh) <= dh_max and abs(fig.ds) <= ds_max, (fig.dh, fig.ds)
    assert len(calls) <= 3


def test_the_monte_carlo_fit_puts_the_colour_first_where_the_curves_want_another(monkeypatch, felt4_probe):
    """A measurement whose curves and colour disagree: the curves of the stand-in Monte Carlo at one dye, the
    colour geometry's spectrum (same mean) from another dye. At colour weight 1 the surrogate's optimum trades
    the colour away (hue ~0.05 turn off, confirmed by the Monte Carlo); with the colour first the surrogate fit
    raises the colour weight until its colour is within half the tolerance, and the 3 runs end within it."""
    from fabric_optics.fitting.spec import COLOUR_TOLERANCE

    probe = felt4_probe
    measured, g_star = _colour_disagreeing(probe)
    g = probe.geometries
    dh_max, ds_max = COLOUR_TOLERANCE
    figs = {}
    for colour_first in (False, True):
        calls: list = []
        monkeypatch.setattr(fit_mc, "run_monte_carlo", _fake_tinted(calls, colour=True))
        if not colour_first:
            monkeypatch.setattr(fit_mc, "_colour_first", lambda problem: False)
        start = _felt4(X4_START)
        problem = MCFitProblem(start, measured, parse_free([FREE4], start), target_rel_err=0.5, seed=2,
                               wavelengths_nm=WL6)
        problem.share_walks(probe)
        geo = problem.residual_model().colour_geometry                 # the row whose spectrum was replaced
        assert [round(float(geo[c]), 6) for c in ("theta_i", "phi_i", "theta_o", "phi_o")] == \
            [round(float(g.iloc[g_star][c]), 6) for c in ("theta_i", "phi_i", "theta_o", "phi_o")]
        result = run_mc_fit(problem, max_runs=3, noise_draws=2, inner_evaluations=80, echo=lambda s: None)
        monkeypatch.undo()
        assert len(calls) <= 3
        figs[colour_first] = problem.residual_model().evaluate(result.model_fit[0])
        props = [it["proposal"] for it in result.info["iterations"] if "proposal" in it]
        if colour_first:
            assert props[0]["colour_weights"][0] == 1.0 and len(props[0]["colour_weights"]) > 1
            assert abs(props[0]["surrogate_dh"]) <= 0.5 * dh_max and abs(props[0]["surrogate_ds"]) <= 0.5 * ds_max
            assert problem.colour_weight == 1.0                      # the problem's weight is restored
            assert result.warnings == [w for w in result.warnings if not w.startswith("colour left off")]
    old, new = figs[False], figs[True]
    assert abs(old.dh) > 2 * dh_max, old.dh                         # without the colour first: another colour
    assert abs(new.dh) <= dh_max and abs(new.ds) <= ds_max, (new.dh, new.ds)
    assert new.nrmse < 1.2 * old.nrmse                              # at a small cost in curve error


def test_the_best_run_is_the_colour_s_first():
    """With the colour first a run within the colour tolerance beats one outside it whatever their objectives,
    of two outside the nearer colour wins, of two inside the lower objective; without, the objective alone."""
    def run(objective, dh, ds=0.0):
        return MCRun(np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)), 0.0, 0, 0.0, objective, 0.1, dh, ds)

    inside, outside = run(0.5, 0.019, -0.029), run(0.1, 0.021)
    assert fit_mc._better(inside, outside, True) and not fit_mc._better(outside, inside, True)
    assert fit_mc._better(outside, inside, False)
    assert fit_mc._better(run(0.9, 0.05), run(0.1, 0.0, 0.2), True)          # 2.5 tolerances against 6.7
    assert fit_mc._better(run(0.1, 0.01), run(0.2, 0.0), True)               # both inside: the objective
    assert not fit_mc._better(run(0.3, 0.0), run(0.2, 0.01), True)
    assert fit_mc._better(run(0.1, float("nan")), run(0.2, float("nan")), True)  # no colour: the objective


def _colour_disagreeing(probe):
    """``(measured, g_star)``: the stand-in Monte Carlo's curves at one dye with the colour geometry's spectrum (row
    ``g_star``, same mean) from another dye: a measurement whose curves and colour disagree."""
    curves = _fake_tinted([])(probe, X4_TRUE).beta
    spectrum = _fake_tinted([])(probe, np.array([-3.0, -1.5, -0.6, -0.3])).beta
    g = probe.geometries
    g_star = int(np.flatnonzero((g["theta_i"] == 0.0) & np.isclose(g["theta_o"], 10.0))[0])
    beta = curves.copy()
    beta[g_star] = spectrum[g_star] * curves[g_star].mean() / spectrum[g_star].mean()
    return _measured(beta, 0.01 * beta + 1e-5, probe.geometries, WL6), g_star


def test_only_the_kept_surrogate_fit_computes_its_uncertainty(monkeypatch, felt4_probe):
    """With the colour first the surrogate is fitted again at larger colour weights and only the last fit is kept:
    the uncertainty is computed for that one alone, and equals the whole fit's (run_fit: search and uncertainty)
    from the same start at the same weight, bit for bit."""
    import fabric_optics.fitting.search as fit_module

    probe = felt4_probe
    measured, g_star = _colour_disagreeing(probe)
    start = _felt4(X4_START)
    problem = MCFitProblem(start, measured, parse_free([FREE4], start), target_rel_err=0.5, seed=2, wavelengths_nm=WL6)
    problem.share_walks(probe)
    run = _fake_tinted([], colour=True)(problem, problem.start)
    surrogate = fit_mc.Surrogate.at(problem, problem.start, run.beta, run.u_beta)

    searches, finishes = [], []
    real_search, real_finish = fit_module.search_fit, fit_module.finish_fit

    def search(problem, **kw):
        searches.append(problem.colour_weight)
        return real_search(problem, **kw)

    def finish(problem, found, **kw):
        finishes.append(problem.colour_weight)
        return real_finish(problem, found, **kw)

    monkeypatch.setattr(fit_mc, "search_fit", search)
    monkeypatch.setattr(fit_mc, "finish_fit", finish)
    res, weights, kept = fit_mc._surrogate_fit(surrogate, problem.start.copy(), True, max_evaluations=80,
                                               noise_draws=4)
    monkeypatch.undo()
    assert len(weights) > 1 and searches == weights          # fitted again at larger weights (else nothing is shown)
    assert finishes == [weights[-1]]                         # the discarded fits computed no uncertainty
    assert problem.colour_weight == 1.0 and kept.colour_weight == weights[-1]   # the spec is as it was

    found = fit_module.search_fit(kept, start=res.start.copy(), out=None, invert_start=True, max_evaluations=80)
    whole = fit_module.finish_fit(kept, found, noise_draws=4)
    for name in ("x", "u", "u_data", "u_mc", "correlation"):
        np.testing.assert_array_equal(getattr(res, name), getattr(whole, name), err_msg=name)
    assert np.isfinite(res.u).all() and res.objective == whole.objective and res.warnings == whole.warnings
    assert res.info["evaluations_uncertainty"] == whole.info["evaluations_uncertainty"] > 0
