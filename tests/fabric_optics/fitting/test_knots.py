"""The ``knots`` dye (any colour) and the start inverted from the measurement's colour."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fabric_optics import paths
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.spec import parse_free
from fabric_optics.fitting.start import inverted_start, knots_config
from fabric_optics.paths import toml_dumps
from simulate.config import ConfigError, parse_config

from .conftest import WAVELENGTHS, measurement


def _bands(*bands):
    """A Gaussian-band host absorption (1/um) at the test wavelengths: another family than the knots."""
    out = np.full(WAVELENGTHS.size, 1e-3)
    for c, w, a in bands:
        out = out + a * np.exp(-0.5 * ((WAVELENGTHS - c) / w) ** 2)
    return out


#: a green (absorbs red and blue) and a blue (absorbs red and green) dye
GREEN = _bands((650.0, 45.0, 1.5), (430.0, 25.0, 1.2))
BLUE = _bands((620.0, 60.0, 1.8), (540.0, 40.0, 0.8))


@pytest.fixture(scope="module")
def knots_problem(red_cotton, base_problem):
    kc = knots_config(red_cotton, WAVELENGTHS)
    beta, _ = base_problem.model_at_host(base_problem.config, GREEN)
    meas = measurement(lambda g, wl: beta, None, geometries=base_problem.geometries)
    return FitProblem(kc, meas, parse_free(["dye"], kc), method="classic", target_rel_err=0.03, seed=5)


def _colour(problem, x):
    fig = problem.residual_model().evaluate(problem.model(x)[0])
    return fig.dh, fig.ds


def _sibling(problem, beta):
    meas = measurement(lambda g, wl: beta, None, geometries=problem.geometries)
    p = FitProblem(problem.config, meas, problem.free, method=problem.method,
                   target_rel_err=problem.target_rel_err, seed=problem.seed)
    p.share_walks(problem)
    return p


@pytest.mark.parametrize("colour", ["green", "blue"])
def test_inverted_start_has_the_measured_hue(knots_problem, base_problem, colour):
    mu = GREEN if colour == "green" else BLUE
    beta, _ = base_problem.model_at_host(base_problem.config, mu)
    p = knots_problem if colour == "green" else _sibling(knots_problem, beta)
    dh0, _ = _colour(p, p.start)
    assert abs(dh0) > 0.1  # red cotton's knots: the wrong colour (else the test shows nothing)
    x0, note = inverted_start(p, p.start)
    assert "inverted" in note
    dh, ds = _colour(p, x0)
    assert abs(dh) < 0.01 and abs(ds) < 0.05
    assert p.counters.walks <= 1  # the inversion reads the fit's table: no photon of its own


def test_dye_only_fit_recovers_the_colour(knots_problem):
    result = run_fit(knots_problem, max_evaluations=40, noise_draws=4)
    dh, ds = _colour(knots_problem, result.x)
    assert abs(dh) < 0.01 and abs(ds) < 0.02
    assert result.info["start_note"].startswith("dye knots started")


def test_knots_curve_and_its_errors(red_cotton):
    kc = knots_config(red_cotton, WAVELENGTHS, count=6)
    k = np.asarray(kc.dye.params["wavelength_nm"])
    v = np.asarray(kc.dye.params["log10_per_um"])
    assert np.allclose(np.log10(kc.dye(k)), v)  # through the knots
    np.testing.assert_allclose(kc.dye([300.0, 800.0]), 10.0 ** v[[0, -1]])  # end values held
    mid = kc.dye(np.linspace(k[0], k[-1], 400))
    assert mid.max() <= 10.0 ** v.max() * (1 + 1e-12)  # no overshoot: the largest knot is the maximum
    doc = tomllib.loads(kc.text)
    for dye, message in [
        ({"wavelength_nm": [400, 500], "log10_per_um": [-1]}, "as many items"),
        ({"wavelength_nm": [500, 400], "log10_per_um": [-1, -2]}, "strictly increasing"),
        ({"wavelength_nm": [400, 500], "log10_per_um": [-1, 3]}, "[-6, 2]"),
        ({"wavelength_nm": [400], "log10_per_um": [-1]}, "at least 2 knots"),
        ({"wavelength_nm": [400, 500]}, "log10_per_um"),
        ({"wavelength_nm": [400, 500], "log10_per_um": [-1, -2], "bands": []}, "bands"),
    ]:
        doc["fiber"]["dye"] = {"curve": "knots", **dye}
        with pytest.raises(ConfigError, match="fiber.dye") as info:
            parse_config(toml_dumps(doc), "k.toml")
        assert message in str(info.value)
    names = [p.name for p in parse_free(["dye"], kc)]
    assert names == [f"fiber.dye.log10_per_um[{i}]" for i in range(6)]


def test_a_dye_only_point_reads_its_config_from_the_parse_of_its_other_parameters(knots_problem, monkeypatch):
    """config_at parses the whole config once per value of the parameters other than the dye: a point that
    changes only the dye gets the config a full parse gives, field by field (text, SHA-256 and the dye
    included), and the same model bit for bit; a change of another parameter is parsed whole."""
    import fabric_optics.fitting.problem as problem_module

    base = knots_problem
    problem = FitProblem(base.config, base.measured, parse_free(["dye,rms_slope"], base.config), method="classic",
                         target_rel_err=base.target_rel_err, seed=base.seed)
    problem.share_walks(base)
    parses = []
    real_parse = problem_module.parse_config

    def counted(*args, **kwargs):
        parses.append(args[0])
        return real_parse(*args, **kwargs)

    monkeypatch.setattr(problem_module, "parse_config", counted)
    x0 = problem.start.copy()
    problem.config_at(x0)
    x1 = x0.copy()
    x1[:-1] += np.linspace(-0.3, 0.4, x1.size - 1)            # every knot moved, the RMS slope kept
    got = problem.config_at(x1)
    assert len(parses) == 1                                   # read from x0's parse
    monkeypatch.undo()
    doc = tomllib.loads(base.config.text)
    for p, v in zip(problem.free, x1, strict=True):
        paths.set_value(doc, p.name, float(v))
    full = parse_config(toml_dumps(doc), f"{base.config.name}.toml", source=f"fit of {base.config.source}")
    assert _same(got, full) and got.dye is not None
    assert got.text == full.text and got.sha256 == full.sha256 and got.dye != problem.config_at(x0).dye
    b_got, u_got = problem.model(x1)
    b_full, u_full = problem.model_at_host(full, full.dye(problem.wavelengths_nm))
    np.testing.assert_array_equal(b_got, b_full)
    np.testing.assert_array_equal(u_got, u_full)
    monkeypatch.setattr(problem_module, "parse_config", counted)
    x2 = x1.copy()
    x2[-1] *= 1.1                                             # the RMS slope: parsed whole
    assert problem.config_at(x2).rms_slope == pytest.approx(x2[-1], rel=1e-15) and len(parses) == 2


def _same(a, b) -> bool:
    """Equal field by field, arrays element by element (a config holds numpy arrays: ``==`` is not a bool)."""
    import dataclasses

    if type(a) is not type(b):
        return False
    if dataclasses.is_dataclass(a):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(u, v) for u, v in zip(a, b, strict=True))
    return bool(a == b)


def test_a_dye_only_point_with_a_bad_dye_is_refused_as_a_full_parse_refuses_it(knots_problem):
    """The dye table of a dye-only point goes through the parser's own checks: a knot outside the knots' range
    gives the full parse's error."""
    problem = knots_problem
    problem.config_at(problem.start)
    x = problem.start.copy()
    x[0] = 5.0                                                # log10 5 /um: above the knots' range
    doc = tomllib.loads(problem.config.text)
    doc["fiber"]["dye"]["log10_per_um"][0] = 5.0
    with pytest.raises(ConfigError) as full:
        parse_config(toml_dumps(doc), f"{problem.config.name}.toml")
    with pytest.raises(ConfigError) as got:
        problem.config_at(x)
    assert str(got.value) == str(full.value)


def test_a_budget_spent_by_the_start_keeps_the_start_s_objective(knots_problem):
    """One evaluation: the config's start is evaluated, the inverted start is not; the fit ends at the budget with
    the start's objective (a search that stops before its inverted start is compared)."""
    p = _sibling(knots_problem, knots_problem.measured.table["beta"].to_numpy().reshape(
        len(knots_problem.geometries), -1))
    result = run_fit(p, max_evaluations=1, noise_draws=2)
    assert result.info["evaluations"] == 1
    assert any("evaluation budget" in w for w in result.warnings)
    r = p.residuals(p.start)
    assert result.objective_start == pytest.approx(float(r @ r), rel=1e-12)
