"""simulate fit frees a ring dye's depth (``fiber.dye_depth_um``): the depth of a synthetic measurement made at a
known depth comes back within 3 of its reported uncertainties from another start depth (the classic model, the
structured summation, in the slow suite; the felt Monte Carlo's fit: tests/docs/test_dye_depth_check.py), and a bad
depth or a model that cannot take one is refused in one line.
Likewise the depth of a skin of scatterers (``fiber.scatterer_depth_um``): its default bounds inside the fiber, the
free value reaching the fiber that is walked, and the refusals."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.spec import parse_free
from fabric_optics.paths import toml_dumps
from gonio.data import make_dataset, new_meta, write_dataset
from simulate.config import load_config, parse_config

from .conftest import MOCK_REL_U, geometry_table, measurement

#: six wavelengths through red cotton's dye band and the incidences 0 and 30 deg to 45 deg (test_fit_blend's plan)
WL6 = np.arange(480.0, 581.0, 20.0)
FLAT = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)


def ring_text(depth: float, structure: bool = True) -> str:
    """Red cotton with its dye in a ring ``depth`` um deep (radius 10 um)."""
    doc = tomllib.loads(load_config("red-cotton").text)
    doc["fiber"].update(dye_profile="ring", dye_depth_um=depth)
    if not structure:
        del doc["structure"]
    return toml_dumps(doc)


def ring(depth: float, structure: bool = True):
    return parse_config(ring_text(depth, structure), "ring.toml")


def _geometries():
    g = geometry_table()
    return g[(g["theta_i"] < 45) & (g["theta_o"].abs() <= 45)].reset_index(drop=True)


def _measured(beta: np.ndarray, geometries, noise_seed: int):
    """``beta`` at ``geometries`` and WL6 with the mock's noise."""
    u = MOCK_REL_U * np.abs(beta) + 1e-5
    noisy = beta + np.random.default_rng(noise_seed).standard_normal(beta.shape) * u
    rep = geometries.loc[geometries.index.repeat(WL6.size)].reset_index(drop=True)
    table = dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"], phi_o=rep["phi_o"],
                 wavelength_nm=np.tile(WL6, len(geometries)), beta=noisy.ravel(), u_beta=u.ravel(),
                 n=np.ones(noisy.size, dtype=int))
    return make_dataset(table, new_meta("measured", {"name": "synthetic ring dye"}))


def _recovered(method: str, truth: float, start: float, target: float, max_evaluations: int):
    """The fit of ``fiber.dye_depth_um`` from ``start`` to the model made at ``truth`` (one walk's photons: the
    measurement's walk is the fit's first)."""
    cfg = ring(start)
    free = parse_free(["fiber.dye_depth_um"], cfg)
    assert free[0].kind == "walk" and free[0].low < truth < free[0].high < 10.0
    flat = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None, geometries=_geometries())
    made = FitProblem(cfg, flat, free, method=method, target_rel_err=target, seed=3, wavelengths_nm=WL6)
    beta, _ = made.model(np.array([truth]))
    problem = FitProblem(cfg, _measured(beta, made.geometries, noise_seed=11), free, method=method,
                         target_rel_err=target, seed=3, wavelengths_nm=WL6)
    problem.share_walks(made)
    return run_fit(problem, noise_draws=16, max_evaluations=max_evaluations)


@pytest.mark.slow
def test_a_classic_fit_recovers_a_ring_dyes_depth():
    """Made at 1.0 um, started at 1.5 um: the depth comes back within 3 u, and the start lies beyond that."""
    result = _recovered("classic", truth=1.0, start=1.5, target=0.1, max_evaluations=30)
    assert result.objective < result.objective_start
    assert result.info["u_status"] == [""] and 0 < result.u[0] < 0.2, result.u
    assert abs(result.x[0] - 1.0) < 3 * result.u[0], (result.x, result.u)
    assert abs(result.x[0] - 1.5) > 3 * result.u[0]


@pytest.mark.slow
def test_a_structured_summation_fit_recovers_a_ring_dyes_depth():
    """The structured summation (the fit's walk scores the ring: simulate.fiber.absorption), made at a lattice point
    of the walked depth (2.5 exp(-0.8) um) and started at 2.5 um: the depth within 3 u."""
    truth = 2.5 * np.exp(-0.8)
    result = _recovered("summation", truth=truth, start=2.5, target=0.3, max_evaluations=30)
    assert result.objective < result.objective_start
    assert result.info["u_status"] == [""] and result.u[0] > 0, result.u
    assert abs(result.x[0] - truth) < 3 * result.u[0], (result.x, result.u)


@pytest.mark.parametrize("config, free, method, message", [
    (ring(1.5), "fiber.dye_depth_um=-1:3", "classic", "a dye depth lies in (0, 10) um (the fiber's radius), got [-1, 3]"),
    (ring(1.5), "fiber.dye_depth_um=1:12", "classic", "a dye depth lies in (0, 10) um (the fiber's radius), got [1, 12]"),
    (ring(1.5, structure=False), "fiber.dye_depth_um", "summation",
     "--free fiber.dye_depth_um: the summation of a config without [structure] reads the top cell by next events"),
    (ring(1.5, structure=False), "rms_slope", "summation", "ring.toml: fiber.dye_profile = 'ring': the summation"),
])
def test_a_bad_depth_or_a_model_without_one_is_refused_in_one_line(config, free, method, message):
    with pytest.raises(FitError) as exc:
        FitProblem(config, FLAT, parse_free([free], config), method=method)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_the_default_bounds_keep_the_depth_inside_the_fiber():
    deep = parse_free(["fiber.dye_depth_um"], ring(6.0))[0]
    assert (deep.low, deep.high) == (1.5, 9.8)          # start / 4 to the radius less 2 %
    with pytest.raises(FitError, match="has no depth"):
        FitProblem(load_config("red-cotton"), FLAT, [deep], method="classic")


@pytest.mark.parametrize("depth_text, free, message", [
    ("dye_depth_um = 1.5", "fiber.dye_depth_um=-1:3", "--free: 'fiber.dye_depth_um=-1:3': a dye depth lies in (0, 10)"),
    ("dye_depth_um = 12.0", "fiber.dye_depth_um", "ring.toml: fiber.dye_depth_um must be a number > 0 and < 10, got 12"),
    ("dye_depth_um = -1.0", "fiber.dye_depth_um", "ring.toml: fiber.dye_depth_um must be a number > 0 and < 10, got -1"),
])
def test_the_cli_refuses_a_bad_depth_before_any_work(tmp_path, capsys, depth_text, free, message):
    (tmp_path / "ring.toml").write_text(ring_text(1.5).replace("dye_depth_um = 1.5", depth_text))
    write_dataset(FLAT, tmp_path / "m")
    code = main(["fit", str(tmp_path / "ring.toml"), str(tmp_path / "m"), "--method", "classic", "--free", free,
                 "--out", str(tmp_path / "f")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "f").exists()


# ------------------------------------------------------------------------------------------
# the depth of a skin (or core) of scatterers


def skin_text(depth: float, structure: bool = True, profile: str = "skin") -> str:
    """Red cotton with its scatterers (k = 0) in a skin ``depth`` um deep (radius 10 um)."""
    doc = tomllib.loads(load_config("red-cotton").text)
    doc["fiber"].update(scatterer_profile=profile, scatterer_depth_um=depth)
    if not structure:
        del doc["structure"]
    return toml_dumps(doc)


def skin(depth: float, structure: bool = True):
    return parse_config(skin_text(depth, structure), "skin.toml")


def test_the_scatterer_depths_default_bounds_keep_it_inside_the_fiber():
    deep = parse_free(["fiber.scatterer_depth_um"], skin(6.0))[0]
    assert (deep.kind, deep.low, deep.high) == ("walk", 1.5, 9.8)          # start / 4 to the radius less 2 %
    with pytest.raises(FitError, match="has its scatterers through the fiber") as exc:
        FitProblem(load_config("red-cotton"), FLAT, [deep], method="classic")
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("config, free, method, message", [
    (skin(1.5), "fiber.scatterer_depth_um=-1:3", "classic",
     "a scatterer depth lies in (0, 10) um (the fiber's radius), got [-1, 3]"),
    (skin(1.5), "fiber.scatterer_depth_um=1:10", "classic",
     "a scatterer depth lies in (0, 10) um (the fiber's radius), got [1, 10]"),
    (skin(1.5, structure=False), "fiber.scatterer_depth_um", "summation",
     "--free fiber.scatterer_depth_um: the summation of a config without [structure] reads the top cell by next events"),
    (skin(1.5, structure=False), "rms_slope", "summation",
     "skin.toml: fiber.scatterer_profile = 'skin': the summation of a config without [structure]"),
])
def test_a_bad_scatterer_depth_or_a_model_without_one_is_refused_in_one_line(config, free, method, message):
    with pytest.raises(FitError) as exc:
        FitProblem(config, FLAT, parse_free([free], config), method=method)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_the_cli_refuses_a_scatterer_depth_of_uniform_scatterers_before_any_work(tmp_path, capsys):
    (tmp_path / "cotton.toml").write_text(load_config("red-cotton").text)
    write_dataset(FLAT, tmp_path / "m")
    code = main(["fit", str(tmp_path / "cotton.toml"), str(tmp_path / "m"), "--method", "classic", "--free",
                 "fiber.scatterer_depth_um", "--out", str(tmp_path / "f")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert ("--free fiber.scatterer_depth_um: cotton.toml has its scatterers through the fiber "
            "(fiber.scatterer_profile \"uniform\"), which have no depth") in err
    assert not (tmp_path / "f").exists()


def test_the_free_scatterer_depth_is_the_walked_fibers_and_kept_off_the_lattice():
    """The classic model at a free depth is the model of the config written at that depth (the same seed: the same
    walk), another depth's differs, and the depth is walked as it is, not re-weighted from a lattice point (a walk
    is re-weighted to other scattering, not to another placement)."""
    geometries = _geometries()
    flat = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None, geometries=geometries)

    def problem(depth: float) -> FitProblem:
        cfg = skin(depth)
        return FitProblem(cfg, flat, parse_free(["fiber.scatterer_depth_um"], cfg), method="classic",
                          target_rel_err=0.3, seed=3, wavelengths_nm=WL6)

    moved = problem(1.0)
    assert moved.lattice((2.13,)) == (2.13,)
    at_3, _ = moved.model(np.array([3.0]))
    written, _ = problem(3.0).model(np.array([3.0]))
    np.testing.assert_array_equal(at_3, written)
    at_1, _ = moved.model(np.array([1.0]))
    assert np.max(np.abs(at_1 - at_3) / np.abs(at_3)) > 0.02
