"""The ``knots`` dye (any colour) and the start inverted from the measurement's colour."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from simulate.config import ConfigError, parse_config
from fabric_optics.fitting.driver import FitProblem, parse_free, run_fit
from fabric_optics.fitting.start import inverted_start, knots_config
from fabric_optics.paths import toml_dumps

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
    p._tables = problem._tables
    p.photons = problem.photons
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
    assert p.walks <= 1  # the inversion reads the fit's table: no photon of its own


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
