"""The structured summation in simulate fit (simulate.structwalk.walk): same numbers as simulate fabric,
structure parameters free, recovered, validated."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.spec import parse_free
from fabric_optics.paths import toml_dumps
from gonio.data import make_dataset, new_meta, write_dataset
from simulate.config import load_config, parse_config
from simulate.fabric import structure as st
from simulate.fiber.absorption import absorption_nodes
from simulate.structwalk import walk as fit_structure

from .conftest import geometry_table

#: three wavelengths (one exit-table chunk): the structured walk in seconds, not minutes
WL3 = np.array([450.0, 550.0, 650.0])
#: six at 20 nm (one chunk; the fewest ASTM E308's step, so compare's colour terms exist): the recovery's objective
WL6 = np.arange(480.0, 581.0, 20.0)


def _felt(spread: float = 20.0, dye_log10: float | None = None, volume_fraction: float | None = None) -> object:
    import tomllib

    doc = tomllib.loads(load_config("green-felt").text)
    doc["structure"]["felt_spread_deg"] = spread
    if volume_fraction is not None:
        doc["particles"]["volume_fraction"] = volume_fraction
        # a felt preset's earlier dye and roughness: the recovery's setting, independent
        # of the preset's refits
        doc["fiber"]["dye"] = {"curve": "knots", "wavelength_nm": doc["fiber"]["dye"]["wavelength_nm"],
                               "log10_per_um": [-1.559, 0.194, 0.997, -0.939, -1.839, 0.78, 0.217, 0.768]}
        doc["surface"]["rms_slope"] = 0.14
    if dye_log10 is not None:
        doc["fiber"]["dye"] = {"curve": "knots", "wavelength_nm": [400.0, 700.0], "log10_per_um": [dye_log10] * 2}
    return parse_config(toml_dumps(doc), "felt-test.toml")


def _measured(beta: np.ndarray | float, geometries=None, rel_u: float = 0.01, noise_seed: int | None = None,
              wavelengths: np.ndarray = WL3):
    g = geometry_table() if geometries is None else geometries
    beta = np.broadcast_to(np.asarray(beta, float), (len(g), wavelengths.size)).copy()
    u = rel_u * np.abs(beta) + 1e-5
    if noise_seed is not None:
        beta = beta + np.random.default_rng(noise_seed).standard_normal(beta.shape) * u
    rep = g.loc[g.index.repeat(wavelengths.size)].reset_index(drop=True)
    table = dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"], phi_o=rep["phi_o"],
                 wavelength_nm=np.tile(wavelengths, len(g)), beta=beta.ravel(), u_beta=u.ravel(),
                 n=np.ones(beta.size, dtype=int))
    return make_dataset(table, new_meta("measured", {"name": "synthetic felt"}))


@pytest.mark.slow
def test_structured_fit_model_equals_simulate_fabric_summation():
    """The fit's structured model is simulate fabric's structured summation at the same parameters in its
    fixed-photons mode (one round of the fit's photons per row, the controller's first-round streams),
    scored at the absorption nodes. Not bit for bit: the kernel's roulette acts on the largest target
    weight (node 0, no dye, is a target of the fit's walk), so the two runs roulette different photons --
    equal within their standard errors, without bias. 2 x 2000 photons per row: the two-halves error
    estimate is reliable there (at a few hundred it is not, simulate.fabric.structure.PHOTONS_PER_ROW_AT_1PCT).

    The three wavelengths are two wavelength groups (450; 550 and 650 nm, walked at 650), each on its own
    stream in both runs (simulate.structwalk.walk.seed_of), so the two runs share their photons up
    to the roulette: their difference is well below the noise of two independent runs, ``sigma`` here (the
    RMS over the geometries of each run's two-halves error, per wavelength). Measured at seeds 3-16, both
    dyes: the difference's RMS 0.3-0.7 sigma, its largest value 2.4 sigma (limit 3.5). With the second
    group walked on the first one's stream the runs are independent at 550 and 650 nm: RMS 0.5-1.5
    sigma, the largest value above 3.5 sigma at 5 of seeds 3-32 (4.65 at seed 3), which fails here, as
    does a model without one of its terms."""
    config = _felt()
    free = parse_free(["structure.felt_spread_deg"], config)
    problem = FitProblem(config, _measured(0.3), free, method="summation", target_rel_err=0.1, seed=3)
    assert problem.structured and not any("carpet" in n for n in problem.notes)
    per_row = fit_structure.photons_per_row(0.1)
    assert per_row >= 2000
    nodes = absorption_nodes(problem.nu_max, problem.nodes)
    g = problem.geometries
    from simulate import fabric as fab

    w_i = fab.directions_deg(g["theta_i"].to_numpy(), g["phi_i"].to_numpy())
    w_o = fab.directions_deg(g["theta_o"].to_numpy(), g["phi_o"].to_numpy())
    for dye in (math.log10(nodes[9]), -1.234):        # on a node, between nodes
        other = _felt(dye_log10=dye)       # the preset's scatterers (0.005: nearly clear fibers)
        ref, u_ref, info = st.structured_beta(other.structure, other.fiber(WL3), None, w_i, w_o, WL3,
                                              target_rel_err=0.1, seed=3, photons_per_row=per_row)
        assert len(info["rounds"]) == 1 and info["photons_per_row"] == 2 * per_row
        beta, u = problem.model_at_host(config, other.dye(WL3))
        assert problem.counters.walks == 1 and problem.photons["per_row"] == per_row
        sigma = np.sqrt(np.mean(u ** 2, axis=0) + np.mean(u_ref ** 2, axis=0))   # per wavelength, RMS
        d = (beta - ref) / sigma
        assert float(np.max(np.abs(d))) < 3.5, d    # two runs on the same streams (docstring)
        assert abs(float(np.mean(d))) < 4.0 / math.sqrt(d.shape[0]) + 0.5, d   # no bias beyond the noise
        np.testing.assert_allclose(beta, ref, rtol=0.08)
    # the structure moves the model without a walk; the same spread gives the same numbers again
    b20 = problem.model(np.array([20.0]))[0]
    b40 = problem.model(np.array([40.0]))[0]
    assert problem.counters.walks == 1 and not np.allclose(b20, b40, rtol=1e-3)
    np.testing.assert_array_equal(problem.model(np.array([20.0]))[0], b20)


@pytest.mark.slow
def test_recovery_of_felt_spread():
    """A synthetic felt (the model at a known spread, 1 % noise) is fitted back within 3.5 reported standard
    uncertainties, without a walk beyond the first (the spread re-runs the facet sum only).

    The walked parameters' recovery is ``tests/fabric_optics/fitting/test_fit.py::test_recovery_of_a_walked_parameter``.
    A joint recovery of spread and volume fraction at this test's 10 % walks is not asserted: the objective
    in the volume fraction is piecewise (one walk per 10 % lattice cell) and its jumps between walks exceed
    the data noise, which the reported ``u`` does not contain (docs/physics.md 6.5)."""
    config = _felt(spread=20.0, volume_fraction=0.02)
    free = parse_free(["structure.felt_spread_deg=5:45"], config)
    probe = FitProblem(config, _measured(0.3, wavelengths=WL6), free, method="summation", target_rel_err=0.1, seed=4)
    x_true = np.array([32.0])
    measured = _measured(probe.model(x_true)[0], probe.geometries, noise_seed=21, wavelengths=WL6)
    problem = FitProblem(config, measured, free, method="summation", target_rel_err=0.1, seed=4)
    problem.share_walks(probe)
    result = run_fit(problem, noise_draws=12, max_evaluations=24)
    assert result.objective < result.objective_start
    z = (result.x - x_true) / result.u
    assert np.all(np.abs(z) < 3.5), (result.x, result.u)
    assert abs(result.x[0] - 20.0) > 3.0 * result.u[0]   # it moved off the start: the spread is identifiable
    assert problem.counters.walks == 0   # the probe's walk is shared: the spread is fitted without walking again


def test_structure_parameters_parse_with_defaults_and_range():
    red = load_config("red-cotton")
    (twist,) = parse_free(["structure.warp_twist_deg"], red)   # defaulted field: the spec's default starts
    assert (twist.kind, twist.start, twist.low, twist.high) == ("structure", 24.0, 0.0, 60.0)
    (spread,) = parse_free(["structure.felt_spread_deg=0:40"], load_config("green-felt"))
    assert spread.kind == "structure" and (spread.low, spread.high) == (0.0, 40.0)


@pytest.mark.parametrize("config, free, message", [
    ("green-felt", "structure.felt_spread_deg=-5:30", "valid range [0, 60]"),
    ("green-felt", "structure.felt_spread_deg=10:90", "valid range [0, 60]"),
    ("green-felt", "structure.warp_twist_deg", "does nothing for the config's structure kind 'nonwoven'"),
    ("red-cotton", "structure.felt_spread_deg", "does nothing for the config's structure kind 'woven'"),
    ("green-felt", "structure.layers", "not a structure parameter a fit frees"),
])
def test_bad_structure_parameters_are_one_line_exit_2(tmp_path, capsys, config, free, message):
    write_dataset(_measured(0.3), tmp_path / "m")
    code = main(["fit", config, str(tmp_path / "m"), "--method", "summation", "--free", free,
                 "--out", str(tmp_path / "f")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "f").exists()


def test_structure_parameters_need_the_structured_summation():
    config = load_config("green-felt")
    free = parse_free(["structure.felt_spread_deg"], config)
    with pytest.raises(FitError, match="need --method summation"):
        FitProblem(config, _measured(0.3), free, method="classic")


def test_felt_kind_is_read_as_nonwoven():
    assert load_config("green-felt").structure.kind == "nonwoven"


#: geometries of the green felt file's measured plan (``gonio truth FILE --plan measured``) where a comparison of
#: ``simulate fit``'s initial model with ``simulate fabric`` departed by several of their one-degree-of-freedom
#: standard errors: the retro ring and the in-plane points 6 deg from the retro direction at 27.76 deg, the
#: retro side at 68.77 and 78.56 deg, and a specular and a normal-incidence point
MEASURED_PLAN_POINTS = pd.DataFrame(
    [(27.7551, 0.0, 28.345672, 12.718272), (27.7551, 0.0, 28.345672, 347.281728), (27.7551, 0.0, 21.7551, 0.0),
     (27.7551, 0.0, 20.0, 0.0), (27.7551, 0.0, 30.0, 180.0), (68.7738, 0.0, 30.0, 0.0), (78.5617, 0.0, 48.5617, 0.0),
     (78.5617, 0.0, 50.0, 0.0), (40.0255, 0.0, 60.0, 0.0), (0.0, 0.0, 10.0, 0.0)],
    columns=["theta_i", "phi_i", "theta_o", "phi_o"])


@pytest.mark.parametrize("dye_log10", [None, -1.04])
def test_fit_model_equals_simulate_fabric_on_the_felt_measured_plan(dye_log10):
    """The green felt preset (its own dye, or a uniform one between absorption nodes) at the measured plan's
    geometries that once looked departed: the fit's structured model at the start and ``simulate fabric``'s
    structured summation in its fixed-photons mode, same seed, agree within a few standard errors at every
    geometry and wavelength. ``sigma`` is the RMS over the geometries of each run's two-halves error (per
    wavelength): a single value's error is a one-degree-of-freedom estimate, whose ratio to a difference has
    tails like Student's t with one or two degrees of freedom (docs/notes/fit-trust.md, "The fit's model
    against simulate fabric"). The model without its surface term fails here."""
    config = _felt(spread=0.0, dye_log10=dye_log10)
    wl = np.array([450.0, 550.0, 650.0])
    free = parse_free(["rms_slope"], config)
    problem = FitProblem(config, _measured(0.1, geometries=MEASURED_PLAN_POINTS, wavelengths=wl), free,
                         method="summation", target_rel_err=0.1, seed=3)
    beta, u = problem.model(problem.start)
    from simulate import fabric as fab

    g = problem.geometries
    w_i = fab.directions_deg(g["theta_i"].to_numpy(), g["phi_i"].to_numpy())
    w_o = fab.directions_deg(g["theta_o"].to_numpy(), g["phi_o"].to_numpy())
    ref, u_ref, _ = st.structured_beta(config.structure, config.fiber(wl), None, w_i, w_o, wl, target_rel_err=0.1,
                                       seed=3, photons_per_row=fit_structure.photons_per_row(0.1))
    sigma = np.sqrt(np.mean(u ** 2, axis=0) + np.mean(u_ref ** 2, axis=0))
    d = (beta - ref) / sigma
    assert float(np.max(np.abs(d))) < 3.5, d
    # the retro ring's two azimuths are one geometry mirrored: the same value in both models
    ring = np.flatnonzero(np.isclose(g["theta_o"].to_numpy(), 28.345672))
    assert ring.size == 2
    np.testing.assert_allclose(beta[ring[0]], beta[ring[1]], rtol=1e-9)
    np.testing.assert_allclose(ref[ring[0]], ref[ring[1]], rtol=1e-9)
