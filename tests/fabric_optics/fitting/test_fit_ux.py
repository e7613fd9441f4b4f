"""simulate fit as a user meets it: walk progress, walk checkpoint and resume, Ctrl-C message,
the evaluation budget, warnings (bounds, colour, once each) and the grazing rule."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.fitting import problem as fit_problem
from fabric_optics.fitting import spec as fit_spec
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.outputs import EXIT_COLOUR_OFF
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.state import STATE_NAME, WALKS_DIR
from gonio.data import write_dataset

from .conftest import measurement, model_measurement


def _fresh(problem: FitProblem, measured=None, free=None, **kw) -> FitProblem:
    """A problem like ``problem`` with no table yet (its first walk is walked again)."""
    return FitProblem(problem.config, problem.measured if measured is None else measured,
                      problem.free if free is None else free, method=problem.method,
                      target_rel_err=0.1, seed=problem.seed, **kw)


def test_first_walk_reports_progress_before_its_first_run_ends(base_problem):
    calls = []
    p = _fresh(base_problem)
    p.use_walk_progress(lambda photons, run, runs: calls.append((photons, run, runs)))
    p.model(p.start)
    runs = calls[0][2]
    assert calls[0] == (0, 0, runs) and runs >= 1
    assert any(ph > 0 and run == 0 for ph, run, _ in calls)  # photons counted inside the first run
    assert calls[-1][1] == runs and calls[-1][0] == sum(p.photons.values())


class _Stop(KeyboardInterrupt):
    pass


def test_interrupted_first_walk_resumes_from_its_checkpoint(base_problem, tmp_path):
    """Ctrl-C after the first run of the first walk: --resume reads that run, walks the rest, and gets
    the table of an uninterrupted walk."""
    ref = _fresh(base_problem)
    R_ref = ref.table(ref.config).R

    def stop_after_first_run(photons, run, runs):
        if run == 1:
            raise _Stop

    p = _fresh(base_problem)
    p.use_checkpoint(tmp_path)
    p.use_walk_progress(stop_after_first_run)
    with pytest.raises(KeyboardInterrupt):
        p.table(p.config)
    assert not (tmp_path / STATE_NAME).exists()
    assert len(list((tmp_path / WALKS_DIR).glob("*.npz"))) == 1
    q = _fresh(base_problem)
    walked = []
    q.use_walk_progress(lambda photons, run, runs: walked.append(run))
    result = run_fit(q, out=tmp_path, resume=True, max_evaluations=6, noise_draws=2)
    assert "not walked again" in result.info["start_note"]
    np.testing.assert_array_equal(q.table(q.config).R, R_ref)  # the same table as without the interrupt


def test_resume_says_why_not(base_problem, tmp_path):
    with pytest.raises(FitError, match="nothing to resume"):
        run_fit(_fresh(base_problem), out=tmp_path, resume=True)


def test_ctrl_c_message_claims_only_what_exists(base_problem, tmp_path, capsys, monkeypatch):
    write_dataset(model_measurement(base_problem, (1.4, 0.25), noise_seed=3), tmp_path / "m")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fit_problem, "absorption_table", interrupted)
    code = main(["fit", "red-cotton", str(tmp_path / "m"), "--free", "rms_slope", "--out", str(tmp_path / "f"),
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 130
    assert "nothing was saved" in err and "fit-state.json" not in err
    assert not (tmp_path / "f" / STATE_NAME).exists()


def test_ctrl_c_names_the_walk_parts_this_fit_left_in_the_table_cache(base_problem, tmp_path, capsys,
                                                                      monkeypatch):
    """A structured walk keeps its finished parts in the table cache, not in DIR: the message says how many
    THIS fit stored (a part stored before it began is not claimed) and where they are."""
    import dataclasses

    import fabric_optics.fitting.methods as fit_module
    from simulate.fiber import tablecache

    monkeypatch.setenv(tablecache.ENV_DIR, str(tmp_path / "cache"))
    write_dataset(model_measurement(base_problem, (1.4, 0.25), noise_seed=3), tmp_path / "m")
    tablecache.store("structwalk-" + "0" * 40, {"G": np.zeros(2)})     # an earlier fit's part

    def run_fit(problem, **kwargs):
        for i in (1, 2):       # two parts finished, then Ctrl-C in the third
            tablecache.store(f"structwalk-{i:040d}", {"G": np.full(2, float(i))})
        raise KeyboardInterrupt

    classic = fit_module.METHODS["classic"]
    monkeypatch.setitem(fit_module.METHODS, "classic", dataclasses.replace(classic, run=run_fit))
    argv = ["fit", "red-cotton", str(tmp_path / "m"), "--free", "rms_slope", "--no-progress"]
    assert main(argv + ["--out", str(tmp_path / "f")]) == 130
    err = capsys.readouterr().err
    assert "2 finished parts of the structured walk are in the table cache" in err
    assert str(tmp_path / "cache") in err and "nothing was saved" not in err

    def nothing(problem, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setitem(fit_module.METHODS, "classic", dataclasses.replace(classic, run=nothing))
    assert main(argv + ["--out", str(tmp_path / "g")]) == 130
    assert "nothing was saved" in capsys.readouterr().err      # the parts stored before are not claimed


@pytest.mark.parametrize("budget, starts", [(1, 1), (7, 1), (15, 3)])
def test_max_evaluations_bounds_the_search_in_all(base_problem, budget, starts):
    p = _fresh(base_problem, measured=model_measurement(base_problem, (1.4, 0.25), noise_seed=3))
    p.share_walks(base_problem)
    result = run_fit(p, max_evaluations=budget, starts=starts, noise_draws=2)
    assert 1 <= result.info["evaluations"] <= budget
    assert any("evaluation budget" in w for w in result.warnings)


def test_warnings_at_bound_and_colour_once_each(base_problem, tmp_path, capsys):
    """The truth lies beyond the peak's upper bound: flagged at the bound; the hue cannot follow a
    green measurement with only the red band's peak free: flagged as colour left off."""
    green = np.full(base_problem.wavelengths_nm.size, 1e-3) + 1.5 * np.exp(
        -0.5 * ((base_problem.wavelengths_nm - 650.0) / 45.0) ** 2)
    beta, _ = base_problem.model_at_host(base_problem.config, green)
    write_dataset(measurement(lambda g, wl: beta, None, geometries=base_problem.geometries), tmp_path / "m")
    code = main(["fit", "red-cotton", str(tmp_path / "m"), "--free", "fiber.dye.bands[0].peak_per_um=0.3:1.2",
                 "--out", str(tmp_path / "f"), "--seed", "5", "--target-rel-err", "0.1", "--no-progress",
                 "--max-evaluations", "30"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_COLOUR_OFF == 3                   # a failing fit, distinct from bad input (2)
    # the colour held: the peak goes as far towards the measured hue as its bound lets it
    assert sum("at its upper bound: fiber.dye.bands[0].peak_per_um" in line for line in err) == 1
    assert sum("colour left off" in line for line in err) == 1
    failed = [line for line in err if "colour left off" in line][0]
    assert failed.startswith("simulate fit: FAILED") and "--dye knots" in failed   # what helps: any colour
    assert len(err) == len(set(err))  # nothing twice
    doc = json.loads((tmp_path / "f" / "fit.json").read_text())   # the outputs are written, labelled failing
    assert abs(doc["fitted"]["dh"]) > 0.02
    assert doc["verdict"]["passed"] is False and doc["verdict"]["exit_status"] == 3
    assert doc["objective"]["colour_hold"]["from"] == fit_spec.COLOUR_HOLD_FROM   # the CLI holds the colour
    assert "hold(dh, ds)" in doc["objective"]["definition"]
    assert "FAILED: colour left off" in (tmp_path / "f" / "fitted.toml").read_text()
    assert (tmp_path / "f" / "fitted" / "radiance.csv").is_file()


def test_grazing_rows_are_left_out_with_a_note(base_problem):
    g = base_problem.geometries
    graze = pd.DataFrame([(89.99999567, 0.0, 30.0, 0.0)], columns=g.columns)
    geos = pd.concat([g, graze], ignore_index=True)
    p = FitProblem(base_problem.config, measurement(lambda gg, wl: np.full((len(gg), wl.size), 0.3), None,
                                                    geometries=geos),
                   base_problem.free, method="classic", seed=5)
    assert p.geometries["theta_i"].max() < 89.0
    assert len(p.geometries) == len(g)
    assert len(p.notes) == 1 and "89.99999567" in p.notes[0] and "left out" in p.notes[0]
    with pytest.raises(FitError, match="near grazing"):
        FitProblem(base_problem.config, measurement(lambda gg, wl: np.full((len(gg), wl.size), 0.3), None,
                                                    geometries=graze), base_problem.free, method="classic")
