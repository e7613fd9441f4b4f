"""Small synthetic fitting problems: the classic model at 15 wavelengths on a 3-incidence plan."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.spec import parse_free
from gonio.data import in_plane_geometry, make_dataset, new_meta
from simulate.config import load_config

WAVELENGTHS = np.arange(420.0, 701.0, 20.0)  # ASTM E308 needs a 1, 5, 10 or 20 nm step
#: the mock goniophotometer's typical relative standard uncertainty (median of the demo: 1.1 %)
MOCK_REL_U = 0.011


def geometry_table() -> pd.DataFrame:
    rows = []
    for theta_i in (0.0, 30.0, 60.0):
        for s in (-60.0, -40.0, -20.0, -10.0, 10.0, 20.0, 40.0, 60.0):
            if abs(s + theta_i) < 5.0:  # beam-blocked, as the instrument
                continue
            theta_o, phi_o = in_plane_geometry(theta_i, np.array([s]))
            rows.append((theta_i, 0.0, float(theta_o[0]), float(phi_o[0])))
    return pd.DataFrame(rows, columns=["theta_i", "phi_i", "theta_o", "phi_o"])


def measurement(beta_of, noise_seed: int | None, rel_u: float = MOCK_REL_U, geometries=None):
    """A "measured" dataset from ``beta_of(geometries, wavelengths) -> [G, L]`` with Gaussian noise."""
    g = geometry_table() if geometries is None else geometries
    beta = np.asarray(beta_of(g, WAVELENGTHS), float)
    u = rel_u * np.abs(beta) + 1e-5
    if noise_seed is not None:
        beta = beta + np.random.default_rng(noise_seed).standard_normal(beta.shape) * u
    rep = g.loc[g.index.repeat(WAVELENGTHS.size)].reset_index(drop=True)
    table = dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"], phi_o=rep["phi_o"],
                 wavelength_nm=np.tile(WAVELENGTHS, len(g)), beta=beta.ravel(), u_beta=u.ravel(),
                 n=np.ones(beta.size, dtype=int))
    return make_dataset(table, new_meta("measured", {"name": "synthetic"}))


def model_measurement(problem: FitProblem, x_true, noise_seed):
    """The problem's own model at ``x_true`` (at the measured geometries) plus mock-level noise."""
    beta, _ = problem.model(np.asarray(x_true, float))
    return measurement(lambda g, wl: beta, noise_seed, geometries=problem.geometries)


@pytest.fixture(scope="session")
def red_cotton():
    return load_config("red-cotton")


@pytest.fixture(scope="session")
def base_problem(red_cotton):
    """A classic-model problem freeing the 520 nm band's peak and the RMS slope (one walk, shared)."""
    flat = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)
    free = parse_free(["fiber.dye.bands[0].peak_per_um=0.3:3,rms_slope=0.1:0.8"], red_cotton)
    return FitProblem(red_cotton, flat, free, method="classic", target_rel_err=0.03, seed=5)


def sibling(problem: FitProblem, measured, free=None, **settings) -> FitProblem:
    """Same config, model and Monte Carlo table as ``problem``, another measurement (no re-walk); ``settings``
    of the spec in place of the defaults (``hold_colour``, ``colour_weight``, ...)."""
    p = FitProblem(problem.config, measured, problem.free if free is None else free, method=problem.method,
                   target_rel_err=problem.target_rel_err, seed=problem.seed, **settings)
    p.share_walks(problem)
    return p
