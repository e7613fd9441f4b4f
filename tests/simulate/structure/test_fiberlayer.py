"""The visible-surface average with masking (simulate.fabric.fiberlayer) against an independent layer trace."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.fabric import fiberlayer as FL
from simulate.fiber import Fiber
from simulate.fiber import farfield as FF
from simulate.media.medium import HGMedium

R_UM, N_HOST, MU_S, MU_A, G = 10.0, 1.5, 0.4, 0.02, 0.5


def _fiber() -> Fiber:
    return Fiber(radius_um=R_UM, n_host=N_HOST, medium=HGMedium(mu_s=MU_S, mu_a=MU_A, g=G), roughness=0.3,
                 cell_width_deg=10)


@pytest.fixture(scope="module")
def table():
    return FF.exit_table(_fiber(), [550.0], w_t=[0.0, 0.3, 0.6], photons_per_row=20_000, seed=4, threads=2)


def _w(w_t: float, beta_deg: float) -> np.ndarray:
    rho = math.sqrt(1.0 - w_t * w_t)
    b = math.radians(beta_deg)
    return np.array([w_t, -rho * math.sin(b), rho * math.cos(b)])


def test_visibility_matches_ray_marching():
    """The analytic two-circle test = marching the ray in small steps against the neighbours (random cases)."""
    rng = np.random.default_rng(1)
    w = rng.normal(size=(400, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    w[:, 2] = np.abs(w[:, 2])
    psi = rng.uniform(-math.pi, math.pi, 400)
    spacing = 2.2
    got = np.array([FL.visibility(w[i:i + 1], psi[i:i + 1], spacing)[0, 0] for i in range(400)])
    expected = np.zeros(400)
    steps = np.linspace(1e-6, 8.0, 40_000)
    for i in range(400):
        ny, nz = -math.sin(psi[i]), math.cos(psi[i])
        if w[i, 1] * ny + w[i, 2] * nz <= 0:
            continue
        u = np.array([w[i, 1], w[i, 2]])
        u /= np.linalg.norm(u)
        y = ny + steps * u[0]
        z = nz + steps * u[1]
        blocked = np.any(((y - spacing) ** 2 + z ** 2 < 1.0) | ((y + spacing) ** 2 + z ** 2 < 1.0))
        expected[i] = 0.0 if blocked else 1.0
    assert 0.2 < expected.mean() < 0.8   # both outcomes are exercised
    assert np.array_equal(got, expected)


def _hemisphere_bins(n_1: int, n_2: int, m: int) -> np.ndarray:
    sub = (np.arange(m) + 0.5) / m
    mu = (np.arange(n_1)[:, None] + sub[None, :]) / n_1
    phi = (np.arange(n_2)[:, None] + sub[None, :]) / n_2 * 2.0 * math.pi - math.pi
    mm = np.broadcast_to(mu[:, None, :, None], (n_1, n_2, m, m))
    pp = np.broadcast_to(phi[None, :, None, :], (n_1, n_2, m, m))
    s = np.sqrt(1.0 - mm ** 2)
    return np.stack([s * np.cos(pp), s * np.sin(pp), mm], axis=-1).reshape(n_1, n_2, m * m, 3)


@pytest.mark.parametrize("beta_deg", [0.0, 50.0])
def test_masked_layer_agrees_with_layer_trace(table, tracer, beta_deg):
    """G of the masked layer (volume) = the traced layer of touching fibers, per bin of the upper hemisphere.

    beta = 50 deg across the fibers: each fiber is shadowed over a third of its width and much of
    its light is masked -- the lit fractions and the visible widths are both exercised. Allowed:
    4 standard errors of the trace + 4 % of the largest bin (the exit table's 9 x 18 direction bins
    and partly lit cells, module docstring limits 2 and 3).
    """
    w_in = _w(0.3, beta_deg)
    n_1, n_2, n = 4, 8, 400_000
    sums, sq = tracer(n, 21, *w_in, R_UM, N_HOST, MU_S, MU_A, G, 2.0 * R_UM, n_1, n_2)
    omega = 2.0 * math.pi / (n_1 * n_2)
    mean = sums / n
    scale = w_in[2] / omega
    trace = mean * scale
    u_trace = np.sqrt(np.maximum(sq / n - mean ** 2, 0.0) / (n - 1)) * scale
    dirs = _hemisphere_bins(n_1, n_2, 5)
    got = FL.layer_G(table, _fiber(), w_in, dirs.reshape(-1, 3), surface=False)[:, 0].reshape(n_1, n_2, -1).mean(axis=2)
    err = np.abs(got - trace)
    assert np.all(err <= 4.0 * u_trace + 0.04 * trace.max()), (got, trace)
    # masking matters here: the unmasked visible average is clearly larger
    free = FL.layer_G(table, _fiber(), w_in, dirs.reshape(-1, 3), masking=False, surface=False)[:, 0]
    assert free.reshape(n_1, n_2, -1).mean(axis=2).sum() > 1.1 * trace.sum()


def test_layer_table_lookup(table):
    """The table reproduces layer_G at its nodes, through the mirrors, and between nodes within 5 %."""
    fiber = _fiber()
    lt = FL.layer_table(table, fiber, step_deg=15.0, phi_step_deg=30.0)
    w_in = np.array([math.sin(math.radians(30)) * math.cos(math.radians(60)),
                     math.sin(math.radians(30)) * math.sin(math.radians(60)), math.cos(math.radians(30))])
    w_out = np.array([[math.sin(math.radians(45)) * math.cos(math.radians(150)),
                       math.sin(math.radians(45)) * math.sin(math.radians(150)), math.cos(math.radians(45))]])
    direct = FL.layer_G(table, fiber, w_in, w_out)[0, 0]
    assert lt(w_in[None], w_out)[0, 0] == pytest.approx(direct, rel=1e-9)
    flip = np.array([-1.0, -1.0, 1.0])
    assert lt((w_in * flip)[None], w_out * flip)[0, 0] == pytest.approx(direct, rel=1e-9)
    # between nodes: interpolation error of a coarse 15 x 30 deg grid stays small for this smooth layer
    w_mid = np.array([[0.35, 0.2, 0.0]])
    w_mid[0, 2] = math.sqrt(1 - 0.35 ** 2 - 0.2 ** 2)
    w_mo = np.array([[-0.3, 0.4, 0.0]])
    w_mo[0, 2] = math.sqrt(1 - 0.3 ** 2 - 0.4 ** 2)
    assert lt(w_mid, w_mo)[0, 0] == pytest.approx(FL.layer_G(table, fiber, w_mid[0], w_mo)[0, 0], rel=0.05)
    # below the layer: nothing
    assert lt(np.array([[0.0, 0.6, -0.8]]), w_out)[0, 0] == 0.0
